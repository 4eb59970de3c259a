"""Random packings compacted in a mould (membrax.spheres.compaction): measures, mould law, the packings.

The packings are checked against the reference states of equal spheres (Agnolin & Roux 2007; Silbert
2010): random close packing ≈ 0.64 for frictionless compaction, a looser packing with friction.
"""

import dataclasses
import json
import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax.errors import ErrorCode, SimulationError
from membrax.spheres import compaction as compaction_module
from membrax.spheres import fire
from membrax.spheres.compaction import Compaction, compact, packing_measures, random_packing
from membrax.spheres.fcc import fcc_specimen
from membrax.spheres.fire import FireRelaxer
from membrax.spheres.grading import Grading, sample_diameters
from membrax.spheres.mould import mould_energy
from membrax.spheres.neighbors import pair_neighbor_fn as real_pair_neighbor_fn

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


def test_a_neighbour_list_too_small_is_grown_and_no_contact_is_dropped(monkeypatch):
    """The growth chunks run through membrax.driver.drive: a chunk whose list overflows is run again from its
    start with a larger list (driver.grow_tables) where the compaction used to stop. The grown list holds
    exactly the candidate pairs of an ample allocation at the same positions, and the run ends where one
    whose list never overflowed ends, to 1e-4 in the growth factor. Not to the bit (measured 6e-6 after
    100 steps): the grown list's cell list has another capacity (93 per cell against 18), so its pairs
    come in another slot order and the per-sphere sums round differently, and the quench's v = 0 on an
    uphill step is discontinuous in the forces. Fresh lists of 1.25 and 3 times the capacity give the
    same bits."""
    volume = math.pi * (2.5 * DIAMETER) ** 2 * 5 * DIAMETER
    diameters = sample_diameters(Grading.equal(DIAMETER), 0.58 * volume)
    grown = []
    real_grow = compaction_module.grow_tables

    def recording_grow(states, error, frame, **kwargs):
        result = real_grow(states, error, frame, **kwargs)
        grown.append((int(error), frame, states[0], result[0]))
        return result

    monkeypatch.setattr(compaction_module, "grow_tables", recording_grow)
    packings = {}
    for multiplier in (0.2, 3.0):
        monkeypatch.setattr(
            compaction_module,
            "pair_neighbor_fn",
            lambda *args, m=multiplier, **kwargs: real_pair_neighbor_fn(
                *args, **kwargs, capacity_multiplier=m
            ),
        )
        packings[multiplier] = compact(
            diameters, 5 * DIAMETER, 5 * DIAMETER, seed=3, max_steps=100, chunk_steps=100
        )
    assert [error for error, *_ in grown] == [int(ErrorCode.NEIGHBOR_OVERFLOW)]  # the tiny list, once
    _, frame, before, after = grown[0]
    count = before.position.shape[0]
    ample = real_pair_neighbor_fn(  # the same frame with three times the capacity
        -frame.origin, frame.box - frame.origin, frame.cutoff, frame.skin, 0.0, capacity_multiplier=3.0
    ).allocate(before.position)

    def pairs(idx):
        return {(int(i), int(j)) for i, j in np.asarray(idx).T if i < count}

    assert not bool(after.neighbors.did_buffer_overflow)
    assert pairs(after.neighbors.idx) == pairs(ample.idx) and len(pairs(ample.idx)) > 100
    small, large = packings[0.2], packings[3.0]
    assert small.steps == large.steps == 100
    assert small.growth == pytest.approx(large.growth, rel=1e-4)


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
    from membrax import assemble
    from membrax.config import TriaxialConfig

    monkeypatch.setenv("MEMBRAX_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(assemble, "_RANDOM_SPECIMENS", {})
    config = TriaxialConfig(packing="random", specimen_diameter_mm=100.0, specimen_height_mm=100.0)
    first = assemble.build_specimen(config)
    (saved,) = (tmp_path / "specimens").glob("*.npz")
    monkeypatch.setattr(assemble, "_RANDOM_SPECIMENS", {})

    def compact_again(*args, **kwargs):
        raise AssertionError("the cached packing was compacted again")

    monkeypatch.setattr(assemble, "random_packing", compact_again)
    second = assemble.build_specimen(config)
    np.testing.assert_array_equal(np.asarray(second.position), np.asarray(first.position))
    np.testing.assert_array_equal(np.asarray(second.radius), np.asarray(first.radius))
    assert (second.diameter, second.height, second.seed) == (first.diameter, first.height, first.seed)
    np.testing.assert_equal(dict(second.packing_measures), dict(first.packing_measures))  # NaN == NaN
    # Another seed is another specimen: not the cached one.
    other = TriaxialConfig(
        packing="random", specimen_diameter_mm=100.0, specimen_height_mm=100.0, packing_seed=1
    )
    with pytest.raises(AssertionError, match="compacted again"):
        assemble.build_specimen(other)
    assert saved.exists()


# A jammed packing's relaxed stress jumps where its contact network rearranges (the paper-size seed-8
# specimen in float64: 7.73 kPa at one growth, 11.29 kPa at the next float64, nothing in the ±2 % window
# around 10 kPa; 7.9 and 10.9 kPa were reported for seed 1 elsewhere).
JUMP_AT, STRESS_BELOW, STRESS_ABOVE = 1.0192651, 7.9e3, 10.9e3


class _JumpRelaxer(FireRelaxer):
    """Spheres of 25 mm, k_n = 1e7 N/m, whose relaxed stress is a step at s* (as the device sees s).

    Each relaxation is at rest already (ratio 5e-4, no FIRE step), and returns positions tagged with the
    growth they were relaxed at (the compensation holds s), so a test can tell which state came back.
    """

    def __init__(self, dtype, below=STRESS_BELOW, above=STRESS_ABOVE):
        self.particles = SimpleNamespace(radius=jnp.full(4, 0.5 * DIAMETER))
        self.params = SimpleNamespace(contact=SimpleNamespace(normal_stiffness=1e7))
        self.dtype, self.below, self.above = np.dtype(dtype), below, above
        self.growths = []

    def relax(self, position, growth, target, tolerance, max_steps, on_chunk=None, settle=True):
        self.growths.append(growth)
        above = self.dtype.type(growth) >= self.dtype.type(JUMP_AT)
        tagged = (np.zeros(3, self.dtype), np.full(3, growth))
        return tagged, self.above if above else self.below, 5e-4, 0

    def search(self, accept_jump=True):
        """relax_to_stress to 10 kPa ± 2 % from s = 1.019265, 1e-7 below s* in float64 (the first secant
        step, (10 − 7.9) kPa over k_n/D = 4e8 Pa, is Δ ln s = 5.25e-6: past s*) and on s* in float32
        (whose spacing there, 1.2e-7, is wider)."""
        start = (np.zeros(3, self.dtype), np.full(3, 1.019265))
        return self.relax_to_stress(start, 1.019265, 1e4, 0.02, 1e-3, 400_000, accept_jump=accept_jump)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize(
    "below, above, accepted",
    [
        (7.9e3, 10.9e3, 10.9e3),  # |ln 0.79| = 0.24 against |ln 1.09| = 0.086: above (also −21 % vs +9 %)
        (9.0e3, 13.0e3, 9.0e3),  # |ln 0.9| = 0.105 against |ln 1.3| = 0.26: below
        (2.5e3, 30.0e3, 30.0e3),  # |ln 0.25| = 1.39 against |ln 3| = 1.10: above (a difference: below)
    ],
)
def test_a_stress_jump_over_the_window_ends_on_the_closest_state_at_rest(dtype, below, above, accepted):
    """The search closes its bracket on the two neighbouring growths of the dtype around s* and accepts the
    side nearer 10 kPa in ratio, with the positions relaxed at that side's growth; both sides are reported.

    Calls: two bracket s*, at most max(|σ − 10 kPa|)/(k_n/D) apart in ln s (one secant step); halving that
    down to one spacing of the dtype at s (2.3e-16 in float64, 1.2e-7 in float32) takes, for the first pair
    in float64, log2(5.25e-6/2.3e-16) ≈ 35 calls. A secant step, cutting the bracket in the ratio of the
    stress errors, can shrink it by less than half: the search may take up to twice a bisection's calls.
    """
    relaxer = _JumpRelaxer(dtype, below, above)
    position, growth, stress, ratio, steps, converged, jump = relaxer.search()
    kind = np.dtype(dtype).type
    assert (stress, ratio, steps, converged) == (accepted, 5e-4, 0, True)
    side = kind(JUMP_AT) if accepted == above else np.nextafter(kind(JUMP_AT), kind(0))
    assert kind(growth) == side  # the latest growth on the accepted side, as the device sees it
    np.testing.assert_array_equal(position[1], growth)  # the positions relaxed at that growth
    assert (jump["stress_below"], jump["stress_above"], jump["stress_accepted"]) == (below, above, accepted)
    assert kind(jump["growth_above"]) == kind(JUMP_AT)
    assert kind(jump["growth_below"]) == np.nextafter(kind(JUMP_AT), kind(0))
    first = max(1e4 - below, above - 1e4) / (1e7 / DIAMETER)
    bisections = math.ceil(math.log2(first / (np.finfo(dtype).eps * JUMP_AT)))
    assert len(relaxer.growths) <= 2 * (1 + bisections), relaxer.growths


def test_a_search_that_can_make_no_progress_ends_naming_its_state():
    """The same jump with acceptance off: once the bracket has closed, every call repeats an end's growth
    (no FIRE step, the bracket unchanged); after fire.IDLE_CALLS (64) of them the search raises, naming s,
    the stress, the ratio, the steps, the calls and both ends of the bracket."""
    accepting = _JumpRelaxer("float64")
    accepting.search()
    closing = len(accepting.growths)  # the calls that close the bracket
    relaxer = _JumpRelaxer("float64")
    with pytest.raises(SimulationError) as raised:
        relaxer.search(accept_jump=False)
    assert len(relaxer.growths) == closing + fire.IDLE_CALLS
    message = str(raised.value)
    below = repr(float(np.nextafter(JUMP_AT, 0.0)))
    for part in (
        f"{fire.IDLE_CALLS} calls in a row",
        f"bracket below s = {below} at 7900 Pa, above s = {JUMP_AT!r} at 10900 Pa",
        "unbalanced-force ratio 0.0005",
        "0 FIRE steps",
        f"{closing + fire.IDLE_CALLS} calls",
        "stress_tolerance",
    ):
        assert part in message, message


class _SettledShortRelaxer(_JumpRelaxer):
    """Spheres that jam at s*: at rest their stress rises from 2 kPa at s* with slope k_n/D = 4e8 Pa per
    unit ln s; below s* they are unjammed. Grown from an unjammed state, a relaxation that may stop once its
    stress settles (``settle``) stops on a dense fluid's 30 kPa (ratio 0.03, short of rest); one that must
    reach rest, or starts from a jammed state at rest, finds the stress at rest. Positions carry a flag
    (``position[0][0]`` 1: relaxed from a jammed state at rest) and the growth (the compensation)."""

    def relax(self, position, growth, target, tolerance, max_steps, on_chunk=None, settle=True):
        self.growths.append(growth)
        kind = self.dtype.type
        if kind(growth) < kind(JUMP_AT):
            return (np.zeros(3, self.dtype), np.full(3, growth)), 0.0, 5e-4, 1000
        if settle and position[0][0] == 0.0:
            return (np.zeros(3, self.dtype), np.full(3, growth)), 30e3, 0.03, 1000
        at_rest = 2e3 + 1e7 / DIAMETER * math.log(float(growth) / JUMP_AT)
        return (np.ones(3, self.dtype), np.full(3, growth)), at_rest, 5e-4, 1000


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_a_bracket_closed_on_a_state_short_of_rest_reopens_and_reaches_the_window(dtype):
    """The calibration grid's 300 × 600 mm seed-0 specimen (float64): its first jammed state settled at
    32.7 kPa short of rest, every lower growth was unjammed, and the bracket closed on them; relaxed on, that
    state was at 2.0 kPa. The search relaxes the end, finds it under the target, drops it from the bracket
    and goes on: the stress at rest reaches 10 kPa at ln(s/s*) = 8 kPa / 4e8 Pa = 2e-5, in the window, with
    no jump recorded."""
    relaxer = _SettledShortRelaxer(dtype)
    position, growth, stress, ratio, _, converged, jump = relaxer.search()
    assert converged and jump is None
    assert abs(stress / 1e4 - 1.0) < 0.02 and ratio == 5e-4
    assert position[0][0] == 1.0  # a state relaxed to rest
    expected = JUMP_AT * math.exp((1e4 - 2e3) / (1e7 / DIAMETER))
    assert abs(growth / expected - 1.0) < 0.02 * 1e4 / (1e7 / DIAMETER)  # the window, in s


class _OverflowingRelaxer(FireRelaxer):
    """A relaxer whose neighbour list overflows at every measure, even right after it is allocated."""

    def __init__(self):
        self.neighbors, self.dt, self.chunk_steps, self.allocations = None, 1e-5, 1000, 0
        self.frame = SimpleNamespace(allocate=self.allocate)

    def allocate(self, position):
        self.allocations += 1
        return "a neighbour list"

    def _grow(self, carry, error):
        assert error == ErrorCode.NEIGHBOR_OVERFLOW
        return carry._replace(neighbors=self.allocate(carry.position))

    def _measure(self, position, compensation, neighbors, growth):
        return jnp.asarray(1e4), jnp.asarray(5e-4), jnp.asarray(True)


@pytest.mark.parametrize("finite", [True, False])
def test_a_neighbour_list_that_overflows_again_after_allocation_ends_the_relaxation(finite):
    """Measure (overflow), allocate for these positions, measure (overflow again): 2 calls, 2 allocations (the
    first list and the reallocation), then SimulationError naming s, the steps, the calls and the cause."""
    relaxer = _OverflowingRelaxer()
    position = jnp.zeros((2, 3)) if finite else jnp.full((2, 3), jnp.nan)
    with pytest.raises(SimulationError) as raised:
        relaxer.relax((position, jnp.zeros((2, 3))), 1.25, 1e4, 1e-3, 400_000)
    assert relaxer.allocations == 2
    message = str(raised.value)
    assert "s = 1.25" in message and "0 FIRE steps, 2 calls" in message, message
    assert ("positions finite" if finite else "positions NOT finite") in message, message


def test_chunks_of_no_steps_are_refused():
    """chunk_steps = 0 would never advance the growth loop: ValueError naming the argument."""
    with pytest.raises(ValueError, match="chunk_steps"):
        compact(np.full(8, DIAMETER), 5 * DIAMETER, 5 * DIAMETER, chunk_steps=0)


def _jumped_packing():
    """A two-sphere Compaction that accepted the jump of _JumpRelaxer (hand values)."""
    return Compaction(
        position=np.array([[0.0, 0.0, 0.0125], [0.0, 0.0, 0.0375]]),
        radius=np.full(2, 0.0125),
        diameter=0.25 / JUMP_AT,
        height=0.5 / JUMP_AT,
        growth=JUMP_AT,
        steps=37_000,
        seconds=25.0,
        stress=STRESS_ABOVE,
        unbalanced_force_ratio=5e-4,
        converged=True,
        measures={"num_spheres": 2, "solid_fraction": 0.6},
        seed=1,
        stress_jump={
            "stress_below": STRESS_BELOW,
            "stress_above": STRESS_ABOVE,
            "growth_below": float(np.nextafter(JUMP_AT, 0.0)),
            "growth_above": JUMP_AT,
            "stress_accepted": STRESS_ABOVE,
        },
    )


def test_a_saved_packing_keeps_its_stress_jump_and_an_older_file_loads_without_one(tmp_path):
    """save/load round-trips the jump to the bit; a file written before the field (its scalars without
    ``stress_jump``) loads with None and every other value as written."""
    packing = _jumped_packing()
    packing.save(tmp_path / "jumped.npz")
    loaded = Compaction.load(tmp_path / "jumped.npz")
    assert loaded.stress_jump == packing.stress_jump
    assert loaded.stress_jump["growth_below"] == 1.0192650999999997
    assert (loaded.stress, loaded.growth, loaded.seed) == (10.9e3, JUMP_AT, 1)

    # The scalars save wrote before stress_jump existed.
    written = ("diameter", "height", "growth", "steps", "seconds", "stress", "unbalanced_force_ratio")
    scalars = {name: getattr(packing, name) for name in (*written, "converged", "measures", "seed")}
    np.savez(
        tmp_path / "old.npz", position=packing.position, radius=packing.radius, scalars=json.dumps(scalars)
    )
    old = Compaction.load(tmp_path / "old.npz")
    assert old.stress_jump is None
    np.testing.assert_array_equal(old.position, packing.position)
    assert (old.stress, old.growth, old.steps, old.converged, old.measures) == (
        10.9e3,
        JUMP_AT,
        37_000,
        True,
        {"num_spheres": 2, "solid_fraction": 0.6},
    )


def test_a_jumped_packing_says_so_in_its_specimen_and_the_run_metadata():
    """The specimen's packing measures carry the compaction stress and the jump's sides (Pa), and a run's
    specimen record gives them in kPa (hand values: 10.9, 7.9 and 10.9 kPa); a packing that reached its
    window carries the stress alone."""
    from membrax.run_records import specimen_metadata

    packing = _jumped_packing()
    measures = dict(packing.specimen().packing_measures)
    assert (measures["compaction_stress"], measures["compaction_stress_below"]) == (10.9e3, 7.9e3)
    assert measures["compaction_stress_above"] == 10.9e3
    record = specimen_metadata(packing.specimen())
    assert record["compaction_stress_kpa"] == pytest.approx(10.9, rel=1e-12)
    assert record["compaction_stress_below_kpa"] == pytest.approx(7.9, rel=1e-12)
    assert record["compaction_stress_above_kpa"] == pytest.approx(10.9, rel=1e-12)
    reached = specimen_metadata(
        Compaction(
            **{**{f.name: getattr(packing, f.name) for f in dataclasses.fields(packing)}, "stress_jump": None}
        ).specimen()
    )
    assert "compaction_stress_below_kpa" not in reached and reached["compaction_stress_kpa"] == pytest.approx(
        10.9
    )
