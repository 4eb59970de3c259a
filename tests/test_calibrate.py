"""calibrate: fitting tables from sweeps, correction models, the optax fit and its uncertainty, JSON.

Every check is against a hand calculation or a closed form: the models are linear in their parameters, so
the weighted least-squares optimum and its Gauss–Newton covariance are the normal equations' solution
(θ = (XᵀX)⁻¹Xᵀy, C = s²(XᵀX)⁻¹), computed here with numpy.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

from calibrate import abstention, datasets, fit, models, persistence
from membrax import theory

TRUE = {"k_r": 0.8, "r0": 0.05, "r1": -0.2, "k_a": 0.3, "a0": 0.4, "a1": -1.1}
NOISE = 0.01


def _synthetic_table(seed=0, cases=8, rows=60, noise=NOISE):
    """Inputs spread like a sweep's, targets from the paper model with TRUE plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    n = cases * rows
    case = np.repeat(np.arange(cases), rows)
    indentation = np.repeat(rng.uniform(0.15, 0.45, cases), rows)
    inputs = {name: np.zeros(n) for name in datasets.INPUTS}
    inputs["hoop_ratio"] = rng.uniform(0.0, 0.5, n)
    inputs["strain_ratio_change"] = rng.uniform(-1.2, -0.2, n)
    inputs["indentation_ratio"] = indentation
    axial, radial = fit.predict(
        models.PAPER, TRUE, datasets.FittingTable(inputs, *(np.zeros(n),) * 2, case, case == -1)
    )
    axial = axial + noise * rng.standard_normal(n)
    radial = radial + noise * rng.standard_normal(n)
    return datasets.FittingTable(inputs, axial, radial, case, np.zeros(n, dtype=bool))


def _normal_equations(table):
    """The paper model's least-squares solution and covariance by hand (two decoupled linear fits)."""
    x = table.inputs
    one = np.ones(table.num_rows)
    design_a = np.stack([x["strain_ratio_change"], one, x["indentation_ratio"]], axis=1)
    design_r = np.stack([x["hoop_ratio"], one, x["indentation_ratio"]], axis=1)
    theta_a = np.linalg.lstsq(design_a, table.axial_target, rcond=None)[0]
    theta_r = np.linalg.lstsq(design_r, table.radial_target, rcond=None)[0]
    rss = np.sum((design_a @ theta_a - table.axial_target) ** 2) + np.sum(
        (design_r @ theta_r - table.radial_target) ** 2
    )
    s2 = rss / (2 * table.num_rows - 6)
    params = dict(zip(("k_a", "a0", "a1"), theta_a, strict=True)) | dict(
        zip(("k_r", "r0", "r1"), theta_r, strict=True)
    )
    std = dict(
        zip(("k_a", "a0", "a1"), np.sqrt(np.diag(s2 * np.linalg.inv(design_a.T @ design_a))), strict=True)
    )
    std |= dict(
        zip(("k_r", "r0", "r1"), np.sqrt(np.diag(s2 * np.linalg.inv(design_r.T @ design_r))), strict=True)
    )
    return params, std


def test_the_fit_is_the_normal_equations_solution_and_recovers_the_true_coefficients():
    table = _synthetic_table()
    result = fit.fit(models.PAPER, table)
    params, std = _normal_equations(table)
    for name in TRUE:
        assert result.params[name] == pytest.approx(params[name], abs=1e-8), name
        assert result.std[name] == pytest.approx(std[name], rel=1e-6), name
        # the true value within 4 standard errors (each has a 6e-5 chance of failing by chance)
        assert abs(result.params[name] - TRUE[name]) < 4.0 * result.std[name], name
    # the residual RMS is the noise's
    assert result.rms == pytest.approx(NOISE, rel=0.1)
    assert result.evaluations["adam"] > 0 and result.evaluations["lbfgs"] > 0


def test_nan_rows_are_left_out_and_too_few_rows_are_refused():
    table = _synthetic_table()
    spoiled = table.axial_target.copy()
    spoiled[::7] = np.nan  # e.g. the strain-ratio window at the ends of a record
    clean = fit.fit(models.PAPER, table.select(np.isfinite(spoiled)))
    with_nan = fit.fit(models.PAPER, table._replace(axial_target=spoiled))
    # the NaN rows still hold radial targets, so only the axial parameters must agree with the clean fit
    for name in ("k_a", "a0", "a1"):
        assert with_nan.params[name] == pytest.approx(clean.params[name], abs=1e-8)
    with pytest.raises(ValueError, match="usable rows"):
        fit.fit(models.PAPER, table.select(np.arange(2)))


def test_leave_one_case_out_error_is_the_noise_when_the_model_is_right():
    table = _synthetic_table(cases=5, rows=40)
    scores = fit.cross_validate(models.PAPER, table, adam_steps=100)
    assert sorted(scores) == list(range(5))
    for score in scores.values():
        # out-of-sample error: noise plus a small parameter error, nowhere near the signal (~0.3)
        assert NOISE * 0.7 < score["axial"] < NOISE * 1.6
        assert NOISE * 0.7 < score["radial"] < NOISE * 1.6


def test_each_refit_of_a_cross_validation_is_the_normal_equations_without_its_case_on_shared_programs():
    # a refit weighs its case's rows 0 and keeps the table's size: the same optimum as the table without
    # them (normal equations by hand), from the programs the first fit compiled
    table = _synthetic_table(cases=4, rows=41)  # a size no other test fits
    steps = fit._optimiser_steps(models.PAPER.predict, fit._template(models.PAPER.initial_params), 0.05)
    before = steps.adam_step._cache_size(), steps.lbfgs_step._cache_size()
    axial, radial = fit.cross_validated_predictions(models.PAPER, table)
    for case in range(4):
        held = table.case == case
        params, _ = _normal_equations(table.select(~held))
        expected = fit.predict(models.PAPER, params, table.select(held))
        np.testing.assert_allclose(axial[held], expected[0], rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(radial[held], expected[1], rtol=1e-7, atol=1e-9)
    # four refits, one new program each: optax's weak-typed initial L-BFGS state would make it two
    # (fit.strong_types), a table of the left-in rows one per refit
    assert (steps.adam_step._cache_size(), steps.lbfgs_step._cache_size()) == (before[0] + 1, before[1] + 1)


def test_nelder_mead_reaches_the_same_optimum_with_more_loss_evaluations():
    table = _synthetic_table(cases=4, rows=40)
    result = fit.fit(models.PAPER, table)
    baseline = fit.nelder_mead_baseline(models.PAPER, table)
    assert baseline["converged"]
    assert baseline["loss"] == pytest.approx(result.loss, rel=1e-6)
    for name in TRUE:
        assert baseline["params"][name] == pytest.approx(result.params[name], abs=1e-4)
    assert baseline["evaluations"] > result.evaluations["adam"] + result.evaluations["lbfgs"]


def test_models_work_under_jit_vmap_and_grad():
    inputs = {
        "hoop_ratio": jnp.asarray([0.1, 0.2]),
        "strain_ratio_change": jnp.asarray([-0.5, -0.8]),
        "indentation_ratio": jnp.asarray([0.3, 0.3]),
        "size_ratio": jnp.asarray([0.1, 0.1]),
        "axial_strain": jnp.asarray([0.01, 0.05]),
    }
    with jax.enable_x64(True):
        params = {k: jnp.asarray(v) for k, v in TRUE.items()}
        axial, radial = jax.jit(models.PAPER.predict)(params, inputs)
        # by hand: r = 0.8·0.1 + 0.05 − 0.2·0.3, a = 0.3·(−0.5) + 0.4 − 1.1·0.3
        assert float(radial[0]) == pytest.approx(0.8 * 0.1 + 0.05 - 0.2 * 0.3, rel=1e-14)
        assert float(axial[0]) == pytest.approx(0.3 * -0.5 + 0.4 - 1.1 * 0.3, rel=1e-14)
        # linear in its parameters: ∂r/∂k_r is the hoop ratio, ∂a/∂a1 the indentation ratio
        gradient = jax.grad(lambda p: jnp.sum(models.PAPER.predict(p, inputs)[1]))(params)
        assert float(gradient["k_r"]) == pytest.approx(0.3, rel=1e-14)
        batched = jax.vmap(lambda k: models.PAPER.predict({**params, "k_r": k}, inputs)[1])(
            jnp.asarray([0.0, 1.0])
        )
        np.testing.assert_allclose(np.asarray(batched[1] - batched[0]), [0.1, 0.2], rtol=1e-14)
        rich = {k: jnp.asarray(v) for k, v in models.RICH.initial_params.items()} | params
        np.testing.assert_allclose(
            np.asarray(models.RICH.predict(rich, inputs)[0]), np.asarray(axial), rtol=1e-14
        )


def _sweep_like(tmp_cases=((10.0, 2.5), (40.0, 5.0)), received=True):
    """A two-member dataset shaped like sweep.nc, with hand-made records (``received``: with the received σ3).

    Δσ_a/σc = 0.2 − ε_a; Δσ_r/σc = 0.1 + ε_a counted from the §4.3 σ3 and 0.05 + ε_a/2 from the received one.
    """
    records = 5
    pressures = sorted({p for p, _ in tmp_cases})
    thicknesses = sorted({t for _, t in tmp_cases})
    shape = (len(pressures), len(thicknesses), records)
    strain = np.linspace(0.0, 0.04, records)
    variables = {}
    for name in (
        "axial_strain",
        "radial_strain",
        "strain_ratio_change",
        "hoop_strain",
        "platen_area",
        "additional_axial_stress",
        "additional_radial_stress",
        "external_radial_stress",
        "received_radial_stress",
    ):
        variables[name] = np.full(shape, np.nan)
    counts = np.zeros(shape[:2], dtype=np.int32)
    for p, t in tmp_cases:
        i, j = pressures.index(p), thicknesses.index(t)
        counts[i, j] = records
        variables["axial_strain"][i, j] = strain
        variables["radial_strain"][i, j] = -0.3 * strain
        variables["strain_ratio_change"][i, j] = -0.3 - 2.0 * strain
        variables["hoop_strain"][i, j] = 0.001 + 0.3 * strain  # 0.001 left from consolidation
        variables["platen_area"][i, j] = math.pi * 0.125**2
        variables["additional_axial_stress"][i, j] = 1e3 * p * (0.2 - strain)
        variables["additional_radial_stress"][i, j] = 1e3 * p * (0.1 + strain)
        variables["external_radial_stress"][i, j] = 1e3 * p
        variables["received_radial_stress"][i, j] = 1e3 * p * (1.05 + 0.5 * strain)
    if not received:  # a sweep written before membrax recorded the received σ3
        del variables["received_radial_stress"]
    dims = ("cell_pressure_kpa", "membrane_thickness_mm", "record")
    dataset = xr.Dataset(
        {name: (dims, value) for name, value in variables.items()} | {"num_records": (dims[:2], counts)},
        coords={"cell_pressure_kpa": pressures, "membrane_thickness_mm": thicknesses},
        attrs={
            "base_config": json.dumps(
                {
                    "particle_diameter_mm": 25.0,
                    "membrane_modulus_kpa": 1400.0,
                    "cell_pressure_kpa": 10.0,
                    "membrane_thickness_mm": 5.0,
                }
            ),
            "grid": json.dumps({"cell_pressure_kpa": pressures}),
            "grid_fields": "cell_pressure_kpa,membrane_thickness_mm",
        },
    )
    return dataset


def test_a_sweep_becomes_a_fitting_table_of_dimensionless_groups():
    table = datasets.fitting_table(_sweep_like())
    assert table.num_cases == 2 and table.num_rows == 10  # the two empty grid points are skipped
    first = table.case == table.case[0]
    rows = table.select(first)
    # the first member is (10 kPa, 2.5 mm): groups by hand
    assert rows.inputs["cell_pressure"][0] == pytest.approx(1e4)
    assert rows.inputs["specimen_diameter"][0] == pytest.approx(0.25)
    assert rows.inputs["thickness_ratio"][0] == pytest.approx(2.5 / 25.0)
    assert rows.inputs["stiffness_ratio"][0] == pytest.approx(1.4e6 * 2.5e-3 / (1e4 * 0.025))
    assert rows.inputs["size_ratio"][0] == pytest.approx(0.025 / 0.25)
    expected_indentation = (
        0.275 * (1 + theory.FCC_VOID_RATIO) ** (4 / 9) * (25 / 2.5) ** (1 / 3) * (10 / 1400) ** (1 / 3)
    )
    assert rows.inputs["indentation_ratio"][0] == pytest.approx(expected_indentation, rel=1e-12)
    # hoop strain from the start of shearing, and Henkel & Gilbert's hoop stress over σc
    strain = np.linspace(0.0, 0.04, 5)
    np.testing.assert_allclose(rows.inputs["hoop_strain"], 0.3 * strain, atol=1e-15)
    np.testing.assert_allclose(
        rows.inputs["tape_hoop_ratio"], 2 * 1.4e6 * 2.5e-3 * 0.3 * strain / (0.25 * 1e4), atol=1e-12
    )
    # the hoop ratio every laboratory has: the right cylinder's hoop strain −ε_r = 0.3 ε_a here
    np.testing.assert_allclose(
        rows.inputs["hoop_ratio"], 2 * 1.4e6 * 2.5e-3 * 0.3 * strain / (0.25 * 1e4), atol=1e-12
    )
    np.testing.assert_allclose(rows.axial_target, 0.2 - strain, rtol=1e-12)
    # Δσ_r from the received σ3 (the default) and from the paper's §4.3 one
    assert table.radial_target_name == rows.radial_target_name == "received"
    np.testing.assert_allclose(rows.radial_target, 0.05 + 0.5 * strain, rtol=1e-12)
    paper = datasets.fitting_table(_sweep_like(), "section_4_3")
    assert paper.radial_target_name == "section_4_3"
    np.testing.assert_allclose(paper.select(first).radial_target, 0.1 + strain, rtol=1e-12)
    np.testing.assert_array_equal(paper.axial_target, table.axial_target)
    assert rows.initial.tolist() == [True, False, False, False, False]
    with pytest.raises(ValueError, match="base_config"):
        datasets.fitting_table(xr.Dataset())
    with pytest.raises(ValueError, match=r"received_radial_stress.*radial-target section_4_3"):
        datasets.fitting_table(_sweep_like(received=False))
    with pytest.raises(ValueError, match="radial_target = 'love_weber'"):
        datasets.fitting_table(_sweep_like(), "love_weber")
    with pytest.raises(ValueError, match="different internal stresses"):
        datasets.concatenate([table, paper])


def test_a_fitting_table_keeps_its_radial_target_through_a_file(tmp_path):
    paper = datasets.fitting_table(_sweep_like(), "section_4_3")
    datasets.save_table(paper, tmp_path / "t.npz")
    loaded = datasets.load_table(tmp_path / "t.npz")
    assert loaded.radial_target_name == "section_4_3"
    np.testing.assert_array_equal(loaded.radial_target, paper.radial_target)
    # a table written before tables named their target held the §4.3 one
    with np.load(tmp_path / "t.npz") as content:
        old = {k: content[k] for k in content.files if k != "radial_target_name"}
    np.savez(tmp_path / "old.npz", **old)
    assert datasets.load_table(tmp_path / "old.npz").radial_target_name == "section_4_3"


def test_corrections_round_trip_through_json_with_provenance(tmp_path):
    table = _synthetic_table(cases=3, rows=30)
    result = fit.fit(models.PAPER, table, adam_steps=50)
    path = persistence.save_corrections(
        tmp_path / "c.json", models.PAPER, result, table, {"sweep_sha256": "abc"}
    )
    loaded = persistence.load_corrections(path)
    assert loaded.model is models.PAPER
    assert loaded.params == result.params and loaded.std == result.std
    np.testing.assert_array_equal(loaded.covariance, result.covariance)
    low, high = loaded.input_ranges["hoop_ratio"]
    assert low == pytest.approx(table.inputs["hoop_ratio"].min()) and high == pytest.approx(
        table.inputs["hoop_ratio"].max()
    )
    assert loaded.provenance["sweep_sha256"] == "abc" and loaded.provenance["cases"] == 3
    assert persistence.sweep_hash(_sweep_like()) == persistence.sweep_hash(_sweep_like())
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="line 1"):
        persistence.load_corrections(tmp_path / "bad.json")
    (tmp_path / "short.json").write_text(json.dumps({"format": "membrax-corrections"}))
    with pytest.raises(ValueError, match="lacks"):
        persistence.load_corrections(tmp_path / "short.json")
    with pytest.raises(FileNotFoundError, match="membrax fit"):
        persistence.load_corrections(tmp_path / "none.json")


def test_membrax_fit_writes_the_fit_of_the_sweep_files_and_names_a_bad_file(tmp_path, capsys):
    from membrax import cli, io

    first = io.write_netcdf(_sweep_like(), tmp_path / "a.nc")
    second = io.write_netcdf(_sweep_like(((100.0, 2.5),)), tmp_path / "b.nc")
    out = tmp_path / "corrections.json"
    assert cli.main(["fit", str(first), str(second), "--out", str(out), "--model", "paper"]) == 0
    report = capsys.readouterr().out
    assert "3 cases, 15 records from 2 sweep(s)" in report and "leave-one-case-out" in report
    loaded = persistence.load_corrections(out)
    table = datasets.concatenate(
        [datasets.fitting_table(io.read_results(first)), datasets.fitting_table(io.read_results(second))]
    )
    assert sorted(set(table.case.tolist())) == [0, 1, 2]
    # the abstention rule is stored, fitted on the leave-one-case-out predictions: one case per octave of
    # E_m t_m/(σc D) = 1400·2.5/(10·25) = 14, 1400·5/(40·25) = 7 and 1400·2.5/(100·25) = 1.4
    assert "when the correction abstains" in report
    assert [(r["low"], r["cases"]) for r in loaded.abstention["regions"]] == [(1.0, 1), (4.0, 1), (8.0, 1)]
    assert loaded.abstention == abstention.fit_rule(
        table, *fit.cross_validated_predictions(models.PAPER, table)
    )
    assert persistence.ASPECT_RATIO not in loaded.input_ranges  # FCC sweeps without a height record
    expected = fit.fit(models.PAPER, table)
    for name, value in expected.params.items():
        assert loaded.params[name] == pytest.approx(value, abs=1e-9)
    assert len(loaded.provenance["sweep_sha256"]) == 2
    # the received σ3 is the target; the §4.3 one is fitted the same way beside it, as the alternate
    assert loaded.radial_target == "received" and loaded.alternate.radial_target == "section_4_3"
    assert loaded.alternate.alternate is None
    paper = datasets.concatenate(
        [datasets.fitting_table(io.read_results(path), "section_4_3") for path in (first, second)]
    )
    for name, value in fit.fit(models.PAPER, paper).params.items():
        assert loaded.alternate.params[name] == pytest.approx(value, abs=1e-9)
    assert loaded.alternate.abstention == abstention.fit_rule(
        paper, *fit.cross_validated_predictions(models.PAPER, paper)
    )
    # sweeps without the received σ3: refused by default, fitted on §4.3 when asked, with no alternate
    old = io.write_netcdf(_sweep_like(received=False), tmp_path / "old.nc")
    assert cli.main(["fit", str(old), "--out", str(tmp_path / "old.json"), "--model", "paper"]) == 2
    assert "received_radial_stress" in capsys.readouterr().err
    argv = ["fit", str(old), "--out", str(tmp_path / "old.json"), "--model", "paper"]
    assert cli.main([*argv, "--radial-target", "section_4_3", "--no-cross-validation"]) == 0
    assert "no alternate correction" in capsys.readouterr().out
    legacy = persistence.load_corrections(tmp_path / "old.json")
    assert legacy.radial_target == "section_4_3" and legacy.alternate is None
    # a file written before corrections named their target reproduces §4.3
    content = json.loads((tmp_path / "old.json").read_text())
    del content["radial_target"]
    (tmp_path / "older.json").write_text(json.dumps(content))
    assert persistence.load_corrections(tmp_path / "older.json").radial_target == "section_4_3"
    # a file that is not a sweep's: exit 2, the file named
    other = io.write_netcdf(xr.Dataset({"x": ("record", np.arange(3.0))}), tmp_path / "other.nc")
    assert cli.main(["fit", str(other), "--out", str(tmp_path / "x.json")]) == 2
    error = capsys.readouterr().err
    assert "other.nc" in error and "base_config" in error
    assert not (tmp_path / "x.json").exists()


def test_the_specimens_h_d_is_read_from_the_sweeps_height_record_or_a_random_mould(tmp_path):
    with_height = _sweep_like()
    strain = np.linspace(0.0, 0.04, 5)
    height = np.full(with_height["axial_strain"].shape, np.nan)
    height[..., :] = 0.5 * (1.0 - strain)  # 0.5 m at the start of shearing, over D_s = 2·0.125 m
    with_height["height"] = (with_height["axial_strain"].dims, height)
    assert datasets.aspect_ratios([with_height]) == [pytest.approx(2.0, rel=1e-12)] * 2
    # no height record: a random specimen's mould (250/150), an FCC one nothing
    random = _sweep_like()
    base = json.loads(random.attrs["base_config"])
    base.update(packing="random", specimen_diameter_mm=150.0, specimen_height_mm=250.0)
    random.attrs["base_config"] = json.dumps(base)
    assert datasets.aspect_ratios([random, _sweep_like()]) == [pytest.approx(5.0 / 3.0, rel=1e-12)] * 2
    # saved as a range in the JSON, or added with a rule to one written without them, the rest untouched
    table = _synthetic_table(cases=3, rows=30)
    result = fit.fit(models.PAPER, table, adam_steps=50)
    path = persistence.save_corrections(
        tmp_path / "c.json", models.PAPER, result, table, aspect_ratio=(1.5, 2)
    )
    assert persistence.load_corrections(path).input_ranges[persistence.ASPECT_RATIO] == (1.5, 2.0)
    old = persistence.save_corrections(tmp_path / "old.json", models.PAPER, result, table)
    before = json.loads(old.read_text())
    assert persistence.load_corrections(old).abstention is None
    rule = {"quantity": "stiffness_ratio", "regions": []}
    persistence.amend_corrections(old, aspect_ratio=(1.28, 5 / 3), abstention=rule)
    after = json.loads(old.read_text())
    assert after.pop("abstention") == rule
    assert after["input_ranges"].pop(persistence.ASPECT_RATIO) == [1.28, 5 / 3]
    assert after == before


def test_the_packing_family_is_read_from_the_sweeps_and_kept_in_the_json(tmp_path):
    random = _sweep_like()
    base = json.loads(random.attrs["base_config"])
    base.update(
        packing="random", compaction_friction_deg=26.565051177077994, grading=[[20.0, 0.0], [30.0, 100.0]]
    )
    random.attrs["base_config"] = json.dumps(base)
    random["solid_fraction"] = (
        ("cell_pressure_kpa", "membrane_thickness_mm"),
        [[0.57, np.nan], [np.nan, 0.59]],
    )
    family = datasets.packing_family([random, _sweep_like()])
    assert family["packings"] == ["fcc", "random"] and family["states"] == ["loose"]
    assert family["gradings"] == ["20–30 mm, d50 25 mm"]  # d50 halfway up a straight curve, by hand
    assert family["solid_fraction"] == [0.57, 0.59]  # the members with records only
    assert datasets.packing_family([_sweep_like()])["solid_fraction"] is None
    table = _synthetic_table(cases=3, rows=30)
    result = fit.fit(models.PAPER, table, adam_steps=50)
    path = persistence.save_corrections(
        tmp_path / "c.json", models.PAPER, result, table, packing_family=family
    )
    assert persistence.load_corrections(path).packing_family == family
    content = json.loads(path.read_text())
    del content["packing_family"]  # a file written before families were recorded
    path.write_text(json.dumps(content))
    assert persistence.load_corrections(path).packing_family == {}
