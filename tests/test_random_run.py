"""A test on a random specimen from its configuration (packing = "random"): the specimen, the grading
it was sampled from and the sampled fractions in the results, the external stresses by definition, the
mobilised friction below Rowe's FCC bound."""

import meshio
import numpy as np
import pytest

from membrax import theory
from membrax.config import SMOKE_CONFIG, TriaxialConfig
from membrax.io.results import dataset_attrs_to_python
from membrax.io.vtk import read_pvd
from membrax.run import run_test
from membrax.triaxial import analysis

GRADING = ((20.0, 0.0), (25.0, 50.0), (30.0, 100.0))  # mm, % passing by mass


@pytest.mark.slow
def test_a_graded_random_specimen_runs_and_its_grading_reaches_the_results(tmp_path):
    config = TriaxialConfig(
        **{
            **SMOKE_CONFIG,
            "name": "random_graded",
            "packing": "random",
            "grading": GRADING,
            "specimen_diameter_mm": 125.0,
            "specimen_height_mm": 150.0,
            "vtk_every_steps": 100_000,  # the first and the last state
        }
    )
    result = run_test(config, tmp_path / "run", progress=False)
    specimen = dataset_attrs_to_python(result.results)["specimen"]
    # The VTK snapshot holds every sphere with its own radius: their volume over the specimen's cylinder is
    # the solid fraction reported, and every diameter lies within the grading's sizes.
    folder = tmp_path / "run" / "vtk"
    (_, first), *_ = read_pvd(folder / "specimen_particles.pvd")
    spheres = meshio.read(folder / first)
    radius = np.asarray(spheres.point_data["radius"])
    assert radius.size == specimen["num_spheres"]
    assert np.all((2e3 * radius >= 20.0 - 1e-9) & (2e3 * radius <= 30.0 + 1e-9))
    cylinder = np.pi / 4.0 * specimen["width_mm"] ** 2 * specimen["height_mm"] * 1e-9
    assert np.sum(4.0 / 3.0 * np.pi * radius**3) / cylinder == pytest.approx(
        specimen["solid_fraction"], rel=1e-5
    )
    np.testing.assert_allclose(spheres.point_data["diameter"], 2.0 * radius)
    # The membrane's first snapshot is its rest shape: both principal stretches 1 in every triangle.
    (_, first), *_ = read_pvd(folder / "specimen_membrane.pvd")
    membrane = meshio.read(folder / first)
    for name in ("stretch_largest", "stretch_smallest"):
        np.testing.assert_allclose(membrane.cell_data[name][0], 1.0, atol=1e-5)
    assert specimen["packing"] == "random"
    assert specimen["grading_size_mm"] == pytest.approx([20.0, 25.0, 30.0])
    assert specimen["grading_percent_passing"] == pytest.approx([0.0, 50.0, 100.0])
    # The sampled spheres follow the curve to within the rounding of the counts: one largest sphere's share
    # of the mass per bin (random_packing.sample_diameters).
    one_sphere = 100.0 * 30.0**3 / (specimen["num_spheres"] * 20.0**3)
    assert specimen["sampled_percent_passing"] == pytest.approx([0.0, 50.0, 100.0], abs=one_sphere)
    assert 0.45 < specimen["solid_fraction"] < 0.64  # a walled random packing, below random close packing
    # The cell pressure is the external radial stress at every record; Rowe's FCC peak bounds φ'.
    radial = analysis.record(result.results, "external_radial_stress")
    np.testing.assert_allclose(radial, config.cell_pressure, rtol=1e-6)
    angle = analysis.record(result.results, "love_weber_friction_angle")
    assert np.nanmax(angle) < theory.rowe_peak_friction_angle_deg(config.friction_angle_deg, theory.FCC)
    # At 10 kPa in 5 mm the summary sets the paper's numbers beside, saying they are of its FCC lattice.
    assert (config.cell_pressure_kpa, config.membrane_thickness_mm) == (10.0, 5.0)
    assert "FCC lattice (10 × 25 uniform spheres), another packing than this random one" in result.summary


@pytest.mark.slow
def test_a_sweep_over_cell_pressure_shares_one_random_specimen(tmp_path):
    """Two cell pressures on one random specimen (compacted once, to 10 kPa): each member's external
    radial stress is its own cell pressure, and both carry the same spheres."""
    from membrax import sweep

    base = TriaxialConfig(
        **{
            **SMOKE_CONFIG,
            "name": "random_sweep",
            "packing": "random",
            "specimen_diameter_mm": 125.0,
            "specimen_height_mm": 150.0,
        }
    )
    result = sweep.run_sweep(
        base, {"cell_pressure_kpa": [10.0, 40.0]}, tmp_path / "sweep", progress=False, num_devices=1
    )
    for pressure in (10.0, 40.0):
        member = sweep.member_records(result.dataset, cell_pressure_kpa=pressure)
        np.testing.assert_allclose(member["external_radial_stress"].values, 1e3 * pressure, rtol=1e-6)
        # The spheres carry about the cell pressure at the end of consolidation (the membrane's share is a
        # few kPa at most: 0.3 kPa measured for the 150 mm demo at 10 kPa).
        internal = float(member["internal_radial_stress"].values[0])
        assert internal == pytest.approx(1e3 * pressure, rel=0.3)
