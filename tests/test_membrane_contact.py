"""Node–sphere membrane contacts: the law against hand calculations, conservation, candidates, jit/vmap."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tolerance

from membrax.membrane.candidates import (
    ERROR_MEMBRANE_CANDIDATE_OVERFLOW,
    build_candidates,
    candidate_errors,
    cell_grid,
    needs_rebuild,
    remap_node_history,
    sphere_slot_table,
    update_candidates,
)
from membrax.membrane.contact import (
    ContactNodes,
    ContactSpheres,
    MembraneContactParams,
    node_sphere_forces,
    node_sphere_normal_energy,
)

THICKNESS = 0.005
MU = math.tan(math.radians(25.0))


def _one_node_call(node, sphere, radius, spring=None, node_velocity=None, params=None, dt=1e-6):
    params = MembraneContactParams.default() if params is None else params
    node_position = jnp.asarray(node)[None, :]
    spring = jnp.zeros((3, 1, 1)) if spring is None else spring
    velocity = jnp.zeros((1, 3)) if node_velocity is None else node_velocity
    return node_sphere_forces(
        ContactNodes(position=node_position, velocity=velocity),
        ContactSpheres(
            position=jnp.asarray(sphere)[None, :],
            velocity=jnp.zeros((1, 3)),
            angular_velocity=jnp.zeros((1, 3)),
            radius=jnp.asarray([radius]),
        ),
        jnp.zeros((1, 1), dtype=jnp.int32),
        spring,
        dt,
        params,
        THICKNESS,
    )


def _random_config(seed, num_nodes=30, num_spheres=6, box=0.03):
    rng = np.random.default_rng(seed)
    return dict(
        node_position=jnp.asarray(rng.uniform(0.0, box, (num_nodes, 3))),
        node_velocity=jnp.asarray(rng.normal(0.0, 0.1, (num_nodes, 3))),
        sphere_position=jnp.asarray(rng.uniform(0.0, box, (num_spheres, 3))),
        sphere_velocity=jnp.asarray(rng.normal(0.0, 0.1, (num_spheres, 3))),
        sphere_angular_velocity=jnp.asarray(rng.normal(0.0, 10.0, (num_spheres, 3))),
        sphere_radius=jnp.asarray(rng.uniform(0.006, 0.01, num_spheres)),
    )


def _bodies(config, node_position=None):
    """The nodes and spheres of a configuration, as node_sphere_forces takes them (other node positions if
    given)."""
    nodes = ContactNodes(
        position=config["node_position"] if node_position is None else node_position,
        velocity=config["node_velocity"],
    )
    spheres = ContactSpheres(
        position=config["sphere_position"],
        velocity=config["sphere_velocity"],
        angular_velocity=config["sphere_angular_velocity"],
        radius=config["sphere_radius"],
    )
    return nodes, spheres


def _forces(config, candidates, spring, params=None, dt=1e-5):
    params = MembraneContactParams.default() if params is None else params
    return node_sphere_forces(
        *_bodies(config),
        candidates,
        spring,
        dt,
        params,
        THICKNESS,
    )


_jit_forces = jax.jit(_forces)


def _candidate_args(config, skin):
    """build_candidates' arguments before the capacity: ``config``'s nodes and spheres, skin."""
    return (config["node_position"], config["sphere_position"], config["sphere_radius"], THICKNESS, skin)


# A grid for any _random_config (radii at most 10 mm, skin 2 mm): cells of 22 mm over the 30 mm box, room
# for every sphere in one cell. Under jit the grid is static (build_candidates cannot make it from traced
# positions); a grid made from other positions is still exact, since points outside it are clipped in.
_GRID = cell_grid(np.array([[0.0, 0.0, 0.0], [0.03, 0.03, 0.03]]), [0.01, 0.01], 0.002, 6)


def _all_candidates(config):
    num_spheres = config["sphere_position"].shape[0]
    return build_candidates(*_candidate_args(config, 0.002), num_spheres, grid=_GRID)


def test_default_parameters_and_time_scale():
    params = MembraneContactParams.default()
    assert float(params.normal_stiffness) == 1e5
    assert float(params.tangential_stiffness) == 1e5
    assert float(params.friction_coefficient) == pytest.approx(MU, rel=1e-15)
    # Interior node of a 5 mm near-equilateral mesh, t = 5 mm, 1000 kg/m³: m = (√3/2) a² t ρ = 1.08e-4 kg.
    mass = math.sqrt(3.0) / 2.0 * 0.005**2 * 0.005 * 1000.0
    assert mass == pytest.approx(1.0825e-4, rel=1e-4)
    assert math.sqrt(mass / float(params.normal_stiffness)) == pytest.approx(3.29e-5, rel=1e-2)


def test_normal_force_is_k_delta_along_outward_normal_and_minus_grad(precision):
    radius, overlap = 0.01, 2.0e-4
    direction = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    sphere = np.array([0.1, 0.2, -0.05])
    node = sphere + (radius + THICKNESS / 2 - overlap) * direction
    result = _one_node_call(node, sphere, radius)
    assert result.node_force.dtype == precision
    # The overlap is a difference of lengths near R + t_m/2 = 12.5 mm: its round-off relative to δ = 0.2 mm
    # is 60× the positions'.
    rtol = 100 * tolerance(precision)
    expected = 1e5 * overlap * direction
    np.testing.assert_allclose(result.node_force[0], expected, rtol=rtol)
    np.testing.assert_allclose(result.sphere_force[0], -expected, rtol=rtol)
    assert float(result.normal_force[0, 0]) == pytest.approx(1e5 * overlap, rel=rtol)
    assert float(result.overlap[0, 0]) == pytest.approx(overlap, rel=rtol)
    # The normal torque on the sphere vanishes (force along the arm).
    np.testing.assert_allclose(result.sphere_torque[0], 0.0, atol=1e-3 * rtol * 1e5 * overlap * radius)
    energy, grad = jax.value_and_grad(node_sphere_normal_energy)(
        jnp.asarray(node)[None, :],
        jnp.asarray(sphere)[None, :],
        jnp.asarray([radius]),
        jnp.zeros((1, 1), dtype=jnp.int32),
        1e5,
        THICKNESS,
    )
    np.testing.assert_allclose(-grad[0], expected, rtol=rtol)
    assert float(energy) == pytest.approx(0.5 * 1e5 * overlap**2, rel=2 * rtol)


def test_static_balance_overlap_is_force_over_stiffness():
    # A node pressed onto the sphere's top by F: the contact balances F exactly at δ = F/k_n.
    radius, load = 0.01, 0.7
    overlap = load / 1e5
    node = np.array([0.0, 0.0, radius + THICKNESS / 2 - overlap])
    result = _one_node_call(node, np.zeros(3), radius)
    np.testing.assert_allclose(result.node_force[0] + np.array([0.0, 0.0, -load]), 0.0, atol=1e-12)


@pytest.mark.parametrize("gap", [1e-4, 0.0])
def test_no_force_in_a_gap_or_exactly_at_the_threshold(gap):
    radius = 0.01
    node = np.array([radius + 0.5 * THICKNESS + gap, 0.0, 0.0])
    result = _one_node_call(node, np.zeros(3), radius, spring=jnp.full((3, 1, 1), 0.3))
    assert float(result.overlap[0, 0]) == pytest.approx(-gap, abs=1e-15)
    assert float(result.overlap[0, 0]) <= 0.0
    np.testing.assert_array_equal(result.node_force, 0.0)
    np.testing.assert_array_equal(result.sphere_force, 0.0)
    np.testing.assert_array_equal(result.spring, 0.0)  # the contact opened: the spring is cleared


def _push(tangential_load, steps=3000):
    """Node of mass 1e-4 kg on top of a fixed sphere (R = 1 m), pressed by N = 1 N, pushed along x by T."""
    radius, normal_load, mass, dt = 1.0, 1.0, 1e-4, 1e-6
    params = MembraneContactParams.default()
    damping = 0.5 * 2.0 * math.sqrt(mass * 1e5)  # ζ = 0.5 on the node's absolute velocity
    external = jnp.asarray([tangential_load, 0.0, -normal_load])
    start = jnp.asarray([[0.0, 0.0, radius + 0.5 * THICKNESS - normal_load / 1e5]])

    def step(carry, _):
        position, velocity, spring = carry
        result = _one_node_call(position[0], jnp.zeros(3), radius, spring, velocity, params, dt)
        force = result.node_force + external[None, :] - damping * velocity
        velocity = velocity + (dt / mass) * force
        return (position + dt * velocity, velocity, result.spring), result.normal_force[0, 0]

    carry = (start, jnp.zeros((1, 3)), jnp.zeros((3, 1, 1)))
    (position, velocity, spring), normal_force = jax.jit(lambda c: jax.lax.scan(step, c, None, length=steps))(
        carry
    )
    return position[0], velocity[0], spring[:, 0, 0], normal_force[-1]


def test_stick_below_the_coulomb_limit():
    tangential_load = 0.8 * MU * 1.0
    position, velocity, spring, normal_force = _push(tangential_load)
    assert float(normal_force) == pytest.approx(1.0, rel=1e-4)
    # The spring holds the push; the node sits displaced by T/k_t and is at rest.
    assert float(-spring[0]) == pytest.approx(tangential_load, rel=1e-4)
    assert float(position[0]) == pytest.approx(tangential_load / 1e5, rel=1e-3)
    assert float(jnp.max(jnp.abs(velocity))) < 1e-6


def test_slip_above_the_coulomb_limit():
    tangential_load = 1.2 * MU * 1.0
    position, velocity, spring, normal_force = _push(tangential_load)
    assert float(normal_force) == pytest.approx(1.0, rel=1e-3)
    # Sliding: friction is capped at μ F_n, against the motion, and the node keeps moving along x.
    assert float(jnp.linalg.norm(spring)) == pytest.approx(MU * float(normal_force), rel=1e-12)
    assert float(-spring[0]) == pytest.approx(MU * float(normal_force), rel=1e-6)
    assert float(velocity[0]) > 0.01
    assert float(position[0]) > 10.0 * tangential_load / 1e5


@pytest.mark.parametrize("seed", [0, 1])
def test_action_reaction_and_angular_momentum(seed, precision):
    config = _random_config(seed)
    candidates = _all_candidates(config)
    rng = np.random.default_rng(seed + 10)
    spring = jnp.asarray(rng.normal(0.0, 0.05, (3, *candidates.idx.shape)))
    result = _jit_forces(config, candidates.idx, spring)
    assert int(jnp.sum(result.normal_force > 0.0)) >= 10  # a real test: many contacts, many sliding
    node_force, sphere_force = np.asarray(result.node_force), np.asarray(result.sphere_force)
    assert node_force.dtype == precision
    scale = np.max(np.abs(node_force))
    atol = 0.1 * tolerance(precision) * scale
    np.testing.assert_allclose(node_force.sum(0) + sphere_force.sum(0), 0.0, atol=atol)
    moment = (
        np.cross(np.asarray(config["node_position"]), node_force).sum(0)
        + np.cross(np.asarray(config["sphere_position"]), sphere_force).sum(0)
        + np.asarray(result.sphere_torque).sum(0)
    )
    np.testing.assert_allclose(moment, 0.0, atol=atol * 0.03)
    # Friction torques are present (the check above is not trivially about central forces).
    assert float(jnp.max(jnp.abs(result.sphere_torque))) > 1e-6


def test_normal_forces_are_minus_gradient_of_the_energy():
    config = _random_config(3)
    candidates = _all_candidates(config)
    zero_spring = jnp.zeros((3, *candidates.idx.shape))
    still = dict(config, node_velocity=jnp.zeros_like(config["node_velocity"]))
    still.update(sphere_velocity=jnp.zeros_like(config["sphere_velocity"]))
    still.update(sphere_angular_velocity=jnp.zeros_like(config["sphere_angular_velocity"]))
    result = _jit_forces(still, candidates.idx, zero_spring)
    grad_node, grad_sphere = jax.grad(node_sphere_normal_energy, argnums=(0, 1))(
        config["node_position"],
        config["sphere_position"],
        config["sphere_radius"],
        candidates.idx,
        1e5,
        THICKNESS,
    )
    np.testing.assert_allclose(result.node_force, -grad_node, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(result.sphere_force, -grad_sphere, rtol=1e-12, atol=1e-12)
    assert float(jnp.max(jnp.abs(grad_node))) > 1.0


def test_gradient_is_finite_at_coincident_centre_and_padding():
    node = jnp.zeros((2, 3))
    candidates = jnp.asarray([[0, 1], [1, 1]], dtype=jnp.int32)  # 1 = N pads
    grad = jax.grad(node_sphere_normal_energy)(
        node, jnp.zeros((1, 3)), jnp.asarray([0.01]), candidates, 1e5, 0.0
    )
    assert bool(jnp.all(jnp.isfinite(grad)))


def _brute_force_sets(config, skin):
    node = np.asarray(config["node_position"])
    sphere = np.asarray(config["sphere_position"])
    radius = np.asarray(config["sphere_radius"])
    distance = np.linalg.norm(node[:, None, :] - sphere[None, :, :], axis=-1)
    within = distance < (radius + THICKNESS / 2 + skin)[None, :]
    return [set(np.flatnonzero(row).tolist()) for row in within]


def _assert_rows_are(idx, reference, num_spheres):
    """Each row holds exactly its reference set, in increasing id order, padded with N."""
    for row, expected in zip(np.asarray(idx), reference, strict=True):
        found = row[row < num_spheres]
        np.testing.assert_array_equal(found, sorted(expected))
        assert np.all(row[len(found) :] == num_spheres)


def test_candidates_match_brute_force_and_flag_overflow():
    config = _random_config(5, num_nodes=200, num_spheres=40, box=0.08)
    skin = 0.003
    reference = _brute_force_sets(config, skin)
    largest = max(len(s) for s in reference)
    assert largest >= 3
    args = _candidate_args(config, skin)
    grid = cell_grid(config["sphere_position"], config["sphere_radius"], skin)
    # Cells of 2 R_max + skin: fewer than 27 cells' worth of the box, so the search skips most spheres.
    assert grid.edge == pytest.approx(2 * float(jnp.max(config["sphere_radius"])) + skin)
    assert grid.num_cells > 27
    build = jax.jit(build_candidates, static_argnames=("capacity", "grid"))
    candidates = build(*args, capacity=largest + 2, grid=grid)
    _assert_rows_are(candidates.idx, reference, 40)
    assert int(candidates.max_count) == largest
    assert not bool(candidates.did_overflow)
    assert int(candidate_errors(candidates)) == 0
    small = build_candidates(*args, largest - 1)
    assert bool(small.did_overflow)
    assert int(candidate_errors(small)) == ERROR_MEMBRANE_CANDIDATE_OVERFLOW
    assert int(small.max_count) == largest
    # A cell holding more spheres than C is an overflow too (the fullest cell's count reported).
    crowded = build_candidates(*args, largest + 2, grid=grid._replace(cell_capacity=1))
    assert bool(crowded.did_overflow)
    assert int(crowded.max_cell_count) == int(candidates.max_cell_count) > 1


def test_candidates_outside_the_grid_are_still_found():
    """A grid made for the spheres where they were finds every pair after the whole configuration moved
    off it (a specimen bulging out of its first bounding box): points outside are clipped into the
    boundary cells, which never separates two points in neighbouring cells."""
    config = _random_config(8, num_nodes=150, num_spheres=30, box=0.06)
    skin = 0.002
    grid = cell_grid(config["sphere_position"], config["sphere_radius"], skin, cell_capacity=30)
    for shift in ([0.2, 0.0, 0.0], [-0.1, 0.3, -0.25]):
        moved = {
            **config,
            "node_position": config["node_position"] + jnp.asarray(shift)[None, :],
            "sphere_position": config["sphere_position"] + jnp.asarray(shift)[None, :],
        }
        candidates = build_candidates(*_candidate_args(moved, skin), 12, grid=grid)
        assert not bool(candidates.did_overflow)
        _assert_rows_are(candidates.idx, _brute_force_sets(moved, skin), 30)
    # Stretched to twice its size about the origin: pairs now split across clipped cells.
    stretched = {
        **config,
        "node_position": 2.0 * config["node_position"],
        "sphere_position": 2.0 * config["sphere_position"],
    }
    candidates = build_candidates(*_candidate_args(stretched, skin), 12, grid=grid)
    _assert_rows_are(candidates.idx, _brute_force_sets(stretched, skin), 30)


def test_a_membrane_thicker_than_the_spheres_is_refused():
    config = _random_config(5)
    with pytest.raises(ValueError, match="exceeds the largest sphere's diameter"):
        build_candidates(
            config["node_position"], config["sphere_position"], config["sphere_radius"], 0.03, 0.002, 3
        )


def test_remap_node_history_follows_sphere_ids():
    num_spheres = 9
    old_idx = jnp.asarray([[3, 7, 1, 9], [0, 9, 9, 9]], dtype=jnp.int32)
    new_idx = jnp.asarray([[1, 4, 3, 9, 9], [9, 0, 9, 9, 9]], dtype=jnp.int32)
    history = jnp.stack([old_idx, -old_idx, 10 * old_idx], axis=-1).astype(jnp.float64)
    carried = remap_node_history(old_idx, new_idx, history, num_spheres)
    expected = np.zeros((2, 5, 3))
    expected[0, 0] = [1, -1, 10]
    expected[0, 2] = [3, -3, 30]
    expected[1, 1] = [0, 0, 0]
    np.testing.assert_array_equal(carried, expected)
    assert carried.shape == (2, 5, 3)
    # The carried springs' layout, (3, n_nodes, K): the same values.
    springs = remap_node_history(
        old_idx, new_idx, jnp.moveaxis(history, -1, 0), num_spheres, components_first=True
    )
    np.testing.assert_array_equal(springs, np.moveaxis(expected, -1, 0))
    # The carry goes through a table of source slots, int8 up to 126 old slots and int32 past them: an old
    # table padded to 130 slots (ids beyond the fourth are padding) carries the same values.
    wide_old = jnp.pad(old_idx, ((0, 0), (0, 126)), constant_values=num_spheres)
    wide_history = jnp.pad(history, ((0, 0), (0, 126), (0, 0)), constant_values=-5.0)
    np.testing.assert_array_equal(remap_node_history(wide_old, new_idx, wide_history, num_spheres), expected)


def test_remap_of_springs_is_linear_and_its_gradient_carries_back_by_the_same_ids():
    # The carry is a 0/1 matching of equal real ids, symmetric in the two tables, so its transpose (the
    # gradient of <w, carried> with respect to the old springs) is the carry from the new table back to
    # the old one; checked jitted and vmapped over two members, in float32.
    num_spheres = 9
    old_idx = jnp.asarray([[3, 7, 1, 9], [0, 9, 9, 9]], dtype=jnp.int32)
    new_idx = jnp.asarray([[1, 4, 3, 9, 9], [9, 0, 9, 9, 9]], dtype=jnp.int32)
    rng = np.random.default_rng(3)
    springs = jnp.asarray(rng.normal(size=(2, 3, 2, 4)), jnp.float32)
    weights = jnp.asarray(rng.normal(size=(2, 3, 2, 5)), jnp.float32)

    def pairing(spring, weight):
        carried = remap_node_history(old_idx, new_idx, spring, num_spheres, components_first=True)
        return jnp.sum(weight * carried)

    gradient = jax.jit(jax.vmap(jax.grad(pairing)))(springs, weights)
    back = jax.vmap(lambda w: remap_node_history(new_idx, old_idx, w, num_spheres, components_first=True))
    np.testing.assert_array_equal(gradient, back(weights))
    assert gradient.dtype == jnp.float32


def test_update_rebuilds_only_beyond_half_skin_and_carries_springs():
    config = _random_config(11, num_nodes=120, num_spheres=30, box=0.06)
    num_spheres = 30
    skin = 0.004
    candidates = build_candidates(*_candidate_args(config, skin), 12)
    assert not bool(candidates.did_overflow)
    # Spring value encodes (node, sphere id) so we can tell where it went.
    idx = candidates.idx
    node_id = jnp.broadcast_to(jnp.arange(idx.shape[0], dtype=jnp.int32)[:, None], idx.shape)
    valid = idx < num_spheres
    spring = jnp.where(valid[None], jnp.stack([node_id, idx, node_id + idx]), 0).astype(jnp.float64)
    update = jax.jit(update_candidates)

    moved = config["sphere_position"] + jnp.asarray([0.4 * skin, 0.0, 0.0])[None, :]
    same, same_spring = update(
        candidates, spring, config["node_position"], moved, config["sphere_radius"], THICKNESS
    )
    assert not bool(needs_rebuild(candidates, config["node_position"], moved))
    np.testing.assert_array_equal(same.idx, candidates.idx)
    np.testing.assert_array_equal(same_spring, spring)

    # Move beyond skin/2: a rebuild (pairs enter and leave, so slots shift); springs follow their ids.
    moved = config["sphere_position"] + jnp.asarray([0.6 * skin, 0.0, 0.0])[None, :]
    assert bool(needs_rebuild(candidates, config["node_position"], moved))
    new, new_spring = update(
        candidates, spring, config["node_position"], moved, config["sphere_radius"], THICKNESS
    )
    np.testing.assert_array_equal(new.reference_sphere_position, moved)
    reference = _brute_force_sets(dict(config, sphere_position=moved), skin)
    new_idx, old_idx = np.asarray(new.idx), np.asarray(idx)
    kept = 0
    for node in range(new_idx.shape[0]):
        assert set(new_idx[node][new_idx[node] < num_spheres].tolist()) == reference[node]
        for slot, sphere in enumerate(new_idx[node]):
            if sphere < num_spheres and sphere in old_idx[node]:
                np.testing.assert_array_equal(new_spring[:, node, slot], [node, sphere, node + sphere])
                kept += 1
            else:
                np.testing.assert_array_equal(new_spring[:, node, slot], 0.0)
    assert kept > 50


def test_jit_and_vmap_equal_a_loop():
    configs = [_random_config(20), _random_config(21)]
    params = MembraneContactParams.default()
    build = jax.jit(jax.vmap(_all_candidates))
    batch = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *configs)
    batched_candidates = build(batch)
    rng = np.random.default_rng(3)
    springs = jnp.asarray(rng.normal(0.0, 0.05, (2, 3, 30, 6)))

    def forces(config, idx, spring):
        return _forces(config, idx, spring, params)

    batched = jax.jit(jax.vmap(forces))(batch, batched_candidates.idx, springs)
    jitted = jax.jit(forces)
    build_one = jax.jit(_all_candidates)
    for member, config in enumerate(configs):
        candidates = build_one(config)
        np.testing.assert_array_equal(batched_candidates.idx[member], candidates.idx)
        compiled = jitted(config, candidates.idx, springs[member])
        if member == 0:  # eager (op by op) once: it is slow to dispatch
            looped = forces(config, candidates.idx, springs[member])
            for a, b in zip(looped, compiled, strict=True):
                np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-15)
        for b, c in zip(compiled, batched, strict=True):
            np.testing.assert_allclose(c[member], b, rtol=1e-12, atol=1e-15)

    # update_candidates under vmap (its cond becomes a select): member 0 rebuilds, member 1 does not.
    shift = jnp.asarray([[0.0015, 0.0, 0.0], [0.0002, 0.0, 0.0]])
    moved = batch["sphere_position"] + shift[:, None, :]
    update = jax.jit(jax.vmap(update_candidates, in_axes=(0, 0, 0, 0, 0, None)))
    update_one = jax.jit(update_candidates)
    new, new_springs = update(
        batched_candidates, springs, batch["node_position"], moved, batch["sphere_radius"], THICKNESS
    )
    for member, config in enumerate(configs):
        candidates = jax.tree_util.tree_map(lambda x, m=member: x[m], batched_candidates)
        one, one_spring = update_one(
            candidates,
            springs[member],
            config["node_position"],
            moved[member],
            config["sphere_radius"],
            THICKNESS,
        )
        np.testing.assert_array_equal(new.idx[member], one.idx)
        np.testing.assert_array_equal(new_springs[member], one_spring)
        np.testing.assert_array_equal(new.reference_sphere_position[member], one.reference_sphere_position)
    np.testing.assert_array_equal(new.reference_sphere_position[0], moved[0])
    np.testing.assert_array_equal(new.reference_sphere_position[1], batch["sphere_position"][1])


def test_sphere_incidence_sums_equal_the_segment_sum_scatter():
    """The gathered sphere sums (fast path) equal segment_sum on the same slots, also under vmap and grad."""
    config = _random_config(4, num_nodes=60, num_spheres=8)
    num_spheres = 8
    # Sphere 7 moved far away: it holds no slot and must get no force.
    config["sphere_position"] = config["sphere_position"].at[7].set(jnp.asarray([0.5, 0.5, 0.5]))
    candidates = build_candidates(*_candidate_args(config, 0.002), 4, sphere_capacity=40)
    idx, slots = np.asarray(candidates.idx), np.asarray(candidates.sphere_slots)
    # Hand count: sphere s owns exactly the flat slots whose id is s, in slot order.
    for sphere in range(num_spheres):
        owned = slots[sphere][slots[sphere] < idx.size]
        np.testing.assert_array_equal(owned, np.flatnonzero(idx.reshape(-1) == sphere))
    assert not np.any(idx == 7)
    assert int(candidates.max_sphere_count) == max(np.sum(idx == s) for s in range(num_spheres))
    assert int(candidates.max_sphere_count) >= 3 and not bool(candidates.did_overflow)
    spring = jnp.asarray(np.random.default_rng(5).normal(0.0, 0.05, (3, *idx.shape)))

    def both(node_position, spring):
        args = (
            *_bodies(config, node_position),
            candidates.idx,
            spring,
            1e-5,
            MembraneContactParams.default(),
            THICKNESS,
        )
        return node_sphere_forces(*args), node_sphere_forces(*args, sphere_slots=candidates.sphere_slots)

    scatter, gather = jax.jit(both)(config["node_position"], spring)
    scale = float(jnp.max(jnp.abs(scatter.sphere_force)))
    assert scale > 1.0
    np.testing.assert_allclose(gather.sphere_force, scatter.sphere_force, atol=1e-13 * scale)
    np.testing.assert_allclose(gather.sphere_torque, scatter.sphere_torque, atol=1e-13 * scale)
    np.testing.assert_array_equal(gather.sphere_force[7], 0.0)
    # vmap over two node configurations equals a loop.
    shifted = config["node_position"] + 1e-4
    batched = jax.vmap(both)(jnp.stack([config["node_position"], shifted]), jnp.stack([spring, spring]))
    np.testing.assert_allclose(batched[1].sphere_force[1], both(shifted, spring)[1].sphere_force, atol=1e-12)

    # Reverse mode through the gather path equals the scatter path.
    def loss(node_position, which):
        return jnp.sum(both(node_position, spring)[which].sphere_force ** 2)

    grad_gather = jax.grad(loss)(config["node_position"], 1)
    grad_scatter = jax.grad(loss)(config["node_position"], 0)
    np.testing.assert_allclose(grad_gather, grad_scatter, atol=1e-10 * float(jnp.max(jnp.abs(grad_scatter))))

    # Too small an M overflows, as K does.
    small = sphere_slot_table(candidates.idx, num_spheres, 2)
    assert int(small[1]) == int(candidates.max_sphere_count) and small[0].shape == (8, 2)
    tight = build_candidates(*_candidate_args(config, 0.002), 4, sphere_capacity=2)
    assert int(candidate_errors(tight)) == ERROR_MEMBRANE_CANDIDATE_OVERFLOW


def test_grown_candidate_capacities_follow_the_rule_by_hand():
    """Only what ran out grows: K = min(max(largest count + 2, ⌈1.5 K_old⌉), N) if the count exceeds K_old,
    M = largest sphere count + 8 if it exceeds M_old, C = fullest cell + 2 if it exceeds C_old; K by
    ⌈1.5 K_old⌉ if none does; stacked tables take the largest over members."""
    import types

    from membrax.membrane.candidates import grown_candidate_capacities

    old = types.SimpleNamespace(
        reference_sphere_position=np.zeros((50, 3)),
        idx=np.zeros((100, 4)),
        sphere_slots=np.zeros((50, 10)),
        cell_capacity=5,
    )

    def grown(count, sphere_count, cell_count):
        counts = {"max_count": count, "max_sphere_count": sphere_count, "max_cell_count": cell_count}
        return tuple(grown_candidate_capacities(old, types.SimpleNamespace(**counts)))

    assert grown(9, 15, 1) == (11, 23, 5)
    assert grown(3, 1, 7) == (4, 10, 9)  # a full cell widens no node's row
    assert grown(4, 12, 5) == (4, 20, 5)  # full sphere slots neither
    assert grown(70, 1, 1) == (50, 10, 5)
    assert grown(np.array([3, 9]), np.array([15, 2]), np.array([8, 1])) == (11, 23, 10)
    assert grown(2, 3, 1) == (6, 10, 5)  # nothing over its capacity: K grows, the rerun differs


def test_a_table_keeps_its_largest_counts_through_smaller_rebuilds():
    """After a rebuild with fewer candidates, the table still reports the largest counts since it was
    allocated (by hand: the brute-force sets of both configurations), and stays flagged."""
    config = _random_config(5, num_nodes=200, num_spheres=40, box=0.08)
    skin = 0.003
    crowded = max(len(s) for s in _brute_force_sets(config, skin))
    table = build_candidates(*_candidate_args(config, skin), crowded - 1)
    assert bool(table.did_overflow) and int(table.max_count) == crowded
    # The nodes moved 1 m off the spheres (beyond skin/2): a rebuild that finds no candidate at all.
    away = config["node_position"] + jnp.asarray([[1.0, 0.0, 0.0]])
    spring = jnp.zeros((3, away.shape[0], table.capacity))
    rebuilt, _, did = update_candidates(
        table, spring, away, config["sphere_position"], config["sphere_radius"], THICKNESS, with_rebuilt=True
    )
    assert bool(did) and int(jnp.sum(rebuilt.idx < 40)) == 0
    assert int(rebuilt.max_count) == crowded and bool(rebuilt.did_overflow)
    assert int(rebuilt.max_sphere_count) == int(table.max_sphere_count) > 0
    assert int(rebuilt.max_cell_count) == int(table.max_cell_count)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_a_node_pushed_between_two_spheres_is_stopped_by_the_sphere_behind(dtype):
    """Spheres A, B 2.8 R apart on the surface and C behind them; a node pushed between A and B into C.

    The search finds C (every sphere is a candidate, not a fixed boundary subset), which pushes the node
    back out with k_n δ, δ = R + t_m/2 − |x_node − x_C| (hand value); with A and B alone nothing touches
    it and the node would pass.
    """
    radius, gap_half = 0.0125, 0.0175  # A, B at y = ±1.4 R: beyond a node's reach R + t_m/2 + skin
    behind = -0.0125  # C's centre, one radius inside the surface line x = 0
    node = jnp.asarray([[0.0, 0.0, 0.0]], dtype)  # pushed to the line through A and B
    spheres = jnp.asarray([[0.0, -gap_half, 0.0], [0.0, gap_half, 0.0], [behind, 0.0, 0.0]], dtype)
    radii = jnp.full(3, radius, dtype)
    params = MembraneContactParams.default()
    expected = float(params.normal_stiffness) * (radius + 0.5 * THICKNESS - abs(behind))

    def force_with(subset):
        candidates = build_candidates(node, spheres[subset], radii[subset], THICKNESS, 0.001, capacity=2)
        return node_sphere_forces(
            ContactNodes(position=node, velocity=jnp.zeros_like(node)),
            ContactSpheres(
                position=spheres[subset],
                velocity=jnp.zeros_like(spheres[subset]),
                angular_velocity=jnp.zeros_like(spheres[subset]),
                radius=radii[subset],
            ),
            candidates.idx,
            jnp.zeros((3, 1, 2), dtype),
            1e-6,
            params,
            THICKNESS,
        ).node_force[0]

    np.testing.assert_allclose(
        np.asarray(force_with(jnp.asarray([0, 1, 2]))), [expected, 0.0, 0.0], rtol=tolerance(dtype)
    )
    np.testing.assert_array_equal(np.asarray(force_with(jnp.asarray([0, 1]))), 0.0)
