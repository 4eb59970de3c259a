"""The DEM core against closed forms, conservation laws and finite differences (float64)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ACCUMULATED, tolerance

from membrax import batch, compensated, theory
from membrax.spheres import contact, fcc, integrate, neighbors, stability
from membrax.spheres import walls as walls_lib
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.triaxial import rigid as triaxial

R = 0.0125
D = 2 * R
KN = 1e7


def free_system(
    position, radius=R, skin=0.2, margin=1.0, params=None, wall_friction=True, dt=None, inertia=None
):
    """Spheres in free space, platens far below and above (z = 0 and z = 1 m)."""
    position = jnp.asarray(position, dtype=float)  # JAX's default float: float64 under x64, else float32
    radius = jnp.broadcast_to(jnp.asarray(radius, position.dtype), position.shape[:1])
    particles = integrate.make_particles(radius, GRANITE_DENSITY)
    if inertia is not None:
        particles = particles.set(inertia=jnp.full_like(particles.inertia, inertia))
    frame = neighbors.pair_neighbor_fn(
        np.asarray(position).min(0) - D,
        np.asarray(position).max(0) + D,
        2 * float(radius.max()),
        skin * D,
        margin,
    )
    walls = walls_lib.triaxial_walls(np.zeros((0, 2)), np.zeros(0), height=1.0)
    if dt is None:
        dt = 0.01 * math.sqrt(float(particles.mass[0]) / KN)
    init_fn, step_fn = integrate.sphere_dem(particles, frame, dt, wall_friction=wall_friction)
    return particles, frame, walls, init_fn, step_fn, dt


def run_steps(step_fn, state, params, num_steps):
    return jax.jit(lambda s: jax.lax.fori_loop(0, num_steps, lambda _, x: step_fn(x, params), s))(state)


# ------------------------------------------------------------------------------------------------------
# Contact law
# ------------------------------------------------------------------------------------------------------


def test_head_on_collision_duration_and_restitution(precision):
    # Undamped linear spring: contact lasts π √(m*/k_n), m* = m/2, and the rebound speed equals the approach.
    position = [[0.0, 0.0, 0.5], [D + 1e-5, 0.0, 0.5]]
    particles, frame, walls, init_fn, step_fn, dt = free_system(position)
    params = integrate.DEMParams(contact.ContactParams.paper(), integrate.DampingParams.none())
    speed = 0.1
    state = init_fn(
        jnp.asarray(position),
        walls,
        frame.allocate(jnp.asarray(position)),
        velocity=jnp.array([[speed / 2, 0, 0], [-speed / 2, 0, 0.0]]),
    )

    def body(s, _):
        s = step_fn(s, params)
        return s, s.position[1, 0] - s.position[0, 0]

    state, separation = jax.jit(lambda s: jax.lax.scan(body, s, None, length=20_000))(state)
    in_contact = np.nonzero(np.asarray(separation) < D)[0]
    duration = (in_contact[-1] - in_contact[0] + 1) * dt
    mass = float(particles.mass[0])
    expected = math.pi * math.sqrt(mass / 2 / KN)
    assert duration == pytest.approx(expected, rel=1e-3)
    assert float(state.velocity[1, 0] - state.velocity[0, 0]) / speed == pytest.approx(1.0, abs=1e-3)
    assert int(state.error) == 0


def precompressed_cluster(squeeze=1e-3, speed=0.1, seed=1):
    """A 4×4×4 square FCC block shrunk by ``squeeze`` so every lattice contact is closed, in a tight box."""
    specimen = fcc.fcc_specimen(D, 4, 4, cross_section="square")
    position = jnp.asarray(specimen.position) * (1 - squeeze)
    normals, distances = specimen.outline_faces()
    walls = walls_lib.triaxial_walls(
        np.asarray(normals),
        np.asarray(distances) * (1 - squeeze) - squeeze * D,
        specimen.height * (1 - squeeze) - squeeze * D,
    )
    walls = walls.set(position=walls.position.at[:, 0].set(-squeeze * D))
    particles = integrate.make_particles(specimen.radius, GRANITE_DENSITY)
    frame = neighbors.pair_neighbor_fn(
        np.asarray(position).min(0) - D, np.asarray(position).max(0) + D, D, 0.2 * D, D
    )
    velocity = jnp.asarray(np.random.default_rng(seed).normal(size=position.shape) * speed)
    return particles, frame, walls, position, velocity


def total_energy_series(dt_fraction, num_steps=10_000, squeeze=1e-3, speed=0.05):
    """Energy of a relaxed, pre-compressed block vibrating without friction or damping.

    Returns (total energy, kinetic energy, smallest overlap of the contacts closed at the start) per step.
    """
    particles, frame, walls, position, _ = precompressed_cluster(squeeze, 0.0)
    contact_params = contact.ContactParams.paper(friction_angle_deg=0.0)
    params = integrate.DEMParams(contact_params, integrate.DampingParams.none())
    probe_init, _ = integrate.sphere_dem(particles, frame, 1.0)
    critical = stability.critical_time_step(
        probe_init(position, walls, frame.allocate(position)), particles, params
    )
    dt = dt_fraction * critical
    init_fn, step_fn = integrate.sphere_dem(particles, frame, dt, wall_friction=False)
    # Relax to equilibrium first (the scaled block is not one: set-back boundary spheres pop out).
    relax = integrate.DEMParams(contact_params, integrate.DampingParams.viscous(3000.0))
    state = run_steps(step_fn, init_fn(position, walls, frame.allocate(position)), relax, 20_000)
    state = state.set(
        neighbors=frame.allocate(state.position),
        velocity=jnp.asarray(np.random.default_rng(1).normal(size=position.shape) * speed),
        angular_velocity=jnp.zeros_like(position),
    )
    state = state.set(pair_spring=jnp.zeros((state.neighbors.idx.shape[1], 3)))

    def potential(s):
        forces = integrate.compute_forces(s, particles, params, dt, False)
        distance = jnp.linalg.norm(forces.pair_branch, axis=1)
        valid = s.neighbors.idx[0] < particles.num_particles
        overlap = jnp.where(valid, D - jnp.where(valid, distance, 1.0), -1.0)
        wall_overlap = forces.wall_normal_force / KN
        energy = jnp.sum(contact.normal_energy(overlap, KN)) + jnp.sum(0.5 * KN * wall_overlap**2)
        return energy, overlap

    _, overlap0 = potential(state)
    closed = overlap0 > 0.2 * squeeze * D

    def body(s, _):
        energy, overlap = potential(s)
        new = step_fn(s, params)
        # Velocities at the whole step: the mean of the two half steps (velocity Verlet).
        v = 0.5 * (s.velocity + new.velocity)
        w = 0.5 * (s.angular_velocity + new.angular_velocity)
        kinetic = 0.5 * jnp.sum(particles.mass[:, None] * v**2) + 0.5 * jnp.sum(
            particles.inertia[:, None] * w**2
        )
        return new, (kinetic + energy, kinetic, jnp.min(jnp.where(closed, overlap, 1.0)))

    _, (energy, kinetic, closed_min) = jax.jit(lambda s: jax.lax.scan(body, s, None, length=num_steps))(state)
    assert int(jnp.sum(closed)) > 100
    return np.asarray(energy), np.asarray(kinetic), np.asarray(closed_min)


def test_energy_conserved_without_friction_or_damping():
    energy, kinetic, closed_min = total_energy_series(0.02)
    # Every lattice contact stays closed (no on/off events) and a real share of the energy is vibration.
    assert closed_min.min() > 0.0
    assert kinetic[0] / energy[0] > 0.002
    steps = np.arange(energy.size)
    drift = np.polyfit(steps, energy / energy[0], 1)[0] * energy.size
    assert abs(drift) < 1e-6
    # The remaining fluctuation is the integrator's O(Δt²) error: halving Δt cuts it about fourfold.
    coarse, _, _ = total_energy_series(0.04)
    ratio = np.max(np.abs(coarse / coarse[0] - 1)) / np.max(np.abs(energy / energy[0] - 1))
    assert 3.0 < ratio < 5.0


def sphere_on_plane(
    tangential_force, friction_angle_deg=30.0, normal_force=20.0, damping=None, num_steps=20_000
):
    """One sphere on the bottom platen, pressed with N and pushed sideways with T (rotation blocked)."""
    position = jnp.array([[0.0, 0.0, R - normal_force / KN]])
    particles, frame, walls, init_fn, step_fn, dt = free_system(position, inertia=1e30)
    contact_params = contact.ContactParams.paper(wall_friction_angle_deg=friction_angle_deg)
    # γ = 2e4/s: the tangential mode (ω = √(k_s/m) ≈ 1.5e4 rad/s) is damped to rest well within the run.
    params = integrate.DEMParams(contact_params, damping or integrate.DampingParams.viscous(2e4))
    external = jnp.array([[tangential_force, 0.0, -normal_force]])
    state = init_fn(position, walls, frame.allocate(position), external_force=external)
    return run_steps(step_fn, state, params, num_steps), dt, particles


def test_sphere_on_plane_sticks_below_coulomb_limit(precision):
    normal_force, mu = 20.0, math.tan(math.radians(30.0))
    tangential = 0.8 * mu * normal_force
    state, _, particles = sphere_on_plane(tangential)
    spring = np.asarray(state.wall_spring[0, walls_lib.BOTTOM])
    # Static: the tangential spring balances T, and the sphere has moved T / k_s.
    # float32: the damped approach to rest leaves ~10 ulp of force imbalance.
    assert spring[0] == pytest.approx(-tangential, rel=max(1e-6, 10 * tolerance(precision)))
    # The spring is summed from 20,000 increments k_s v Δt: float32 keeps it within ACCUMULATED (1e-3).
    displacement_tolerance = max(1e-4, tolerance(precision, ACCUMULATED))
    assert float(state.position[0, 0]) == pytest.approx(tangential / 5e6, rel=displacement_tolerance)
    # At rest: against the transient's speed scale ω x = √(k_s/m) T/k_s (~0.03 m/s), round-off only.
    speed_scale = math.sqrt(5e6 / float(particles.mass[0])) * tangential / 5e6
    assert abs(float(state.velocity[0, 0])) < max(1e-9, 10 * tolerance(precision) * speed_scale)


def test_sphere_on_plane_slides_at_coulomb_limit(precision):
    normal_force, mu = 20.0, math.tan(math.radians(30.0))
    tangential = 1.2 * mu * normal_force
    state, dt, particles = sphere_on_plane(tangential, damping=integrate.DampingParams.none(), num_steps=5000)
    spring = np.asarray(state.wall_spring[0, walls_lib.BOTTOM])
    # Sliding: friction is exactly μN and the sphere accelerates at (T − μN)/m.
    assert -spring[0] == pytest.approx(mu * normal_force, rel=1e-3)
    before, _, _ = sphere_on_plane(tangential, damping=integrate.DampingParams.none(), num_steps=4000)
    acceleration = float(state.velocity[0, 0] - before.velocity[0, 0]) / (1000 * dt)
    expected = (tangential - mu * normal_force) / float(particles.mass[0])
    assert acceleration == pytest.approx(expected, rel=1e-3)


def test_frictionless_platens_push_back_with_k_times_overlap(precision):
    # F = k_w δ e along each platen's inward normal: a sphere 1 mm into the bottom platen (z = 0) and one
    # 0.5 mm into the top one (z = 1 m), far apart; the frictionless path (the paper's platens, jax.grad of
    # the energy over the gaps) and the frictional one give the same hand values, and no torque.
    position = [[0.0, 0.0, R - 1e-3], [0.5, 0.0, 1.0 - R + 5e-4]]
    params = integrate.DEMParams(contact.ContactParams.paper(), integrate.DampingParams.none())
    stiffness = float(params.contact.wall_normal_stiffness)
    expected = np.zeros((2, 3))
    expected[0, 2], expected[1, 2] = stiffness * 1e-3, -stiffness * 5e-4
    for wall_friction in (False, True):
        particles, frame, walls, init_fn, _, dt = free_system(position, wall_friction=wall_friction)
        state = init_fn(jnp.asarray(position), walls, frame.allocate(jnp.asarray(position)))
        compute = jax.jit(integrate.compute_forces, static_argnums=4)
        forces = compute(state, particles, params, dt, wall_friction)
        # float32: an overlap is a difference of coordinates near 1 m (ulp 1.2e-7 m of 5e-4 m: 2.4e-4).
        np.testing.assert_allclose(forces.force, expected, rtol=100 * tolerance(precision))
        np.testing.assert_allclose(forces.torque, 0.0, atol=1e-12)
        platens = [stiffness * 1e-3, stiffness * 5e-4]
        np.testing.assert_allclose(forces.wall_total_force[0], platens, rtol=1e-3)


def random_cluster(num=40, seed=0):
    rng = np.random.default_rng(seed)
    position = rng.uniform(0.0, 3.2 * D, size=(num, 3)) + np.array([0.0, 0.0, 0.4])
    return jnp.asarray(position)


def test_internal_forces_conserve_momentum_and_angular_momentum(precision):
    position = random_cluster()
    particles, frame, walls, init_fn, step_fn, dt = free_system(position)
    params = integrate.DEMParams(contact.ContactParams.paper(), integrate.DampingParams.none())
    rng = np.random.default_rng(3)
    state = init_fn(
        position,
        walls,
        frame.allocate(position),
        velocity=jnp.asarray(rng.normal(size=position.shape)),
        angular_velocity=jnp.asarray(rng.normal(size=position.shape) * 50),
    )
    state = run_steps(step_fn, state, params, 50)  # build up tangential springs
    forces = integrate.compute_forces(state, particles, params, dt)
    assert int(jnp.sum(forces.pair_normal_force > 0)) > 20
    scale = float(jnp.max(jnp.abs(forces.force)))
    assert forces.force.dtype == precision
    bound = tolerance(precision) * scale * particles.num_particles
    assert np.max(np.abs(np.asarray(jnp.sum(forces.force, axis=0)))) < bound
    # Σ (x × F + T) = 0: each pair's forces act at one contact point.
    angular = jnp.sum(jnp.cross(state.position, forces.force) + forces.torque, axis=0)
    assert np.max(np.abs(np.asarray(angular))) < bound


# ------------------------------------------------------------------------------------------------------
# Neighbour lists and the driver
# ------------------------------------------------------------------------------------------------------


def test_remap_pair_history_by_partner_id():
    n = 5
    old = jnp.array([[0, 0, 1, 2, n], [1, 3, 2, 4, n]])
    new = jnp.array([[1, 0, 3, 2, n, n], [2, 3, 4, 4, n, n]])
    history = jnp.arange(5.0)[:, None] * jnp.ones((1, 3)) + 1.0
    moved = np.asarray(neighbors.remap_pair_history(old, new, history, n))[:, 0]
    # (1,2) was slot 2 → 3.0; (0,3) slot 1 → 2.0; (3,4) new → 0; (2,4) slot 3 → 4.0; padding → 0.
    np.testing.assert_array_equal(moved, [3.0, 2.0, 0.0, 4.0, 0.0, 0.0])


def sheared_block(skin):
    """A small frictional block sheared by its top platen: contacts slide, springs build and rotate."""
    specimen = fcc.fcc_specimen(D, 4, 5)
    return triaxial.rigid_wall_test(specimen, 40e3, skin_fraction=skin, time_step=1e-5, max_wall_speed=0.01)


def count_rebuilds(test, state, num_steps):
    """Steps at which jax-md rebuilt the list inside jit (its reference positions changed)."""

    def body(s, _):
        new = test.runner.step_fn(s, test.params)
        rebuilt = jnp.any(new.neighbors.reference_position != s.neighbors.reference_position)
        return new, rebuilt

    _, rebuilt = jax.jit(lambda s: jax.lax.scan(body, s, None, length=num_steps))(state)
    return int(np.sum(np.asarray(rebuilt)))


@pytest.mark.slow
def test_rebuilding_every_step_equals_every_fifty_steps():
    # Every step: a skin of 1e-6 D makes jax-md rebuild at every step (history remapped inside jit).
    # Every 50 steps: a skin so large that jax-md never rebuilds, and the driver reallocates between chunks.
    every_step = sheared_block(skin=1e-6)
    rarely = sheared_block(skin=0.6)
    velocity = np.zeros(every_step.initial_state.walls.velocity.shape)
    velocity[:, walls_lib.TOP] = -0.05
    results = []
    for test, chunks in ((every_step, 1), (rarely, 6)):
        state = test.set_walls(test.initial_state, False, velocity, 0.0)
        steps_per_chunk = 300 // chunks
        for _ in range(chunks):
            state, _ = test.runner.run(state, test.params, steps_per_chunk, steps_per_chunk, steps_per_chunk)
            if chunks > 1:
                state = test.runner.reallocate(state, capacity_growth=1.0)
        results.append(state)
    a, b = results
    assert every_step.dt == rarely.dt
    start = every_step.set_walls(every_step.initial_state, False, velocity, 0.0)
    assert count_rebuilds(every_step, start, 100) >= 95
    assert count_rebuilds(rarely, rarely.set_walls(rarely.initial_state, False, velocity, 0.0), 100) == 0
    springs = np.linalg.norm(np.asarray(a.pair_spring), axis=1)
    assert np.sum(springs > 0) > 20  # the history matters in this run
    np.testing.assert_allclose(np.asarray(a.position), np.asarray(b.position), rtol=0, atol=1e-12)
    # Angular velocities to 1e-7 of the largest: the torque sums run in a different pair order.
    largest = float(np.max(np.abs(np.asarray(a.angular_velocity))))
    np.testing.assert_allclose(
        np.asarray(a.angular_velocity), np.asarray(b.angular_velocity), atol=1e-7 * largest
    )


def test_too_small_capacity_is_reallocated_and_gives_the_same_result():
    specimen = fcc.fcc_specimen(D, 4, 5)
    reference = triaxial.rigid_wall_test(specimen, 40e3)
    small = triaxial.rigid_wall_test(specimen, 40e3)
    # A list with a fifth of the capacity needed: the first chunk overflows and is rerun after reallocation.
    frame = small.runner.neighbor_frame
    lower = -frame.origin + 0.5 * D
    tiny_frame = neighbors.pair_neighbor_fn(
        lower, lower + frame.box - D, D, frame.skin, 0.5 * D, capacity_multiplier=0.2
    )
    tiny = tiny_frame.allocate(jnp.asarray(specimen.position))
    full = reference.initial_state.neighbors.idx.shape[1]
    start = small.initial_state.set(neighbors=tiny, pair_spring=jnp.zeros((tiny.idx.shape[1], 3)))
    assert tiny.idx.shape[1] <= full // 4
    state_ref, records_ref = reference.consolidate(max_steps=3000, chunk_steps=1000, record_every=100)
    state_small, records_small = small.consolidate(
        state=start, max_steps=3000, chunk_steps=1000, record_every=100
    )
    assert small.runner.reallocations == 1
    np.testing.assert_allclose(np.asarray(state_small.position), np.asarray(state_ref.position), atol=1e-12)
    # Overlaps are ~1e-4 of the coordinates, so positions equal to 1e-12 m give stresses equal to ~1e-6;
    # XLA's CPU scatter splits its sum over two threads, so round-off differs between runs.
    np.testing.assert_allclose(records_small.wall_axial_stress, records_ref.wall_axial_stress, rtol=1e-6)


def test_shared_lists_with_a_larger_capacity_hold_the_brute_force_pairs():
    """A batch's reallocation (executor._shared_neighbors) asks for more capacity than a fresh allocation
    has: each member's list then has exactly that capacity, and its real pairs are the pairs within the
    cutoff + skin found by brute force."""
    from membrax.spheres.neighbors import allocate_shared as _shared_neighbors

    specimen = fcc.fcc_specimen(D, 4, 5)
    frame = triaxial.rigid_wall_test(specimen, 40e3).runner.neighbor_frame
    position = np.asarray(specimen.position)
    moved = position + np.random.default_rng(0).normal(0.0, 0.02 * D, position.shape)
    allocated = frame.allocate(jnp.asarray(position))
    capacity = 3 * int(allocated.max_occupancy)
    lists = _shared_neighbors(frame, [position, moved], capacity=capacity)
    n = position.shape[0]
    for nl, x in zip(lists, (position, moved), strict=True):
        assert nl.idx.shape[1] == capacity and not bool(nl.did_buffer_overflow)
        pairs = {tuple(sorted(pair)) for pair in np.asarray(nl.idx).T if pair[0] < n and pair[1] < n}
        distance = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
        within = {
            (i, j) for i, j in zip(*np.nonzero(distance < frame.cutoff + frame.skin), strict=True) if i < j
        }
        assert pairs == within


def test_shared_lists_asked_for_more_than_the_cell_list_holds_get_its_candidate_count():
    """A capacity above the cell list's candidates, N · 3³ · cell capacity, is capped there (a rebuild
    truncates to it, and the no-rebuild branch must match it for lax.cond): the lists stack, keep the
    brute-force pairs and flag no overflow."""
    from membrax.spheres.neighbors import allocate_shared as _shared_neighbors

    specimen = fcc.fcc_specimen(D, 4, 5)
    frame = triaxial.rigid_wall_test(specimen, 40e3).runner.neighbor_frame
    position = np.asarray(specimen.position)
    allocated = frame.allocate(jnp.asarray(position))
    cells = int(allocated.cell_list_capacity)
    n = position.shape[0]
    lists = _shared_neighbors(frame, [position, position], capacity=10 * n * 27 * cells, cell_capacity=cells)
    for nl in lists:
        assert nl.idx.shape[1] == n * 27 * cells and not bool(nl.did_buffer_overflow)
        pairs = {tuple(sorted(pair)) for pair in np.asarray(nl.idx).T if pair[0] < n and pair[1] < n}
        distance = np.linalg.norm(position[:, None, :] - position[None, :, :], axis=-1)
        close = np.nonzero(distance < frame.cutoff + frame.skin)
        assert pairs == {(i, j) for i, j in zip(*close, strict=True) if i < j}


def test_compensated_summation_keeps_subresolution_motion_in_float32():
    # 1e-9 m per step at 0.075 m is below float32 resolution (ulp 7.5e-9): a plain sum never moves.
    value = jnp.full((1,), 0.075, jnp.float32)
    compensation = jnp.zeros((1,), jnp.float32)
    plain = value
    increment = jnp.full((1,), 1e-9, jnp.float32)
    for _ in range(1000):
        value, compensation = compensated.compensated_add(value, compensation, increment)
        plain = plain + increment
    start = float(jnp.float32(0.075))
    assert float(plain[0]) == start  # the naive sum lost everything
    moved = (float(value[0]) - start) + float(compensation[0])
    assert moved == pytest.approx(1000 * float(increment[0]), rel=1e-3)


def test_compensated_sum_of_rows_is_fast2sum_exact_per_element_under_jit_vmap_and_grad():
    """On (N, 3) rows, summed flat inside: each element's new value + compensation is its exact sum
    (Fast2Sum: value + (increment + compensation), exact in float64 for float32 operands), the shape is
    kept, a vmapped batch equals its members one by one, and d(value + compensation)/d increment = 1."""
    rng = np.random.default_rng(3)
    value = jnp.asarray(rng.uniform(0.05, 0.3, (2, 17, 3)), jnp.float32)
    compensation = jnp.asarray(rng.normal(0.0, 1e-9, (2, 17, 3)), jnp.float32)
    increment = jnp.asarray(rng.normal(0.0, 1e-6, (2, 17, 3)), jnp.float32)
    batched = jax.jit(jax.vmap(compensated.compensated_add))(value, compensation, increment)
    for b in range(2):
        total, error = compensated.compensated_add(value[b], compensation[b], increment[b])
        assert total.shape == error.shape == (17, 3)
        assert np.array_equal(total, batched[0][b]) and np.array_equal(error, batched[1][b])
        corrected = np.asarray(increment[b] + compensation[b], np.float64)  # the float32 sum Fast2Sum adds
        exact = np.asarray(value[b], np.float64) + corrected
        assert np.array_equal(np.asarray(total, np.float64) + np.asarray(error, np.float64), exact)
    slope = jax.grad(lambda inc: jnp.sum(sum(compensated.compensated_add(value[0], compensation[0], inc))))
    assert np.array_equal(slope(increment[0]), np.ones((17, 3), np.float32))


# ------------------------------------------------------------------------------------------------------
# Time step, batching, gradients
# ------------------------------------------------------------------------------------------------------


def test_critical_time_step_of_a_dimer_includes_rotation():
    # Two equal spheres, one contact: normal mode ω² = 2 k_n/m; tangential–rotational ω² = k_s (2/m + 2R²/I)
    # = 7 k_s/m (I = 2/5 m R²). With k_s = k_n/2 the rotational mode is the fastest.
    position = jnp.array([[0.0, 0.0, 0.5], [D, 0.0, 0.5]])
    particles, frame, walls, init_fn, _, _ = free_system(position)
    params = integrate.DEMParams(contact.ContactParams.paper(), integrate.DampingParams.none())
    state = init_fn(position, walls, frame.allocate(position))
    mass = float(particles.mass[0])
    with_rotation = stability.critical_time_step(state, particles, params)
    without = stability.critical_time_step(state, particles, params, include_rotation=False)
    assert with_rotation == pytest.approx(2 / math.sqrt(7 * 5e6 / mass), rel=1e-6)
    assert without == pytest.approx(2 / math.sqrt(2 * KN / mass), rel=1e-6)


def small_batch_cases():
    friction = np.array([15.0, 25.0, 35.0])
    stiffness = np.array([1e7, 2e7, 1e7])
    pressure = np.array([40e3, 20e3, 80e3])
    return friction, stiffness, pressure


def contact_case(friction_deg, stiffness):
    return contact.ContactParams(
        normal_stiffness=jnp.asarray(stiffness),
        tangential_stiffness=jnp.asarray(0.5 * stiffness),
        friction_coefficient=jnp.tan(jnp.deg2rad(jnp.asarray(friction_deg))),
        wall_normal_stiffness=jnp.asarray(1e7 * np.ones_like(stiffness)),
        wall_tangential_stiffness=jnp.asarray(5e6 * np.ones_like(stiffness)),
        wall_friction_coefficient=jnp.zeros_like(jnp.asarray(stiffness)),
    )


def test_folded_batch_and_vmap_match_a_loop_over_cases():
    specimen = fcc.fcc_specimen(D, 4, 4)
    friction, stiffness, pressure = small_batch_cases()
    num_steps = 400
    options = {"time_step": 5e-6, "max_wall_speed": 0.01}
    folded = triaxial.rigid_wall_test(specimen, pressure, contact_case(friction, stiffness), **options)
    dt = folded.dt
    # The loop: one single-member system, run once per case with that case's parameters.
    one = triaxial.rigid_wall_test(specimen, pressure[0], contact_case(friction[0], stiffness[0]), **options)
    _, step = integrate.sphere_dem(one.particles, one.runner.neighbor_frame, dt, wall_friction=False)
    cases = [
        (
            one.set_walls(one.initial_state, True, 0.0, pressure[b]),
            one.params.set(contact=contact_case(friction[b], stiffness[b])),
        )
        for b in range(3)
    ]
    looped = [run_steps(step, state, params, num_steps) for state, params in cases]
    # Folded: one system of 3 members, parameters as arrays over members.
    _fold_init, fold_step = integrate.sphere_dem(
        folded.particles, folded.runner.neighbor_frame, dt, wall_friction=False
    )
    fold_state = folded.set_walls(folded.initial_state, True, 0.0, pressure)
    fold_final = run_steps(fold_step, fold_state, folded.params, num_steps)
    positions = batch.unfold(fold_final.position, 3)
    offsets = batch.member_offsets(3, specimen.width_across_flats + 3 * D)
    for b in range(3):
        # Folded coordinates sit up to 0.35 m from the origin: round-off there (ulp 5.5e-17 m) is fed
        # through k_n = 1e7 N/m and the servos, so agreement is to 1e-8 m (4e-7 D) rather than 1e-12 m
        # (1e-9 m with the lateral walls' old gain 0.1; 3.5e-9 m measured with their α = 0.5, β = α/4).
        np.testing.assert_allclose(
            np.asarray(positions[b]) - offsets[b], np.asarray(looped[b].position), atol=1e-8
        )
    # Stacked: jit(vmap(run)) and jit(lax.map(run)) over the three single-member states.
    stacked_state = batch.stack([state for state, _ in cases])
    stacked_params = batch.stack([params for _, params in cases])

    def run(s, p):
        return jax.lax.fori_loop(0, num_steps, lambda _, x: step(x, p), s)

    for batched in (batch.vmap_members(run), batch.map_members(run)):
        stacked = jax.jit(batched)(stacked_state, stacked_params)
        for b in range(3):
            np.testing.assert_allclose(
                np.asarray(stacked.position[b]), np.asarray(looped[b].position), atol=1e-12
            )
    # The cases differ (the comparison is not trivial).
    assert not np.allclose(np.asarray(looped[0].walls.position), np.asarray(looped[2].walls.position))


def test_gradient_through_viscous_simulation_matches_finite_differences():
    # Smooth (viscous) damping: d(final separation)/d(k_n, γ) by autodiff equals central differences.
    position = jnp.array([[0.0, 0.0, 0.5], [D + 1e-5, 0.0, 0.5]])
    _particles, frame, walls, init_fn, step_fn, _dt = free_system(position)
    velocity = jnp.array([[0.05, 0.01, 0.0], [-0.05, 0.0, 0.0]])
    state = init_fn(position, walls, frame.allocate(position), velocity=velocity)

    def separation(stiffness, rate):
        params = integrate.DEMParams(
            contact.ContactParams.paper(normal_stiffness=1e7).set(normal_stiffness=stiffness),
            integrate.DampingParams.viscous(0.0).set(viscous_rate=rate),
        )
        final = jax.lax.fori_loop(0, 3000, lambda _, s: step_fn(s, params), state)
        return jnp.linalg.norm(final.position[1] - final.position[0])

    value_and_grad = jax.jit(jax.value_and_grad(separation, argnums=(0, 1)))
    _, (d_stiffness, d_rate) = value_and_grad(1e7, 20.0)
    f = jax.jit(separation)
    fd_stiffness = (float(f(1e7 * (1 + 1e-6), 20.0)) - float(f(1e7 * (1 - 1e-6), 20.0))) / (2e7 * 1e-6)
    fd_rate = (float(f(1e7, 20.0 + 1e-4)) - float(f(1e7, 20.0 - 1e-4))) / 2e-4
    assert float(d_stiffness) == pytest.approx(fd_stiffness, rel=1e-5)
    assert float(d_rate) == pytest.approx(fd_rate, rel=1e-5)
    assert abs(fd_stiffness) > 0 and abs(fd_rate) > 0


# ------------------------------------------------------------------------------------------------------
# Rigid-wall triaxial test
# ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rigid_triaxial_friction_series():
    """One folded batch of three 6-across, 8-layer specimens at φμ = 15°, 25°, 35°, 40 kPa."""
    specimen = fcc.fcc_specimen(D, 6, 8)
    friction = np.array([15.0, 25.0, 35.0])
    test = triaxial.rigid_wall_test(specimen, np.full(3, 40e3), contact_case(friction, np.full(3, 1e7)))
    state, consolidation = test.consolidate(chunk_steps=2000)
    state, shear = test.shear(state, target_axial_strain=0.004, inertial_number=1e-3, chunk_steps=1000)
    return test, consolidation, shear


def test_love_weber_equals_boundary_stress_after_consolidation(rigid_triaxial_friction_series):
    _, consolidation, _ = rigid_triaxial_friction_series
    last = -1
    for member in range(3):
        assert consolidation.unbalanced_force_ratio[last, member] < 1e-3
        wall_axial = consolidation.wall_axial_stress[last, member]
        assert wall_axial == pytest.approx(40e3, rel=0.01)
        # Static equilibrium: the contact (Love–Weber) stress equals the boundary stress.
        assert consolidation.love_weber_axial_stress[last, member] == pytest.approx(wall_axial, rel=5e-3)
        assert consolidation.love_weber_radial_stress[last, member] == pytest.approx(
            consolidation.wall_radial_stress[last, member], rel=5e-3
        )
        # Per-wall records: the platens' mean force over the polygon area is the recorded axial stress.
        platen_force = 0.5 * (
            consolidation.wall_force[last, member, 0] + consolidation.wall_force[last, member, 1]
        )
        assert platen_force / consolidation.area[last, member] == pytest.approx(wall_axial, rel=1e-12)
        height = consolidation.wall_position[last, member, 0] + consolidation.wall_position[last, member, 1]
        assert height == pytest.approx(consolidation.height[last, member], rel=1e-12)


def test_rigid_wall_peak_between_38_and_44_and_rising_with_friction_as_rowe(rigid_triaxial_friction_series):
    _, _, shear = rigid_triaxial_friction_series
    peaks = [triaxial.peak(shear, member=b)[0] for b in range(3)]
    assert 38.0 < peaks[1] < 44.0
    rowe = [float(theory.rowe_peak_friction_angle_deg(f)) for f in (15.0, 25.0, 35.0)]
    assert peaks[0] < peaks[1] < peaks[2]
    # Below the rigid-particle closed form (finite stiffness, small specimen with boundaries).
    for simulated, closed_form in zip(peaks, rowe, strict=True):
        assert simulated < closed_form
    # The FCC peak is a spike at small strain.
    strain_at_peak = triaxial.peak(shear, member=1)[1]
    assert strain_at_peak < 0.002
