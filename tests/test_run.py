"""The membrane triaxial test as a run: stresses against force balance, a vanishing membrane, resume, CLI."""

import math

import numpy as np
import pytest

from membrax import cli, packing
from membrax.config import TriaxialConfig
from membrax.membrane_triaxial import membrane_test
from membrax.run import CHECKPOINT_NAME, run_test

SMALL = dict(
    name="small",
    particles_across=4,
    layers=5,
    membrane_edges_per_diameter=2.5,
    target_axial_strain=0.002,
    inertial_number=1e-2,
    chunk_steps=500,
    record_every_fine=25,
    record_every_coarse=100,
    fine_until_strain=0.001,
    checkpoint_every_chunks=2,
    consolidation_max_steps=3000,
    float64=True,
)


def _consolidated(modulus_kpa):
    specimen = packing.fcc_specimen(0.025, 4, 5)
    test = membrane_test(
        specimen, cell_pressure_kpa=10.0, membrane_thickness_mm=5.0, membrane_modulus_kpa=modulus_kpa
    )
    state, records = test.consolidate(max_steps=4000, chunk_steps=1000, record_every=100, tolerance=0.01)
    last = {
        name: float(np.asarray(getattr(records, name))[-1, 0])
        for name in ("ram_force", "platen_axial_stress")
    }
    return test, state, records, last


def test_ram_force_balances_spheres_and_membrane_and_internal_stresses_match_love_weber():
    """Paper membrane (1400 kPa, 5 mm), 10 kPa, a 4 × 4 × 5 specimen consolidated (f64).

    - The servo holds the ram at σc A₀: ram force = platen–sphere force + the membrane's axial pull on the
      platen, and ram / A₀ = σc within 1 %;
    - internal axial and radial stresses (paper §4.3) agree with the Love–Weber stress within 10 %
      (they differ by the membrane's contact dyads: LW counts the axial forces of the membrane on the
      spheres, the platen stress does not; the tolerance covers it at this size);
    - the internal radial force equals −Σ F·r̂ of the recorded sphere forces (hand sum).
    """
    test, state, records, last = _consolidated(1400.0)
    area = test.platen_area
    sphere = float(records.platen_axial_stress[-1, 0]) * area
    reaction = np.asarray(state.membrane.platen_reaction)
    # the record's reaction is one step older than the state's; the ram is their balance at equilibrium
    membrane_pull = 0.5 * (reaction[1, 2] - reaction[0, 2])
    assert abs(last["ram_force"] - (sphere + membrane_pull)) < 0.01 * test.cell_pressure * area
    assert abs(last["ram_force"] / area / test.cell_pressure - 1.0) < 0.01
    for kind in ("axial", "radial"):
        internal = float(getattr(records, f"internal_{kind}_stress")[-1, 0])
        love_weber = float(getattr(records, f"love_weber_{kind}_stress")[-1, 0])
        assert abs(internal / love_weber - 1.0) < 0.10, (kind, internal, love_weber)
    position = np.asarray(state.dem.position)
    axis = np.asarray(state.membrane.clamp_position[0])[:, :2].mean(axis=0)
    offset = position[:, :2] - axis
    force = np.asarray(state.membrane.sphere_force)
    inward = -np.sum(np.sum(force[:, :2] * offset, axis=1) / np.linalg.norm(offset, axis=1))
    recorded = float(records.membrane_radial_force[-1, 0])
    assert recorded == pytest.approx(inward, rel=0.02)


def _compare(a, b):
    assert list(a.data_vars) == list(b.data_vars)
    for name in a.data_vars:
        np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), err_msg=name)


def test_interrupted_and_resumed_run_equals_an_uninterrupted_one(tmp_path):
    config = TriaxialConfig(**SMALL)
    whole = run_test(config, tmp_path / "whole", progress=False)
    assert int(whole.metadata["shear_steps"]) > 0
    with pytest.raises(KeyboardInterrupt):
        run_test(config, tmp_path / "cut", progress=False, interrupt_after_chunks=5)
    assert (tmp_path / "cut" / CHECKPOINT_NAME).exists()
    resumed = run_test(config, tmp_path / "cut", resume=True, progress=False)
    _compare(whole.results, resumed.results)
    _compare(whole.consolidation, resumed.consolidation)
    # Stage 1 servo-controls the ram: at its last record ram / A₀ = σc, with A₀ recovered by hand from the
    # recorded area A = A₀ (1 − ε_v) / (1 − ε_a).
    end = {
        name: float(whole.consolidation[name][-1].squeeze())
        for name in ("ram_force", "platen_area", "axial_strain", "volumetric_strain")
    }
    initial_area = end["platen_area"] * (1.0 - end["axial_strain"]) / (1.0 - end["volumetric_strain"])
    assert end["ram_force"] / initial_area == pytest.approx(1e3 * config.cell_pressure_kpa, rel=0.01)
    assert end["axial_strain"] > 0.0  # the platens moved in
    # The results folder holds what the issue names.
    names = {p.name for p in (tmp_path / "whole").iterdir()}
    assert {"results.nc", "results.csv", "consolidation.nc", "summary.md", "config.toml"} <= names
    assert {"fig5_friction.png", "fig6_additional_stress.png"} <= names
    # Strains restart at the start of shearing: the first record is the end of consolidation.
    strain = np.asarray(whole.results["axial_strain"])
    # Hand count: each phase runs whole records, so its steps round up to a multiple of its record interval;
    # the top platen moves at ε̇ H_start, so ε_a = ε̇ Δt × steps exactly.
    rate = config.inertial_number / (
        config.particle_diameter * math.sqrt(config.particle_density_kg_m3 / 1e4)
    )
    dt = whole.metadata["dt_s"]
    per_strain = 1.0 / (rate * dt)
    fine = math.ceil(math.ceil(config.fine_until_strain * per_strain) / 25) * 25
    coarse = (
        math.ceil(math.ceil((config.target_axial_strain - config.fine_until_strain) * per_strain) / 100) * 100
    )
    assert whole.metadata["shear_steps"] == fine + coarse
    assert strain[0] == 0.0 and strain[-1] == pytest.approx(rate * dt * (fine + coarse), rel=1e-6)
    assert math.isfinite(float(whole.results["external_friction_angle_deg"][-1]))


def test_cli_run_reports_bad_configuration_fields(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("cell_pressure_kpa = -10.0\nmembrane_thickness = 5.0\n")
    assert cli.main(["run", str(bad), "--out", str(tmp_path / "out")]) == 2
    message = capsys.readouterr().err
    assert "cell_pressure_kpa" in message and "membrane_thickness_mm" in message
    assert not (tmp_path / "out").exists()  # refused before anything was built or written
    good = tmp_path / "good.toml"
    good.write_text("layers = 5\n")
    assert cli.main(["run", str(good), "--set", "particles_across=-1", "--out", str(tmp_path / "o")]) == 2
    assert "particles_across" in capsys.readouterr().err
