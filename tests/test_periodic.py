"""The periodic triaxial cell against minimum-image symmetry, conservation laws and closed forms.

Each test checks a number against physics: the force of a pair across the boundary is that of the same pair
inside the box; momentum is conserved without damping; an affine compression of a simple cubic lattice
gives Δσ_xx = k_n Δε / d; the servo holds σc; a frictionless packing is near random close packing; a
vmap over two cell pressures is two single runs; and a list grown through the one table growth
(``driver.grow_tables``) holds every minimum-image pair a brute force finds, with its spring. Run in
float64 and float32 (``precision`` fixture).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax import driver
from membrax.driver import advance
from membrax.errors import ErrorCode
from membrax.spheres.contact import ContactParams
from membrax.spheres.integrate import DampingParams, make_particles
from membrax.spheres.neighbors import periodic_neighbor_fn
from membrax.spheres.periodic import cell_stiffness, love_weber_stress, periodic_pair_forces
from membrax.triaxial.periodic import (
    PeriodicRunner,
    cell_forces,
    periodic_cell,
    periodic_test,
)
from membrax.triaxial.periodic_packing import compact_periodic

DIAMETER = 0.025  # m, the paper's spheres
KN = 1e7  # N/m
#: Relative round-off tolerances: float32 resolves fractional positions to 6e-8 of the box, so an overlap
#: of 1e-3 d in a box of 3–4 d carries ~1e-4 relative error.
ROUNDOFF = {np.dtype("float64"): 1e-9, np.dtype("float32"): 2e-4}


def _pair(fraction_i, fraction_j, length, velocity_j, strain_rate, dtype):
    """One pair's contact (force on j, new spring) through the periodic path, one step from no spring."""
    fraction = jnp.asarray([fraction_i, fraction_j], dtype)
    velocity = jnp.asarray([[0.0, 0.0, 0.0], velocity_j], dtype)
    forces = periodic_pair_forces(
        fraction,
        jnp.zeros_like(fraction),
        velocity,
        jnp.zeros_like(fraction),
        jnp.full((2,), 0.5 * DIAMETER, dtype),
        jnp.asarray(length, dtype),
        jnp.asarray(strain_rate, dtype),
        jnp.asarray([[0], [1]], jnp.int32),
        jnp.zeros((1, 3), dtype),
        ContactParams.paper(),
        1e-6,
    )
    return np.asarray(forces.pair_force[0]), np.asarray(forces.pair_spring[0])


def test_a_pair_across_the_boundary_is_the_same_pair_inside(precision):
    """Minimum image: spheres at s = 0.78 and 0.02 along x in a box of 4 d are 0.24 L = 0.96 d apart through
    the boundary, as spheres at 0.40 and 0.64 inside; the same normal force k_n δ n (δ = 0.04 d) and, with
    the box compressing along x (ε̇_x = −2 /s), the same tangential spring from the image's affine velocity
    ε̇ ⊙ d, equal to that of the inside pair given the relative velocity ε̇ ⊙ d explicitly."""
    length = np.full(3, 4 * DIAMETER)
    rate = [-2.0, 0.0, 0.0]
    shift = [0.24, 0.05, 0.0]  # an oblique branch, so ε̇ ⊙ d has a tangential part
    inside_i, inside_j = [0.40, 0.50, 0.50], [0.64, 0.55, 0.50]
    across_i, across_j = [0.78, 0.97, 0.50], [0.02, 0.02, 0.50]
    branch = length * np.asarray(shift)
    affine = np.asarray(rate) * branch
    force_in, spring_in = _pair(inside_i, inside_j, length, affine, [0.0] * 3, precision)
    force_across, spring_across = _pair(across_i, across_j, length, [0.0] * 3, rate, precision)
    tol = ROUNDOFF[precision]
    scale = KN * DIAMETER
    overlap = DIAMETER - np.linalg.norm(branch)
    assert np.dot(force_in, branch / np.linalg.norm(branch)) == pytest.approx(KN * overlap, rel=10 * tol)
    np.testing.assert_allclose(force_across, force_in, rtol=0, atol=tol * scale)
    assert np.linalg.norm(spring_in) > 0.0
    np.testing.assert_allclose(spring_across, spring_in, rtol=10 * tol, atol=tol * scale * 1e-3)
    # The same pair in a box that does not deform feels no spring (the image's velocity is its own).
    _, still = _pair(across_i, across_j, length, [0.0] * 3, [0.0] * 3, precision)
    assert np.all(still == 0.0)


def _lattice(cells: int, spacing: float, jitter: float = 0.0, seed: int = 0):
    """A simple cubic lattice of cells³ spheres, spacing in diameters, fractional positions and box L."""
    grid = (
        np.stack(np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) + 0.5
    ) / cells
    if jitter:
        grid = (grid + jitter * np.random.default_rng(seed).uniform(-1, 1, grid.shape) / cells) % 1.0
    return grid, np.full(3, cells * spacing * DIAMETER)


def _pairs(idx, count):
    """The real pairs (i, j) of a pair table padded with ``count``."""
    return {(int(i), int(j)) for i, j in np.asarray(idx).T if i < count}


def _compressed_lattice_test(precision, damping):
    """A 4³ simple cubic lattice compressed to 0.97 of touching and jittered, in a cell at 100 kPa."""
    fraction, length = _lattice(4, 0.97, jitter=0.03)
    return periodic_test(
        jnp.asarray(fraction, precision), length, np.full(64, 0.5 * DIAMETER), 1e5, damping=damping
    )


def test_momentum_is_conserved_without_damping(precision):
    """Σ m u is conserved to round-off over 300 undamped steps of a compressed, jittered lattice whose
    spheres move at random (pair forces are equal and opposite across the boundary too), while the contact
    forces are large: the check is not trivially zero."""
    test = _compressed_lattice_test(precision, DampingParams.none())
    velocity = np.random.default_rng(1).normal(0.0, 0.05, (64, 3))
    state = test.control(test.initial_state, False)  # the box at rest: strain control at ε̇ = 0
    state = state.set(velocity=jnp.asarray(velocity, precision))
    mass = np.asarray(test.particles.mass, dtype=float)
    start = np.sum(mass[:, None] * velocity, axis=0)
    state = jax.jit(lambda s, p: advance(test.step_fn, s, p, 300))(state, test.params)
    assert int(state.error) == 0
    end = np.sum(mass[:, None] * np.asarray(state.velocity, dtype=float), axis=0)
    forces = cell_forces(state, test.particles, test.params, test.dt)
    impulse = 300 * test.dt * float(np.max(np.abs(np.asarray(forces.force))))
    assert impulse > 1e3 * np.max(np.abs(start))  # the forces could have changed the momentum a lot
    moved = np.sum(mass[:, None] * np.abs(velocity), axis=0)
    np.testing.assert_allclose(end, start, rtol=0, atol=10 * ROUNDOFF[precision] * np.max(moved))


def test_affine_compression_of_a_simple_cubic_lattice(precision):
    """Δσ_xx = k_n Δε / d (derived here): a simple cubic lattice of N spheres touching at spacing d has N
    contacts along x; shortening the box by Δε along x (spheres carried affinely) closes each by δ = d Δε,
    force k_n d Δε, branch d (1 − Δε), in V = N d³ (1 − Δε): σ_xx = N k_n d Δε d (1 − Δε) / V = k_n Δε / d,
    exactly; σ_yy = σ_zz = 0, and the servo's stiffness K_x = (1/V) Σ k_n d_x² = k_n (1 − Δε) / d. Run
    through the step: the box shortened at an imposed ε̇_x with the lattice at rest, which symmetry keeps in
    balance."""
    fraction, length = _lattice(3, 1.0)
    test = periodic_test(jnp.asarray(fraction, precision), length, np.full(27, 0.5 * DIAMETER), 1e5)
    steps = 400
    strain_per_step = 2.5e-6
    rate = strain_per_step / test.dt
    state = test.control(test.initial_state, False, [-rate, 0.0, 0.0])
    state = jax.jit(lambda s, p: advance(test.step_fn, s, p, steps))(state, test.params)
    assert int(state.error) == 0
    strain = 1.0 - float(state.box_length[0]) / length[0]
    # ε̇ is L̇/L: the box shrinks geometrically, (1 − ε̇Δt)^n.
    assert strain == pytest.approx(1.0 - (1.0 - strain_per_step) ** steps, rel=10 * ROUNDOFF[precision])
    forces = cell_forces(state, test.particles, test.params, test.dt)
    stress = np.asarray(love_weber_stress(forces, state.box_length))
    expected = KN * strain / DIAMETER
    tol = ROUNDOFF[precision]
    assert stress[0, 0] == pytest.approx(expected, rel=20 * tol + 1e-9)
    np.testing.assert_allclose(np.delete(stress.ravel(), 0), 0.0, atol=20 * tol * expected)
    stiffness = np.asarray(cell_stiffness(forces, state.box_length, KN))
    assert stiffness[0] == pytest.approx(KN * (1.0 - strain) / DIAMETER, rel=20 * tol + 1e-9)
    assert np.all(stiffness[1:] == 0.0)


@pytest.fixture(scope="module")
def loose_packing():
    """A loose packing: 150 spheres compressed from a gas at μ_c = 0.5 to 100 kPa (float32, users' use)."""
    with jax.enable_x64(False):
        diameters = np.random.default_rng(3).uniform(0.8, 1.2, 150) * DIAMETER
        test, state, records = compact_periodic(diameters, 1e5, 0.5, seed=3, tolerance=1e-3, max_steps=60_000)
    return test, state, records


def test_the_servo_holds_the_cell_pressure_on_each_axis(loose_packing):
    """At the end of the isotropic consolidation each σ_kk is within 1 % of σc (the stop criterion) and the
    unbalanced-force ratio below 1e-3; 4,000 steps later the servo still holds every axis within 1 %."""
    test, state, records = loose_packing
    assert records.step[-1] < 60_000  # it stopped on its criterion, not on the budget
    diagonal = np.diagonal(records.stress[-1])
    np.testing.assert_allclose(diagonal, 1e5, rtol=0.01)
    assert records.unbalanced_force_ratio[-1] < 1e-3
    with jax.enable_x64(False):
        state, later = test.runner.run(state, test.params, 4000, 2000, 100)
    np.testing.assert_allclose(np.diagonal(later.stress, axis1=1, axis2=2), 1e5, rtol=0.01)
    # A loose frictional packing: below random close packing, above random loose packing's ~0.55.
    assert 0.52 < records.solid_fraction[-1] < 0.62


def test_vmap_over_two_cell_pressures_is_two_single_runs(precision):
    """One step function vmapped over two states that differ in their target stress (one cell pressure
    each) gives, after 200 steps, what the two single runs give (the box servo at work in both)."""
    fraction, length = _lattice(3, 0.9995, jitter=2e-4)  # σ ≈ k_n δ / d² ≈ 2e5 Pa: between the targets
    # Viscous damping: local damping's sign(u) flips on round-off where u ≈ 0 (integrate.py's docstring),
    # which would part two runs that differ only in their summation order.
    damping = DampingParams.viscous(2000.0)
    test = periodic_test(
        jnp.asarray(fraction, precision), length, np.full(27, 0.5 * DIAMETER), 1e5, damping=damping
    )
    pressures = (1e5, 3e5)
    states = [test.control(test.initial_state, True, target=p) for p in pressures]

    def run(s):
        return advance(test.step_fn, s, test.params, 200)

    singles = [jax.jit(run)(s) for s in states]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *states)
    batched = jax.jit(jax.vmap(run))(stacked)
    for member, single in enumerate(singles):
        assert int(single.error) == 0
        np.testing.assert_allclose(
            np.asarray(batched.box_length[member]), np.asarray(single.box_length), rtol=ROUNDOFF[precision]
        )
        position = batched.fraction[member] + batched.fraction_compensation[member]
        expected = single.fraction + single.fraction_compensation
        np.testing.assert_allclose(np.asarray(position), np.asarray(expected), atol=ROUNDOFF[precision])
    # The two pressures moved the boxes apart: the comparison is not of two copies.
    assert not np.allclose(np.asarray(singles[0].box_length), np.asarray(singles[1].box_length), rtol=1e-6)
    assert math.isfinite(float(singles[1].box_length[0]))


def test_drained_compression_holds_the_lateral_stress_and_imposes_the_axial_strain(loose_packing):
    """Drained compression of the loose packing with the paper's law (μ = tan 25°) at I = 5e-3: the axial
    strain is the imposed log strain, 1 − exp(−ε̇ t) (to one step), the servo holds σ_xx and σ_yy within
    2.5 % of σc throughout (measured: 1.8 % at most, 2026-11-29), and the loose packing contracts (ε_v > 0;
    1.1 % at ε_a = 3 %) while q rises above 0.2 σc (q/p = 0.83 at 3 %)."""
    compaction, consolidated, _ = loose_packing
    with jax.enable_x64(False):
        state = consolidated
        test = periodic_test(
            state.fraction + state.fraction_compensation,
            np.asarray(state.box_length, dtype=float),
            compaction.particles.radius,
            1e5,
        )
        state, _ = test.consolidate(tolerance=1e-3, max_steps=20_000)
        rate = test.shear_rate(5e-3)
        state, records = test.shear(
            state, 0.03, 5e-3, record_every_fine=100, record_every_coarse=100, chunk_steps=4000
        )
    steps = records.step - records.step[0] + 100
    expected = 1.0 - np.exp(-rate * test.dt * steps)
    np.testing.assert_allclose(records.axial_strain, expected, rtol=1e-3, atol=rate * test.dt)
    assert records.axial_strain[-1] >= 0.03
    lateral = np.stack([records.stress[:, 0, 0], records.stress[:, 1, 1]])
    np.testing.assert_allclose(lateral, 1e5, rtol=0.025)
    assert records.volumetric_strain[-1] > 0.0
    assert records.deviator_stress[-1] > 0.2e5


def test_an_overflowing_list_is_grown_and_the_chunk_rerun(precision):
    """A list too small for its pairs (truncated to 40 slots, then rebuilt at the first step) sets the
    overflow bit; the runner allocates a larger periodic list from the chunk's start and reruns it, and the
    run ends where a run with an ample list ends (viscous damping: no sign flips on round-off)."""
    test = _compressed_lattice_test(precision, DampingParams.viscous(2000.0))
    ample = test.initial_state.set(list_length=2.0 * test.initial_state.length)  # rebuild at the first step
    short = ample.neighbors.set(idx=ample.neighbors.idx[:, :40], max_occupancy=40)
    truncated = ample.set(neighbors=short, pair_spring=ample.pair_spring[:40])
    reference, _ = test.runner.run(ample, test.params, 400, 200, 100)
    assert test.runner.reallocations == 0
    grown, records = test.runner.run(truncated, test.params, 400, 200, 100)
    assert test.runner.reallocations >= 1 and int(grown.error) == 0
    assert grown.neighbors.idx.shape[1] > 40 and records.step[-1] == 400
    box = float(test.initial_state.length[0])
    np.testing.assert_allclose(
        np.asarray(grown.position), np.asarray(reference.position), atol=ROUNDOFF[precision] * box
    )


def test_a_grown_periodic_list_holds_every_minimum_image_pair_and_carries_every_spring():
    """The periodic runner grows through driver.grow_tables. A jittered 6³ lattice (648 nearest pairs, 108
    across the boundary) whose list holds 80 % of its pairs (518 slots) and overflowed at the chunk's end,
    the box 3 % smaller there: the grown list has ceil(1.5 × 518) = 777 slots, holds every pair whose
    minimum-image distance is within the list's radius (brute force over all pairs), carries the spring
    set on each old pair to the same pair, was built at the start's box (list_length) and fits the end's
    box. A list whose cells alone the box outgrew is not grown by the factor (fewer than 1.5 × 648 slots)."""
    fraction, length = _lattice(6, 1.0, jitter=0.03)
    fraction, length = jnp.asarray(fraction), jnp.asarray(length)
    count = fraction.shape[0]
    frame = periodic_neighbor_fn(DIAMETER, 0.2 * DIAMETER, capacity_multiplier=1.0)
    init_fn, step_fn = periodic_cell(make_particles(jnp.full(count, 0.5 * DIAMETER), 2650.0), frame, 1e-6)
    runner = PeriodicRunner(step_fn, frame, None, count)
    overflow = np.array([ErrorCode.NEIGHBOR_OVERFLOW])

    def chunk_end(start):
        """The start at a box 3 % smaller, its list rebuilt there (as a chunk's end would be)."""
        neighbors, _ = frame.update(fraction, start.neighbors, 0.97 * length, 2.0 * length)
        return start.set(length=0.97 * length, neighbors=neighbors)

    full = frame.reallocate(fraction, length, length, 0)
    assert len(_pairs(full.idx, count)) == int(full.max_occupancy) == 648
    old = full.set(idx=full.idx[:, :518], max_occupancy=518)
    # A spring per slot that encodes its pair: (i, j, 0).
    spring = jnp.stack([old.idx[0], old.idx[1], jnp.zeros(518, old.idx.dtype)], axis=1).astype(float)
    start = init_fn(fraction, length, old, None).set(pair_spring=spring, list_length=2.0 * length)
    end = chunk_end(start)
    assert bool(end.neighbors.did_buffer_overflow)
    grown = runner.grow(start, overflow, end)
    new = grown.neighbors
    assert int(new.max_occupancy) == new.idx.shape[1] == math.ceil(driver.TABLE_GROWTH * 518) == 777
    branch = np.asarray(fraction[:, None] - fraction[None])
    distance = np.linalg.norm(np.asarray(length) * (branch - np.round(branch)), axis=-1)
    near = {(i, j) for i, j in zip(*np.nonzero(distance < 1.1 * DIAMETER), strict=True) if i < j}
    across = {(i, j) for i, j in near if np.linalg.norm(np.asarray(length) * branch[i, j]) > 1.1 * DIAMETER}
    assert len(near) == 648 and len(across) == 108 and near <= _pairs(new.idx, count)
    carried = np.asarray(grown.pair_spring)
    for slot, (i, j) in enumerate(np.asarray(new.idx).T):
        if (i, j) in _pairs(old.idx, count):
            assert tuple(carried[slot, :2]) == (i, j)
        else:
            assert not np.any(carried[slot])  # a new pair starts without a spring
    np.testing.assert_array_equal(grown.list_length, length)
    assert not bool(chunk_end(grown).neighbors.cell_size_too_small)
    start = start.set(neighbors=full, pair_spring=jnp.zeros((648, 3)))
    end = chunk_end(start)
    assert bool(end.neighbors.cell_size_too_small) and not bool(end.neighbors.did_buffer_overflow)
    capacity = int(runner.grow(start, overflow, end).neighbors.max_occupancy)
    assert 648 <= capacity < math.ceil(driver.TABLE_GROWTH * 648)


def test_a_frictionless_packing_is_near_random_close_packing():
    """300 spheres (d ± 10 %) compressed frictionless from a gas to 10 σc and unloaded to σc = 100 kPa
    (float32): φ within 0.630–0.648 and the rattler-free z* within 5.9–6.6 of Agnolin & Roux's random close
    packing (2007: φ ≈ 0.639, z* → 6 in the rigid limit; here κ = k_n/(σc d) = 4000 puts z* a little above
    6, and 300 spheres scatter φ by ~±0.005 between seeds), at rest (unbalanced-force ratio < 1e-3)."""
    with jax.enable_x64(False):
        diameters = np.random.default_rng(0).uniform(0.9, 1.1, 300) * DIAMETER
        _, _, records = compact_periodic(diameters, 1e5, 0.0, seed=0, tolerance=1e-3, max_steps=60_000)
    np.testing.assert_allclose(np.diagonal(records.stress[-1]), 1e5, rtol=0.01)
    assert records.unbalanced_force_ratio[-1] < 1e-3
    assert 0.630 < records.solid_fraction[-1] < 0.648
    assert 5.9 < records.rattler_free_coordination_number[-1] < 6.6


def test_a_periodic_run_from_a_configuration_resumes_to_the_same_bits_and_sweeps(tmp_path):
    """``run_test`` of a ``cell = "periodic"`` configuration (64 equal spheres compacted frictionless in the
    cell, 40 kPa, I = 5e-3, to 1 %, float32): z shortens by the imposed log strain ε_a = 1 − exp(−ε̇ t) to
    round-off; a run interrupted after 4 chunks and resumed from its checkpoint writes the same records,
    to the bit, as one run straight through (the checkpoint holds the list's shape and the records)."""
    from helpers import SMALL_ELEMENT

    from membrax.config import TriaxialConfig
    from membrax.run import run_test

    config = TriaxialConfig(name="periodic_resume", **SMALL_ELEMENT)
    straight = run_test(config, tmp_path / "straight", progress=False)
    with pytest.raises(KeyboardInterrupt):
        run_test(config, tmp_path / "resumed", progress=False, interrupt_after_chunks=4)
    resumed = run_test(config, tmp_path / "resumed", resume=True, progress=False)
    for name in ("step", "axial_strain", "volumetric_strain", "stress", "length"):
        np.testing.assert_array_equal(resumed.results[name].values, straight.results[name].values)
    np.testing.assert_array_equal(
        resumed.consolidation["stress"].values, straight.consolidation["stress"].values
    )
    shear = straight.results
    rate = 5e-3 / (DIAMETER * math.sqrt(2650.0 / 4e4))  # ε̇ = I / (d √(ρ/σc))
    elapsed = (shear["step"].values - shear["step"].values[0]) * straight.metadata["dt_s"]
    np.testing.assert_allclose(shear["axial_strain"].values, 1.0 - np.exp(-rate * elapsed), atol=2e-6)
    assert shear["axial_strain"].values[-1] >= 0.01
    # A sweep runs its members as one batch through the same loop (a run is a batch of one): its 40 kPa
    # member is the run above, to the bit, and its 20 kPa member consolidated to its own σc (the servo's 1 %).
    from membrax.sweep import run_sweep

    sweep = run_sweep(config, {"cell_pressure_kpa": [20.0, 40.0]}, tmp_path / "sweep", progress=False)
    member = sweep.member(cell_pressure_kpa=40.0)
    np.testing.assert_array_equal(member["stress"].values, shear["stress"].values)
    # The peak from the member's stresses (float64) and the run's stored φ' column (float32): 1e-5° apart.
    assert float(sweep.dataset["peak_friction_angle_deg"].sel(cell_pressure_kpa=40.0)) == pytest.approx(
        float(np.nanmax(shear["love_weber_friction_angle_deg"].values)), abs=1e-4
    )
    start = sweep.member(cell_pressure_kpa=20.0)["stress"].values[0]
    np.testing.assert_allclose(np.diagonal(start), 2e4, rtol=0.011)


def test_a_periodic_fcc_element_peaks_at_rowe_s_bound(precision):
    """The paper's FCC lattice (square layers of pitch d, alternate layers shifted by (d/2, d/2), d/√2 apart;
    compressed along the layers' normal) as a periodic element of 3 × 3 × 4 spheres, φμ = 25°, consolidated to
    100 kPa and compressed at I = 1e-3: with no boundary its peak φ' is Rowe's stress–dilatancy bound for
    FCC, 43.79° (tan α = 2, β = 45°, membrax.theory.FCC), within 0.1° (measured 43.758° in float64). The
    bounded lattices stay below it: the rigid box's 6 × 10 FCC specimen 38.5° and the paper's internal
    39.7–40.4° (docs/validation.md), so 3–5° of those are their boundary's."""
    from membrax.theory import FCC, rowe_peak_friction_angle_deg
    from membrax.triaxial.analysis import friction_angle_deg

    across, periods = 3, 2
    sites = [
        ((i + 0.5 * (k % 2)) / across, (j + 0.5 * (k % 2)) / across, (k + 0.5) / (2 * periods))
        for k in range(2 * periods)
        for i in range(across)
        for j in range(across)
    ]
    # Touching along the layers (pitch d) and between them (d/√2 apart, offset d/√2): shrunk 2e-4 to load it.
    length = np.array([across, across, periods * math.sqrt(2.0)]) * DIAMETER * (1.0 - 2e-4)
    test = periodic_test(jnp.asarray(sites, precision), length, np.full(len(sites), 0.5 * DIAMETER), 1e5)
    state, _ = test.consolidate(tolerance=1e-4, max_steps=20_000)
    _, records = test.shear(state, 0.003, 1e-3, record_every_fine=5, record_every_coarse=5, chunk_steps=1000)
    angle = friction_angle_deg(records.axial_stress, records.lateral_stress)
    rowe = float(rowe_peak_friction_angle_deg(25.0, FCC))
    assert np.nanmax(angle) == pytest.approx(rowe, abs=0.1)
    assert (
        records.axial_strain[int(np.nanargmax(angle))] < 2e-3
    )  # the lattice's peak is a spike at small strain
