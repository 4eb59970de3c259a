"""Damping relative to the walls' affine field (``DampingParams.frame``) against hand values and balances.

Local damping F − α|F| sign(u) − γ m u (Cundall 1987) acts on u = v − v_ref, v_ref the walls' affine field
(:func:`membrax.spheres.walls.affine_velocity`) for ``"affine"`` and 0 for ``"absolute"``. Units SI.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tolerance

from membrax import assemble, batch
from membrax.config import ConfigError, TriaxialConfig
from membrax.membrane import node_update
from membrax.spheres import contact, fcc, integrate, neighbors, stability
from membrax.spheres import walls as walls_lib
from membrax.spheres.measure import measure
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.triaxial import rigid

R = 0.0125
D = 2 * R


def platens(bottom_height, top_height, bottom_speed, top_speed, num_members=1):
    """Platens only (no lateral walls), the bottom one at z = ``bottom_height`` moving up at ``bottom_speed``
    and the top one at z = ``top_height`` moving up at ``top_speed`` (m, m/s; the planes' h and dh/dt are
    −z and −v at the bottom, whose normal is −e_z)."""
    walls = walls_lib.triaxial_walls(np.zeros((0, 2)), np.zeros(0), 1.0, num_members=num_members)
    dtype = walls.position.dtype
    position = np.stack([-np.asarray(bottom_height, float), np.asarray(top_height, float)], axis=-1)
    velocity = np.stack([-np.asarray(bottom_speed, float), np.asarray(top_speed, float)], axis=-1)
    return walls.set(
        position=jnp.asarray(np.broadcast_to(position, (num_members, 2)), dtype),
        velocity=jnp.asarray(np.broadcast_to(velocity, (num_members, 2)), dtype),
    )


def test_the_damping_of_a_sphere_moving_with_the_affine_field_is_zero(precision):
    # Platens at z = 0 and 0.5 m closing at 2⁻⁶ m/s each: at z = 0.125 m (s = 1/4) the field is
    # 2⁻⁶ − 2⁻⁵/4 = 2⁻⁷ m/s, exact in both dtypes; a sphere moving at it is not damped at all.
    walls = platens(0.0, 0.5, 2.0**-6, -(2.0**-6))
    position = jnp.asarray([[0.01, -0.02, 0.125], [0.01, -0.02, 0.125]])
    reference = walls_lib.affine_velocity(position, walls, jnp.zeros(2, jnp.int32))
    assert np.array_equal(np.asarray(reference), np.tile([0.0, 0.0, 2.0**-7], (2, 1)))
    force = jnp.asarray([[3.0, -2.0, 5.0], [3.0, -2.0, 5.0]])
    # The second sphere moves off the field by u = (0.1, 0, 0.01) m/s: damped by −α|F| sign(u) − γ m u.
    velocity = reference + jnp.asarray([[0.0, 0.0, 0.0], [0.1, 0.0, 0.01]])
    mass = jnp.asarray([0.02, 0.02])
    damping = integrate.DampingParams(local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(50.0))
    damped = integrate.apply_damping(force, velocity, mass, damping, jnp.zeros(2, jnp.int32), reference)
    assert np.array_equal(np.asarray(damped[0]), np.asarray(force[0]))
    hand = [3.0 - 0.3 * 3.0 - 50.0 * 0.02 * 0.1, -2.0, 5.0 - 0.3 * 5.0 - 50.0 * 0.02 * 0.01]
    np.testing.assert_allclose(np.asarray(damped[1]), hand, rtol=tolerance(precision))
    # The absolute law damps the first sphere for the field's motion it shares: F_z − 0.3|F_z| − γ m 2⁻⁷.
    absolute = integrate.apply_damping(force, velocity, mass, damping, jnp.zeros(2, jnp.int32))
    assert float(absolute[0, 2]) == pytest.approx(5.0 - 1.5 - 50.0 * 0.02 * 2.0**-7, rel=tolerance(precision))


def test_the_field_interpolates_the_platen_velocities_and_is_clipped_outside():
    # z_b = −0.1 m moving up at 3 mm/s, z_t = 0.4 m moving down at 1 mm/s: at mid-height (0.15 m) the
    # field is the mean of the two, 1 mm/s; at s = 1/4 (0.025 m) 3 − 4/4 = 2 mm/s; on and beyond the platens
    # their own velocities.
    walls = platens(-0.1, 0.4, 0.003, -0.001)
    z = jnp.asarray([0.15, 0.025, -0.1, 0.4, 0.5, -0.3])
    position = jnp.stack([jnp.full(6, 0.03), jnp.full(6, -0.07), z], axis=1)
    reference = walls_lib.affine_velocity(position, walls, jnp.zeros(6, jnp.int32))
    np.testing.assert_allclose(np.asarray(reference[:, 2]), [0.001, 0.002, 0.003, -0.001, -0.001, 0.003])
    assert np.all(np.asarray(reference[:, :2]) == 0.0)  # no lateral walls: no lateral field
    # Damped with u = v − v_ref: F − α|F| sign(u) − γ m u by hand, v = (0.2, 0, 0.011) m/s at mid-height.
    force = jnp.asarray([[1.0, -2.0, 3.0]])
    damping = integrate.DampingParams(local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(40.0))
    damped = integrate.apply_damping(
        force,
        jnp.asarray([[0.2, 0.0, 0.011]]),
        jnp.asarray([0.05]),
        damping,
        jnp.zeros(1, jnp.int32),
        reference[:1],
    )
    hand = [1.0 - 0.3 - 40.0 * 0.05 * 0.2, -2.0, 3.0 - 0.9 - 40.0 * 0.05 * 0.010]
    np.testing.assert_allclose(np.asarray(damped[0]), hand, rtol=1e-12)


def test_the_lateral_field_of_strain_controlled_walls_is_their_area_rate_about_each_centroid():
    # Two members' square cells of half-width a = 0.1 m, member 1 shifted by (0.5, 0, 0) (a folded batch),
    # their lateral walls moved at imposed velocities (servo off, triaxial_walls' default).
    # Member 0's four walls move out at u = 2 mm/s: ε̇_r = (dA/dt)/(2A) = 8a u/(8a²) = u/a; member 1's first
    # wall moves at 2u, the others at u: Σ L_k v_k/(2A) = 2a·5u/(8a²) = 1.25 u/a.
    a, u = 0.1, 0.002
    normals = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    walls = walls_lib.triaxial_walls(normals, np.full(4, a), 0.4, num_members=2)
    shift = batch.member_offsets(2, 0.5) @ np.asarray(walls.normal).T
    velocity = np.zeros((2, 6))
    velocity[:, 2:] = u
    velocity[1, 2] = 2 * u
    walls = walls.set(position=walls.position + jnp.asarray(shift), velocity=jnp.asarray(velocity))
    position = jnp.asarray([[0.05, -0.02, 0.2], [0.55, -0.02, 0.2]])
    reference = walls_lib.affine_velocity(position, walls, jnp.asarray([0, 1], jnp.int32))
    rates = np.array([u / a, 1.25 * u / a])
    # The centroid of member 1's polygon is its shifted axis (0.5, 0): the walls' positions set it.
    np.testing.assert_allclose(np.asarray(reference[:, :2]), rates[:, None] * [[0.05, -0.02]], rtol=1e-12)
    assert np.all(np.asarray(reference[:, 2]) == 0.0)  # platens at rest


def test_walls_at_rest_or_servo_controlled_give_the_absolute_law_bit_for_bit(precision):
    # A rigid box with spheres given random velocities, its walls at rest, then servo-controlled (as in
    # consolidation, where they move at the servo's velocity): the reference field is exactly 0 both times,
    # so 200 steps of either frame, local and viscous damping at once, end in the same bits.
    test = rigid.rigid_wall_test(fcc.fcc_specimen(D, 4, 4), 1e4, time_step=2e-6)
    rng = np.random.default_rng(3)
    moving = test.initial_state.set(
        velocity=jnp.asarray(
            rng.normal(0.0, 1e-3, test.initial_state.velocity.shape), test.initial_state.velocity.dtype
        )
    )
    _, step = integrate.sphere_dem(test.particles, test.runner.neighbor_frame, test.dt, wall_friction=False)
    runs = {}
    for frame in ("absolute", "affine"):
        damping = integrate.DampingParams(
            local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(500.0), frame=frame
        )
        params = test.params.set(damping=damping)
        run = jax.jit(lambda s, p=params: jax.lax.fori_loop(0, 200, lambda _, x: step(x, p), s))
        runs[frame] = [run(test.set_walls(moving, False, 0.0, 1e4)), run(test.start_consolidation(moving))]
    for at_rest, servo in zip(runs["absolute"], runs["affine"], strict=True):
        assert np.array_equal(np.asarray(at_rest.position), np.asarray(servo.position))
        assert np.array_equal(np.asarray(at_rest.velocity), np.asarray(servo.velocity))
    servo_end = runs["affine"][1]
    assert np.any(np.asarray(servo_end.walls.velocity) != 0.0)  # the servos moved the walls
    reference = walls_lib.affine_velocity(servo_end.position, servo_end.walls, test.particles.member)
    assert not np.any(np.asarray(reference))


def test_jit_and_vmap_over_members_with_their_own_platens():
    # Two members, platens closing at different speeds: the folded batch (one walls row per member), a
    # vmap over stacked single members and a loop give the same field, jitted.
    bottom, top = np.array([0.0, 0.1]), np.array([0.4, 0.6])
    up, down = np.array([0.002, 0.0]), np.array([-0.002, -0.005])
    z = np.array([[0.1, 0.3], [0.35, 0.1]])  # two spheres per member
    position = np.zeros((2, 2, 3))
    position[..., 2] = z
    loop = [
        walls_lib.affine_velocity(
            jnp.asarray(position[b]), platens(bottom[b], top[b], up[b], down[b]), jnp.zeros(2, jnp.int32)
        )
        for b in range(2)
    ]
    hand = up[:, None] + (down - up)[:, None] * (z - bottom[:, None]) / (top - bottom)[:, None]
    np.testing.assert_allclose(np.asarray(loop)[..., 2], hand, rtol=1e-12)
    stacked = batch.stack([platens(bottom[b], top[b], up[b], down[b]) for b in range(2)])
    vmapped = jax.jit(jax.vmap(lambda x, w: walls_lib.affine_velocity(x, w, jnp.zeros(2, jnp.int32))))(
        jnp.asarray(position), stacked
    )
    np.testing.assert_allclose(np.asarray(vmapped), np.asarray(loop), rtol=1e-12, atol=0.0)
    folded_walls = platens(0.0, 1.0, 0.0, 0.0, num_members=2).set(
        position=jnp.asarray(np.stack([-bottom, top], axis=1)),
        velocity=jnp.asarray(np.stack([-up, down], axis=1)),
    )
    folded = jax.jit(walls_lib.affine_velocity)(
        jnp.asarray(position.reshape(4, 3)), folded_walls, jnp.asarray([0, 0, 1, 1], jnp.int32)
    )
    np.testing.assert_allclose(np.asarray(folded).reshape(2, 2, 3), np.asarray(loop), rtol=1e-12, atol=0.0)


def test_viscous_damping_is_differentiable_in_the_platen_velocities(precision):
    # F_d,z = F_z − γ m (v_z − v_b − (v_t − v_b) s): ∂/∂v_t = γ m s, ∂/∂v_b = γ m (1 − s); through the planes'
    # dh/dt (v_b = −dh_0/dt) the bottom's is −γ m (1 − s). Hand values at s = 1/4, γ = 40/s, m = 0.05 kg.
    position = jnp.asarray([[0.0, 0.0, 0.1]])
    damping = integrate.DampingParams.viscous(40.0)

    def damped_z(plane_velocity):
        walls = platens(0.0, 0.4, 0.0, 0.0).set(velocity=plane_velocity[None, :])
        reference = walls_lib.affine_velocity(position, walls, jnp.zeros(1, jnp.int32))
        force = integrate.apply_damping(
            jnp.asarray([[0.0, 0.0, 2.0]]),
            jnp.asarray([[0.0, 0.0, 0.01]]),
            jnp.asarray([0.05]),
            damping,
            jnp.zeros(1, jnp.int32),
            reference,
        )
        return force[0, 2]

    gradient = jax.jit(jax.grad(damped_z))(jnp.asarray([-0.003, -0.001]))
    np.testing.assert_allclose(
        np.asarray(gradient), [-40.0 * 0.05 * 0.75, 40.0 * 0.05 * 0.25], rtol=tolerance(precision)
    )


def chain_excess(frame, num_spheres=8, speed=0.01, duration=0.003):
    """A column of ``num_spheres`` touching spheres between platens closing at ``speed`` each (m/s), with
    the viscous damping that removes what α = 0.3 does per cycle, run for ``duration`` (s): returns (the
    platens' mean stress − the Love–Weber stress, γ m, the pair contacts' closing rate r_p), Pa, kg/s, m/s."""
    z = R + D * np.arange(num_spheres)
    position = jnp.asarray(np.stack([np.zeros(num_spheres), np.zeros(num_spheres), z], axis=1), dtype=float)
    particles = integrate.make_particles(jnp.full(num_spheres, R, position.dtype), GRANITE_DENSITY)
    frame_fn = neighbors.pair_neighbor_fn([-D, -D, -R], [D, D, num_spheres * D + R], D, 0.2 * D, D)
    walls = walls_lib.triaxial_walls(np.zeros((0, 2)), np.zeros(0), num_spheres * D)
    law = contact.ContactParams.paper()
    init, _ = integrate.sphere_dem(particles, frame_fn, 1.0, wall_friction=False)
    state = init(position, walls, frame_fn.allocate(position))
    stiffness, mass = float(law.normal_stiffness), float(particles.mass[0])
    damping = integrate.DampingParams.equivalent_viscous(stiffness, mass, frame=frame)
    params = integrate.DEMParams(law, damping)
    dt = 0.5 * stability.critical_time_step(state, particles, params)
    _, step = integrate.sphere_dem(particles, frame_fn, dt, wall_friction=False)
    state = state.set(walls=walls_lib.set_control(state.walls, False, -speed, 0.0))  # both close
    end = jax.jit(lambda s: jax.lax.fori_loop(0, int(duration / dt), lambda _, x: step(x, params), s))(state)
    area = D * D
    height = jnp.asarray([num_spheres * D])
    records = measure(
        end, particles, params, dt, height, area * height, platen_area=area, wall_friction=False
    )
    # Equal wall and pair stiffnesses: the N + 1 contacts close alike, r_p = 2V/(N + 1).
    closing = 2 * speed / (num_spheres + 1)
    excess = float(records.wall_axial_stress[0] - records.love_weber_axial_stress[0])
    return excess, float(damping.viscous_rate) * mass, closing, int(end.error)


def test_absolute_viscous_damping_loads_the_platens_of_a_compressed_chain_and_the_affine_frame_does_not(
    precision,
):
    # A chain of N spheres compressed at a steady rate: each sphere moves at constant velocity v_i, so its
    # contacts balance its damping, c_i − c_{i−1} = −D_i. Absolute: D_i = −γ m v_i, v_i = −(r/2)(2i − N − 1)
    # (r the contacts' closing rate), so c_j = P − γ m (r/2) j(N − j) and the Love–Weber average
    # [Σ_{j<N} c_j + P]/N falls short of the platen force P by γ m r (N² − 1)/12 (Σ_j j(N − j) = N(N² − 1)/6),
    # over the area A. Affine: the centres sit R from the platens, so the chain's motion is the platens'
    # interpolation less 1/N of it (u_i = −v_i/N: the two wall contacts are half the pairs' spacing): the
    # excess is −1/N of the absolute one. Tolerances: the start-up wave left, e^(−γT/2) ≈ 2e-3, and O(δ/R)
    # geometry (5e-4); float32 adds a contact force's round-off, ulp(2R) k_n ≈ 0.015 N of the 1 N excess.
    excess, drag, closing, error = chain_excess("absolute")
    assert error == 0
    num = 8
    hand = drag * closing * (num**2 - 1) / 12 / D**2
    rtol = {np.dtype(np.float64): 5e-3, np.dtype(np.float32): 2e-2}[precision]
    assert excess == pytest.approx(hand, rel=rtol)
    affine, _, _, _ = chain_excess("affine")
    # The same absolute error on an 8× smaller value.
    assert affine == pytest.approx(-hand / num, rel=8 * rtol)


@pytest.mark.slow
def test_local_damping_drag_on_the_platens_of_a_rigid_box_is_what_the_affine_frame_removes():
    # A 6 × 6 × 10 FCC rigid box at 10 kPa (the demo's specimen), both platens closing at I = 1e-3 after a
    # ramp to 1 % strain, records over 1–2 % (float64). Each sphere's balance of momentum, summed with its
    # height, gives the platens' mean stress less the Love–Weber stress as the damping forces' first moment,
    # (1/V) Σ D_z (z − z_mid), D = F_d − F (inertia at I = 1e-3 is I² σ ~ 1e-6 of it): checked in both
    # frames within 10 % (the records sample a fluctuating drag every 50 steps). Absolute local damping
    # drags the spheres against the platens' motion; the affine frame removes that part, leaving the
    # damping of the non-affine motion (measured here 0.58 % of σ1 against 1.03 %; 0.34 % against 0.68 %
    # while the lateral walls' proportional servo let σ3, and with it σ1, run well above σc (1.37–1.45 σc
    # past 0.1 % strain in a 6 × 10 box at 40 kPa): about the same drag over a smaller stress).
    test = rigid.rigid_wall_test(fcc.fcc_specimen(D, 6, 10), 1e4)
    state, _ = test.consolidate()
    member = test.particles.member

    def drag_moment(s, p):  # Σ D_z (z − z_mid) at the record's state, N·m
        forces = integrate.compute_forces(s, test.particles, p, test.dt, wall_friction=False)
        reference = (
            walls_lib.affine_velocity(s.position, s.walls, member) if p.damping.frame == "affine" else None
        )
        damped = integrate.apply_damping(
            forces.force, s.velocity, test.particles.mass, p.damping, member, reference
        )
        middle = 0.5 * (s.walls.position[0, walls_lib.TOP] - s.walls.position[0, walls_lib.BOTTOM])
        return jnp.sum((damped - forces.force)[:, 2] * (s.position[:, 2] - middle))

    excess, drag = {}, {}
    for frame in ("absolute", "affine"):
        old = test.runner
        runner_ = type(old)(
            old.step_fn,
            old.neighbor_frame,
            lambda s, p, f=old.record_fn: (f(s, p), drag_moment(s, p)),
            old.num_particles,
        )
        framed = dataclasses.replace(
            test, runner=runner_, params=test.params.set(damping=integrate.DampingParams.local(0.3, frame))
        )
        _, (records, moment) = framed.shear(
            state,
            0.02,
            1e-3,
            record_every_fine=50,
            record_every_coarse=50,
            fine_until_strain=0.02,
            ramp_strain=0.01,
            symmetric=True,
        )
        keep = np.asarray(records.axial_strain)[:, 0] >= 0.01
        wall = np.mean(np.asarray(records.wall_axial_stress)[keep, 0])
        contact_stress = np.mean(np.asarray(records.love_weber_axial_stress)[keep, 0])
        volume = np.asarray(records.area)[keep, 0] * np.asarray(records.height)[keep, 0]
        excess[frame] = wall - contact_stress
        drag[frame] = np.mean(np.asarray(moment)[keep] / volume)
        assert excess[frame] == pytest.approx(drag[frame], rel=0.1), frame
        excess[frame] /= contact_stress
    assert 0.0 < excess["affine"] < 0.01 and excess["affine"] < 0.7 * excess["absolute"], excess


def test_membrane_nodes_moving_with_the_reference_are_not_damped_and_none_is_the_absolute_law(precision):
    # The node update (compiled kernel on the CPU, JAX elsewhere): free nodes moving exactly at v_ref keep
    # their force undamped, v' = v + Δt F/m; a None reference and a zero one give the same bits.
    rng = np.random.default_rng(5)
    n = 60
    free = np.ones(n, dtype=bool)
    free[:6] = False
    velocity = jnp.asarray(rng.normal(0.0, 0.01, (n, 3)))
    nodes = node_update.MembraneNodes(
        position=jnp.asarray(rng.uniform(-0.1, 0.1, (n, 3))),
        position_compensation=jnp.zeros((n, 3)),
        velocity=velocity,
        mass=jnp.asarray(rng.uniform(5e-5, 1.5e-4, n)),
        free=jnp.asarray(free),
    )
    membrane_force = jnp.asarray(rng.normal(0.0, 1.0, (n, 3)))
    contact_force = jnp.asarray(rng.normal(0.0, 0.5, (n, 3)))
    damping = integrate.DampingParams(local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(5.0))
    dt = 2e-6
    step = jax.jit(node_update.advance_nodes)
    _, moved, _, _ = step(membrane_force, contact_force, nodes.set(reference_velocity=velocity), dt, damping)
    undamped = velocity + dt * (membrane_force + contact_force) / nodes.mass[:, None]
    # Round-off of v + Δt F/m is relative to its terms' size, not to the sum (some nearly cancel).
    scale = tolerance(precision) * float(jnp.max(jnp.abs(undamped)))
    np.testing.assert_allclose(np.asarray(moved)[free], np.asarray(undamped)[free], rtol=0.0, atol=scale)
    assert np.all(np.asarray(moved)[~free] == 0.0)
    none = step(membrane_force, contact_force, nodes, dt, damping)
    zeros = step(membrane_force, contact_force, nodes.set(reference_velocity=jnp.zeros((n, 3))), dt, damping)
    for a, b in zip(none, zeros, strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))


def test_the_frame_is_a_configuration_field_and_a_static_part_of_the_damping():
    assert TriaxialConfig().damping_frame == "affine"
    assert assemble.damping_params(TriaxialConfig()).frame == "affine"
    absolute = assemble.damping_params(TriaxialConfig(damping_frame="absolute", viscous_damping=True))
    assert absolute.frame == "absolute" and float(absolute.viscous_rate) > 0.0
    with pytest.raises(ConfigError, match="damping_frame must be one of 'affine', 'absolute'"):
        TriaxialConfig(damping_frame="platens")
    with pytest.raises(ValueError, match="frame"):
        integrate.DampingParams.local(0.3, "relative")
    # Static: not a leaf (a traced rollout sees the two arrays only), so jit specialises on it.
    assert len(jax.tree.leaves(integrate.DampingParams.local(0.3))) == 2
    assert jax.tree.structure(integrate.DampingParams.local(0.3, "affine")) != jax.tree.structure(
        integrate.DampingParams.local(0.3, "absolute")
    )
