"""calibrate.correct: classical and fitted corrections of a laboratory record, checked by hand.

The record is built so every correction has a closed form: ε_r = c·ε_a exactly (so dε_r/dε_a = c at every
record, the strain-ratio regression being exact on a straight line), the volumetric strain from it by the
right-cylinder identity, and the fitted model's parameters chosen by hand, so its prediction is a line.
"""

import math

import numpy as np
import pytest

from calibrate import correct, datasets, lab, models, persistence
from membrax import theory

SPECIMEN = correct.Specimen.from_mm_kpa(150.0, 20.0, 2.0, 1400.0)
PARAMS = {"k_r": 0.6, "r0": 0.05, "r1": -0.2, "k_a": 0.1, "a0": 0.3, "a1": -1.0}
CV_RMS = 0.02


def _record(rows=41, ratio=-0.4, cell=20e3):
    axial = np.linspace(0.0, 0.10, rows)
    radial = ratio * axial
    volumetric = 1.0 - (1.0 - axial) * (1.0 - radial) ** 2
    axial_stress = cell * (1.0 + 3.0 * axial / (0.01 + axial))
    return lab.LabRecord(axial, volumetric, radial, axial_stress, np.full(rows, cell), ())


def _corrections(ranges=None, covariance=None):
    names = tuple(sorted(PARAMS))
    return persistence.Corrections(
        models.PAPER,
        dict(PARAMS),
        {name: 0.0 for name in names},
        np.zeros((6, 6)) if covariance is None else covariance,
        names,
        CV_RMS,
        ranges or {},
        {"cross_validation": {"axial_rms": [CV_RMS, CV_RMS], "radial_rms": [CV_RMS, CV_RMS]}},
    )


def test_classical_corrections_are_the_closed_forms():
    record = _record()
    result = correct.correct_record(record, SPECIMEN, _corrections())
    e, t, d = 1.4e6, 2e-3, 0.15
    ea, ev, cell = record.axial_strain, record.volumetric_strain, record.cell_pressure
    measured = record.axial_stress
    # ASTM D4767/D7181: σ1 − 4 E t ε_a / D, σ3 unchanged
    np.testing.assert_allclose(result.sigma_1["astm"], measured - 4 * e * t * ea / d, rtol=1e-12)
    np.testing.assert_allclose(result.sigma_3["astm"], cell, rtol=1e-15)
    # Henkel & Gilbert hoop: σ3 + 2 E t ε_θ / D_now, ε_θ = D_now/D0 − 1 = −ε_r here
    now = d * (1 - record.radial_strain)
    hoop = np.maximum(2 * e * t * (now - d) / d / now, 0.0)
    np.testing.assert_allclose(result.sigma_3["henkel_gilbert"], cell + hoop, rtol=1e-12)
    np.testing.assert_allclose(result.sigma_1["henkel_gilbert"], measured, rtol=1e-15)
    # Kuerbis & Vaid with ν = 0.5 (small strain): Δσ_a = (4Et/3D)(3ε_a + ε_v), Δσ_r = −(4Et/3D) ε_v
    scale = 4 * e * t / (3 * d)
    np.testing.assert_allclose(result.sigma_1["kuerbis_vaid"], measured - scale * (3 * ea + ev), rtol=1e-9)
    np.testing.assert_allclose(result.sigma_3["kuerbis_vaid"], cell - scale * ev, rtol=1e-9)
    # φ' of every method from sin φ' = (σ1 − σ3)/(σ1 + σ3)
    for method in correct.METHODS:
        s1, s3 = result.sigma_1[method], result.sigma_3[method]
        np.testing.assert_allclose(
            result.friction_angle[method], np.degrees(np.arcsin((s1 - s3) / (s1 + s3))), rtol=1e-12
        )


def test_the_fitted_correction_is_the_model_on_the_records_inputs_with_its_band():
    record = _record(ratio=-0.4)
    result = correct.correct_record(record, SPECIMEN, _corrections())
    cell = 20e3
    indentation = float(
        theory.molenkamp_luger_indentation_ratio(theory.FCC_VOID_RATIO, 0.02, 2e-3, cell, 1.4e6)
    )
    hoop = 2 * 1.4e6 * 2e-3 * (-record.radial_strain) / (0.15 * cell)
    # dε_r/dε_a = −0.4 at every record of a straight line
    np.testing.assert_allclose(result.inputs["strain_ratio_change"], -0.4, rtol=1e-9)
    axial = PARAMS["k_a"] * -0.4 + PARAMS["a0"] + PARAMS["a1"] * indentation
    radial = PARAMS["k_r"] * hoop + PARAMS["r0"] + PARAMS["r1"] * indentation
    np.testing.assert_allclose(result.sigma_1["fitted"], record.axial_stress + cell * axial, rtol=1e-9)
    np.testing.assert_allclose(result.sigma_3["fitted"], cell + cell * radial, rtol=1e-9)
    # with exact parameters the band is the cross-validation error alone, σc·0.02, and φ' follows by
    # d φ'/dσ1 = σ3/((σ1 + σ3)√(σ1σ3)), dφ'/dσ3 = −σ1/((σ1 + σ3)√(σ1σ3)) (radians)
    np.testing.assert_allclose(result.std["sigma_1"], cell * CV_RMS, rtol=1e-12)
    np.testing.assert_allclose(result.std["sigma_3"], cell * CV_RMS, rtol=1e-12)
    s1, s3 = result.sigma_1["fitted"], result.sigma_3["fitted"]
    root = (s1 + s3) * np.sqrt(s1 * s3)
    expected = np.degrees(cell * CV_RMS * np.hypot(s3 / root, s1 / root))
    np.testing.assert_allclose(result.std["friction_angle"], expected, rtol=1e-9)
    # a parameter variance adds g C gᵀ: var(a0) = v adds v to the axial variance of every record
    covariance = np.zeros((6, 6))
    covariance[list(sorted(PARAMS)).index("a0"), list(sorted(PARAMS)).index("a0")] = 0.03**2
    wider = correct.correct_record(record, SPECIMEN, _corrections(covariance=covariance))
    np.testing.assert_allclose(wider.std["sigma_1"], cell * math.hypot(CV_RMS, 0.03), rtol=1e-12)


def test_a_record_outside_the_fitted_range_is_warned_about_by_name():
    record = _record()
    inputs = datasets.measured_inputs(
        record.axial_strain, record.radial_strain, np.full(41, -0.4), 20e3, 2e-3, 1.4e6, 0.02, 0.15
    )
    stiffness = float(inputs["stiffness_ratio"][0])  # 1.4e6 · 2e-3 / (2e4 · 0.02) = 7
    assert stiffness == pytest.approx(7.0, rel=1e-12)
    inside = {"stiffness_ratio": (1.0, 10.0), "size_ratio": (0.1, 0.2)}
    with __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("error")
        assert correct.correct_record(record, SPECIMEN, _corrections(inside)).warnings == ()
    outside = {"stiffness_ratio": (1.0, 5.0), "size_ratio": (0.1, 0.2)}
    with pytest.warns(
        UserWarning, match=r"stiffness_ratio of the record spans 7 to 7, outside the fitted 1 to 5"
    ):
        result = correct.correct_record(record, SPECIMEN, _corrections(outside))
    assert len(result.warnings) == 1


def test_specimen_units_are_converted_once_and_bad_values_refused():
    assert SPECIMEN == (0.15, 0.02, 0.002, 1.4e6)
    with pytest.raises(ValueError, match=r"membrane_thickness_mm = -2.*positive"):
        correct.Specimen.from_mm_kpa(150.0, 20.0, -2.0, 1400.0)
    with pytest.raises(ValueError, match="specimen_diameter_mm = nan"):
        correct.Specimen.from_mm_kpa(math.nan, 20.0, 2.0, 1400.0)


CLASSICAL = ("uncorrected", "astm", "henkel_gilbert", "kuerbis_vaid")


def _example():
    from calibrate import evaluate

    return evaluate.read_example_record()


def test_on_the_shipped_held_out_record_the_fitted_correction_beats_none_and_the_classical_ones():
    from calibrate import evaluate

    record, specimen, internal_1, internal_3 = _example()
    assert record.comments[0].startswith("synthetic")
    # the shipped model's provenance: fitted on the calibration grid, none of whose members is this one
    shipped = correct.default_corrections()
    assert shipped.provenance["cases"] >= 30
    errors = evaluate.friction_angle_errors(record, specimen, internal_1, internal_3, shipped)
    for method in CLASSICAL:
        assert errors["fitted"][0] < errors[method][0], (method, errors)
        assert errors["fitted"][1] < errors[method][1], (method, errors)


def test_the_shipped_correction_is_the_fit_of_the_shipped_calibration_table():
    from importlib import resources

    from calibrate import fit

    table = datasets.load_table(resources.files("calibrate") / "data" / "calibration_table.npz")
    shipped = correct.default_corrections()
    assert shipped.provenance["rows"] == table.num_rows and shipped.provenance["cases"] == table.num_cases
    refit = fit.fit(shipped.model, table)
    for name, value in shipped.params.items():
        assert refit.params[name] == pytest.approx(value, rel=1e-6, abs=1e-9), name
    # the input ranges stored for the out-of-range warning are the table's
    low, high = shipped.input_ranges["stiffness_ratio"]
    assert low == pytest.approx(table.inputs["stiffness_ratio"].min(), rel=1e-12)
    assert high == pytest.approx(table.inputs["stiffness_ratio"].max(), rel=1e-12)


def test_membrax_correct_writes_the_csv_and_the_plot_of_the_example(tmp_path, capsys):
    from calibrate import evaluate
    from membrax import cli

    record = _example()[0]
    values = evaluate.example_arguments(record.comments)
    out = tmp_path / "corrected.csv"
    with correct.example_record_path() as path:
        argv = ["correct", str(path), "--out", str(out)]
        for flag, value in zip(
            (
                "--specimen-diameter-mm",
                "--particle-size-mm",
                "--membrane-thickness-mm",
                "--membrane-modulus-kpa",
            ),
            values,
            strict=True,
        ):
            argv += [flag, f"{value!r}"]
        assert cli.main(argv) == 0
    report = capsys.readouterr().out
    assert "fitted" in report and "written" in report
    assert out.exists() and out.with_suffix(".png").stat().st_size > 10_000
    lines = out.read_text().splitlines()
    header = next(line for line in lines if not line.startswith("#")).split(",")
    table = np.loadtxt([line for line in lines if not line.startswith("#")][1:], delimiter=",")
    assert table.shape == (record.axial_strain.size, len(header))
    # the uncorrected columns are the record itself; the fitted φ' is that of its own σ1, σ3
    column = {name: table[:, i] for i, name in enumerate(header)}
    np.testing.assert_allclose(column["sigma_1_uncorrected [kPa]"], 1e-3 * record.axial_stress, rtol=1e-7)
    s1, s3 = column["sigma_1_fitted [kPa]"], column["sigma_3_fitted [kPa]"]
    finite = np.isfinite(s1)
    np.testing.assert_allclose(
        column["friction_angle_fitted [deg]"][finite],
        np.degrees(np.arcsin((s1 - s3) / (s1 + s3)))[finite],
        rtol=1e-6,
    )


@pytest.mark.slow
def test_on_a_fresh_held_out_simulation_the_fitted_correction_beats_none_and_the_classical_ones(tmp_path):
    """A member off every grid line (55 kPa, 2.5 mm, 1800 kPa), simulated here, corrected by each method."""
    from calibrate import evaluate, grid
    from membrax.config import TriaxialConfig
    from membrax.io import read_results
    from membrax.sweep import run_sweep

    specimen = {"particles_across": 6, "layers": 10}
    base = TriaxialConfig(name="held_out", **{**grid.base_fields(), **specimen})
    held = {"cell_pressure_kpa": [55.0], "membrane_thickness_mm": [2.5], "membrane_modulus_kpa": [1800.0]}
    for field, values in held.items():
        for _, design in grid.CALIBRATION.values():
            assert values[0] not in design.get(field, ())  # off the grid
    run_sweep(base, held, tmp_path, progress=False)
    errors = evaluate.held_out_errors(read_results(tmp_path / "sweep.nc"))["pooled"]
    for method in CLASSICAL:
        assert errors["fitted"][0] < errors[method][0], (method, errors)


def test_the_calibration_grid_spans_the_ranges_the_correction_is_for():
    """σc 10–100 kPa, t_m 1–5 mm, E_m 700–2800 kPa, D/D_s 1/6 to 1/10 (D_s from the FCC platen area)."""
    from calibrate import grid
    from membrax.spheres import packing

    values = {"cell_pressure_kpa": set(), "membrane_thickness_mm": set(), "membrane_modulus_kpa": set()}
    ratios = []
    for specimen, design in grid.CALIBRATION.values():
        for field, chosen in design.items():
            values[field] |= set(chosen)
        fcc = packing.fcc_specimen(
            0.025, width_spheres=specimen["particles_across"], height_layers=specimen["layers"]
        )
        ratios.append(0.025 / math.sqrt(4.0 * float(fcc.cross_section_area) / math.pi))
    assert (min(values["cell_pressure_kpa"]), max(values["cell_pressure_kpa"])) == (10.0, 100.0)
    assert (min(values["membrane_thickness_mm"]), max(values["membrane_thickness_mm"])) == (1.0, 5.0)
    assert (min(values["membrane_modulus_kpa"]), max(values["membrane_modulus_kpa"])) == (700.0, 2800.0)
    assert max(ratios) >= 1 / 6 and min(ratios) == pytest.approx(1 / 10, rel=2e-3)
