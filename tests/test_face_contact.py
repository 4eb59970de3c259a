"""Sphere–membrane contact on faces, edges and nodes (membrax.membrane.face_contact) against hand values,
the energy's gradient, finite differences and the conservation laws."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax.membrane import face_contact
from membrax.membrane.contact import (
    ContactNodes,
    ContactSpheres,
    MembraneContactParams,
    node_sphere_normal_energy,
)
from membrax.membrane.mesh import flat_mesh

RADIUS = 0.0125  # m, a 25 mm sphere
THICKNESS = 0.002  # m
REACH = RADIUS + 0.5 * THICKNESS
STIFFNESS = 1e5  # N/m
DEPTH = 1e-4  # m, the overlap δ the hand cases press to


def _sheet(dtype=jnp.float64):
    """A flat 60 × 60 mm sheet of 10 mm triangles in z = 0 (normal +z)."""
    return flat_mesh(0.06, 0.06, 0.01, dtype=dtype)


def _one_sphere_slots(mesh):
    """Every node lists sphere 0 as its one candidate."""
    return face_contact.feature_slots(mesh, jnp.zeros((mesh.num_nodes, 1), jnp.int32), 1)


def _interior_triangle(mesh):
    interior = np.asarray(face_contact.interior_nodes(mesh))
    triangles = np.asarray(mesh.triangles)
    middle = np.asarray(mesh.reference_position).mean(axis=0)
    candidates = [t for t in range(len(triangles)) if interior[triangles[t]].all()]
    centroids = np.asarray(mesh.reference_position)[triangles[candidates]].mean(axis=1)
    return candidates[int(np.argmin(np.linalg.norm(centroids - middle, axis=1)))]


def _forces(mesh, node_position, sphere_centre, node_velocity=None, sphere_velocity=None, springs=None):
    dtype = node_position.dtype
    slots = _one_sphere_slots(mesh)
    nodes = ContactNodes(
        position=node_position,
        velocity=jnp.zeros_like(node_position) if node_velocity is None else node_velocity,
    )
    spheres = ContactSpheres(
        position=sphere_centre[None],
        velocity=jnp.zeros((1, 3), dtype) if sphere_velocity is None else sphere_velocity,
        angular_velocity=jnp.zeros((1, 3), dtype),
        radius=jnp.full((1,), RADIUS, dtype),
    )
    springs = face_contact.zero_springs(slots, dtype) if springs is None else springs
    params = MembraneContactParams.default(normal_stiffness=STIFFNESS)
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)
    return (
        face_contact.face_contact_forces(
            nodes,
            spheres,
            mesh,
            slots,
            springs,
            jnp.asarray(1e-5, dtype),
            params,
            jnp.asarray(THICKNESS, dtype),
        ),
        slots,
    )


def _active(result):
    return {
        kind: int(jnp.sum(force > 0.0))
        for kind, force in zip(face_contact.FEATURE_KINDS, result.normal_force, strict=True)
    }


@pytest.mark.parametrize("feature", ["face", "edge", "node"])
def test_a_sphere_pressed_on_a_face_an_edge_or_a_node_gets_k_delta_once(feature, precision):
    """A sphere under a triangle's centroid, an edge's midpoint or a node, δ = 0.1 mm: one contact of that
    feature, k δ = 10 N on the sphere along −z, the nodes' shares by hand (⅓ each, ½ each, all) summing to
    its opposite. At the centroid no node is within reach (node contact misses the sphere)."""
    mesh = _sheet(precision)
    position = mesh.reference_position
    triangle = np.asarray(mesh.triangles)[_interior_triangle(mesh)]
    corners = np.asarray(position)[triangle]
    point, share = {
        "face": (corners.mean(axis=0), dict(zip(triangle, [1 / 3] * 3, strict=True))),
        "edge": (corners[:2].mean(axis=0), dict(zip(triangle[:2], [0.5, 0.5], strict=True))),
        "node": (corners[0], {triangle[0]: 1.0}),
    }[feature]
    centre = jnp.asarray(point - np.array([0.0, 0.0, REACH - DEPTH]), precision)
    result, _ = _forces(mesh, position, centre)
    expected = {kind: int(kind == feature) for kind in face_contact.FEATURE_KINDS}
    assert _active(result) == expected
    force = STIFFNESS * DEPTH
    rtol = 1e-9 if precision == jnp.float64 else 2e-3  # δ/reach = 7e-3: float32 keeps 4 digits of δ
    np.testing.assert_allclose(result.sphere_force[0], [0.0, 0.0, -force], rtol=rtol, atol=rtol * force)
    expected_nodes = np.zeros((mesh.num_nodes, 3))
    for node, weight in share.items():
        expected_nodes[node, 2] = weight * force
    np.testing.assert_allclose(result.node_force, expected_nodes, rtol=rtol, atol=rtol * force)
    np.testing.assert_allclose(jnp.sum(result.node_force, axis=0), -result.sphere_force[0], atol=1e-6 * force)
    if feature == "face":
        missed = node_sphere_normal_energy(
            position,
            centre[None],
            jnp.full((1,), RADIUS, precision),
            jnp.zeros((mesh.num_nodes, 1), jnp.int32),
            STIFFNESS,
            THICKNESS,
        )
        assert float(missed) == 0.0


def test_under_a_flat_sheet_every_point_has_exactly_one_contact():
    """A sphere slid under a flat sheet at a constant depth meets it once everywhere (no double count where
    regions meet, no gap): the energy is ½ k δ² at every point of a fine grid over the interior."""
    mesh = _sheet()
    slots = _one_sphere_slots(mesh)
    xs = np.linspace(0.02, 0.04, 41)
    grid = np.array([[x, y, -(REACH - DEPTH)] for x in xs for y in xs])

    def energy(centre):
        return face_contact.face_contact_energy(
            mesh.reference_position, centre[None], jnp.full((1,), RADIUS), mesh, slots, STIFFNESS, THICKNESS
        )

    energies = np.asarray(jax.vmap(energy)(jnp.asarray(grid)))
    np.testing.assert_allclose(energies, 0.5 * STIFFNESS * DEPTH**2, rtol=1e-9)


def _wrinkled(mesh, amplitude=0.003, seed=0):
    position = np.asarray(mesh.reference_position).copy()
    rng = np.random.default_rng(seed)
    position[:, 2] += amplitude * rng.standard_normal(len(position))
    return jnp.asarray(position)


def _under(position, x, y, depth=0.001):
    """A sphere centre under (x, y), pressed ``depth`` into the sheet at its nearest node's height."""
    nearest = int(np.argmin(np.sum((np.asarray(position)[:, :2] - np.array([x, y])) ** 2, axis=1)))
    return jnp.asarray([x, y, float(position[nearest, 2]) - REACH + depth])


def test_the_normal_forces_are_minus_the_gradient_of_the_energy_and_it_matches_differences():
    """On a wrinkled sheet (nodes moved ±3 mm out of plane) with the sphere at several places: the law's
    forces (no slip velocity, so no friction) equal −∂U/∂x of face_contact_energy for nodes and sphere, and
    ∂U/∂x matches central differences."""
    mesh = _sheet()
    position = _wrinkled(mesh)
    slots = _one_sphere_slots(mesh)
    radius = jnp.full((1,), RADIUS)

    def energy(node_position, sphere_position):
        return face_contact.face_contact_energy(
            node_position, sphere_position, radius, mesh, slots, STIFFNESS, THICKNESS
        )

    checked = 0
    for x, y in [(0.03, 0.03), (0.027, 0.034), (0.033, 0.026), (0.025, 0.031)]:
        centre = _under(position, x, y)
        result, _ = _forces(mesh, position, centre)
        if float(energy(position, centre[None])) == 0.0:
            continue
        checked += 1
        node_grad, sphere_grad = jax.grad(energy, argnums=(0, 1))(position, centre[None])
        scale_n = float(jnp.max(jnp.abs(result.node_force)))
        np.testing.assert_allclose(result.node_force, -node_grad, atol=1e-9 * scale_n)
        np.testing.assert_allclose(result.sphere_force, -sphere_grad, atol=1e-9 * scale_n)
        step = 1e-8
        for axis in range(3):
            shift = jnp.zeros((1, 3)).at[0, axis].set(step)
            difference = (energy(position, centre[None] + shift) - energy(position, centre[None] - shift)) / (
                2 * step
            )
            np.testing.assert_allclose(
                float(difference), float(sphere_grad[0, axis]), rtol=1e-5, atol=1e-6 * scale_n
            )
    assert checked >= 3


def test_momentum_and_angular_momentum_are_conserved_with_friction():
    """With slip (the sphere sliding and spinning under a wrinkled sheet, springs carried three steps):
    Σ F = 0 and Σ x × F + Σ τ = 0 over nodes and sphere, to round-off."""
    mesh = _sheet()
    position = _wrinkled(mesh, seed=1)
    centre = _under(position, 0.03, 0.03)
    velocity = jnp.asarray([[0.02, -0.01, 0.0]])
    springs = None
    for _ in range(3):
        result, _ = _forces(mesh, position, centre, sphere_velocity=velocity, springs=springs)
        springs = result.spring
    assert any(float(jnp.max(jnp.abs(s))) > 0.0 for s in result.spring)
    total = jnp.sum(result.node_force, axis=0) + result.sphere_force[0]
    moment = (
        jnp.sum(jnp.cross(position, result.node_force), axis=0)
        + jnp.cross(centre, result.sphere_force[0])
        + result.sphere_torque[0]
    )
    scale_f = float(jnp.max(jnp.abs(result.sphere_force)))
    np.testing.assert_allclose(total, 0.0, atol=1e-12 * scale_f)
    np.testing.assert_allclose(moment, 0.0, atol=1e-12 * scale_f * 0.06)


def test_the_law_jits_vmaps_and_differentiates_in_the_stiffness():
    """Under jit and vmap over k_n the sphere's force is k_n δ for each; ∂U/∂k_n = ½ δ² (U linear in k_n)."""
    mesh = _sheet()
    slots = _one_sphere_slots(mesh)
    triangle = np.asarray(mesh.triangles)[_interior_triangle(mesh)]
    centre = np.asarray(mesh.reference_position)[triangle].mean(axis=0) - np.array([0, 0, REACH - DEPTH])

    @jax.jit
    def energy(stiffness):
        return face_contact.face_contact_energy(
            mesh.reference_position,
            jnp.asarray(centre)[None],
            jnp.full((1,), RADIUS),
            mesh,
            slots,
            stiffness,
            THICKNESS,
        )

    stiffnesses = jnp.asarray([1e4, 1e5, 1e6])
    np.testing.assert_allclose(jax.vmap(energy)(stiffnesses), 0.5 * stiffnesses * DEPTH**2, rtol=1e-9)
    np.testing.assert_allclose(jax.grad(energy)(1e5), 0.5 * DEPTH**2, rtol=1e-9)


def test_feature_slots_hold_each_sphere_once_per_feature():
    """Candidate rows [0, 1] and [1, 2] on a triangle's nodes give the triangle spheres {0, 1, 2} once each;
    boundary nodes have no node slots."""
    mesh = _sheet()
    candidates = np.full((mesh.num_nodes, 2), 3, dtype=np.int32)
    triangle = np.asarray(mesh.triangles)[_interior_triangle(mesh)]
    candidates[triangle[0]] = [0, 1]
    candidates[triangle[1]] = [1, 2]
    slots = face_contact.feature_slots(mesh, jnp.asarray(candidates), 3)
    row = np.asarray(slots.face)[_interior_triangle(mesh)]
    assert sorted(row[row < 3].tolist()) == [0, 1, 2]
    interior = np.asarray(face_contact.interior_nodes(mesh))
    assert 0 < interior.sum() < mesh.num_nodes
    assert np.all(np.asarray(slots.node)[~interior] == 3)


def test_a_small_sphere_dropped_between_three_nodes_bounces_off_the_face():
    """A 6 mm sphere falls at 1 m/s onto a fixed flat sheet (10 mm triangles) at a triangle's centroid,
    5.8 mm from every node, so node contact (reach 4 mm) never touches it and it falls through; the face
    stops it: the linear spring's closed form gives the largest overlap δ_max = v₀ √(m/k_n) and an elastic
    rebound at v₀ (symplectic Euler, no damping; to 0.5 %)."""
    mesh = _sheet()
    radius, speed, dt = 0.003, 1.0, 5e-7
    mass = 2650.0 * 4.0 / 3.0 * np.pi * radius**3
    triangle = np.asarray(mesh.triangles)[_interior_triangle(mesh)]
    start = np.asarray(mesh.reference_position)[triangle].mean(axis=0) - np.array([0, 0, radius + 0.0015])
    slots = _one_sphere_slots(mesh)
    node_candidates = jnp.zeros((mesh.num_nodes, 1), jnp.int32)

    def run(law):
        def force(centre):
            if law == "faces":
                energy = face_contact.face_contact_energy(
                    mesh.reference_position,
                    centre[None],
                    jnp.full((1,), radius),
                    mesh,
                    slots,
                    STIFFNESS,
                    THICKNESS,
                )
            else:
                energy = node_sphere_normal_energy(
                    mesh.reference_position,
                    centre[None],
                    jnp.full((1,), radius),
                    node_candidates,
                    STIFFNESS,
                    THICKNESS,
                )
            return energy

        gradient = jax.grad(force)

        def step(carry, _):
            centre, velocity = carry
            velocity = velocity - dt * gradient(centre) / mass
            centre = centre + dt * velocity
            return (centre, velocity), centre[2]

        (centre, velocity), heights = jax.lax.scan(
            step, (jnp.asarray(start), jnp.asarray([0.0, 0.0, speed])), None, length=10000
        )
        return centre, velocity, np.asarray(heights)

    centre, velocity, _ = run("nodes")
    assert float(centre[2]) > 0.0 and float(velocity[2]) == speed  # through the sheet, untouched
    centre, velocity, heights = run("faces")
    np.testing.assert_allclose(float(velocity[2]), -speed, rtol=5e-3)
    deepest = heights.max() - (-(radius + 0.5 * THICKNESS))
    np.testing.assert_allclose(deepest, speed * np.sqrt(mass / STIFFNESS), rtol=5e-3)


def test_widening_keeps_every_spring_and_a_grown_table_carries_them_by_sphere_id():
    """``widen`` pads the slots of a K = 2 table to K = 4 (face 6 → 12, edge 4 → 8, node 2 → 4 columns):
    every existing slot keeps its sphere id and its spring (the friction state) exactly, the new slots are
    empty (id N) with zero springs. A grown table then lists the spheres in another order and one more:
    :func:`face_contact.carry_springs` moves each (feature, sphere) spring onto its new column exactly and
    gives the new sphere zero; the total spring of each kind is conserved. Narrowing is refused."""
    mesh = _sheet()
    num_spheres = 5
    rng = np.random.default_rng(3)
    old_table = np.tile(np.asarray([0, 1], np.int32), (mesh.num_nodes, 1))
    old_table[::3] = [2, num_spheres]  # some rows pad a slot
    slots = face_contact.feature_slots(mesh, jnp.asarray(old_table), num_spheres)
    springs = tuple(
        jnp.where(
            getattr(slots, kind) < num_spheres,
            jnp.asarray(rng.normal(size=(3, *getattr(slots, kind).shape))),
            0.0,
        )
        for kind in face_contact.FEATURE_KINDS
    )
    state = face_contact.FeatureContactState(slots=slots, spring=springs)
    wide = face_contact.widen(state, 4, num_spheres)
    for kind, spring, wide_spring in zip(face_contact.FEATURE_KINDS, springs, wide.spring, strict=True):
        ids, wide_ids = np.asarray(getattr(slots, kind)), np.asarray(getattr(wide.slots, kind))
        width = ids.shape[1]
        assert wide_ids.shape[1] == {"face": 12, "edge": 8, "node": 4}[kind]
        np.testing.assert_array_equal(wide_ids[:, :width], ids)
        np.testing.assert_array_equal(np.asarray(wide_spring)[:, :, :width], np.asarray(spring))
        assert np.all(wide_ids[:, width:] == num_spheres)
        assert np.all(np.asarray(wide_spring)[:, :, width:] == 0.0)
    # The grown table: the old spheres reversed, sphere 3 added.
    new_table = np.concatenate(
        [old_table[:, ::-1], np.full((mesh.num_nodes, 2), num_spheres, np.int32)], axis=1
    )
    new_table[:, 2] = 3
    new_slots = face_contact.feature_slots(mesh, jnp.asarray(new_table), num_spheres)
    carried = face_contact.carry_springs(wide, new_slots, num_spheres)
    for kind, spring, moved in zip(face_contact.FEATURE_KINDS, springs, carried, strict=True):
        ids, new_ids = np.asarray(getattr(slots, kind)), np.asarray(getattr(new_slots, kind))
        spring, moved = np.asarray(spring), np.asarray(moved)
        for row in range(ids.shape[0]):
            for column, sphere in enumerate(new_ids[row]):
                where = np.flatnonzero(ids[row] == sphere) if sphere < num_spheres else []
                expected = spring[:, row, where[0]] if len(where) else np.zeros(3)
                np.testing.assert_array_equal(moved[:, row, column], expected)
        np.testing.assert_allclose(moved.sum(axis=(1, 2)), spring.sum(axis=(1, 2)), rtol=1e-12)
    with pytest.raises(ValueError, match="wide"):
        face_contact.widen(wide, 2, num_spheres)


def test_members_of_two_thicknesses_share_one_node_table_and_lose_no_candidate():
    """Under face contact a node table's reach adds its mesh's longest edge, and the mesh sits at t_m/2 off
    the specimen, so the reach differs with t_m and members of 2.5 and 5 mm could not be stacked in one
    batch (the paper's Table 1 with faces failed so). The batch rebuilds both tables with the larger
    reach: one grid and reach, that reach the larger member's own longest edge, and (both tables rebuilt
    at capacities that hold every candidate, on their own grids) each member's own candidate pairs
    (node, sphere) all among its new ones."""
    from membrax.config import TriaxialConfig
    from membrax.executor import build_batch
    from membrax.membrane.candidates import CandidateCapacities
    from membrax.membrane.coupled import grow_candidates
    from membrax.membrane.face_contact import longest_edge

    configs = [
        TriaxialConfig(
            name=f"t{thickness}",
            particles_across=3,
            layers=4,
            membrane_contact_model="faces",
            membrane_thickness_mm=thickness,
            cell_pressure_kpa=40.0,
        )
        for thickness in (2.5, 5.0)
    ]
    batch = build_batch(configs, num_devices=1)
    stacked = batch.initial_state.membrane.candidates
    reaches = [float(longest_edge(test.mesh)) for test in batch.tests]
    assert reaches[0] != reaches[1]  # the members' own reaches differ
    assert {float(t.initial_state.membrane.candidates.extra_reach) for t in batch.tests} == set(reaches)
    assert stacked.extra_reach == max(reaches)
    particles = batch.tests[0].particles
    # Every sphere a node's candidate, every node a sphere's: tables that cannot overflow.
    num_nodes = batch.tests[0].mesh.num_nodes
    ample = CandidateCapacities(particles.num_particles, num_nodes, particles.num_particles)
    for test, member in zip(batch.tests, batch.unstack(batch.initial_state), strict=True):
        assert member.membrane.candidates.grid == stacked.grid
        thickness = test.params.membrane.contact_thickness
        own = grow_candidates(test.initial_state, particles, ample, thickness, test.mesh).membrane.candidates
        new = grow_candidates(member, particles, ample, thickness, test.mesh).membrane.candidates
        assert not bool(own.did_overflow) and not bool(new.did_overflow)

        def pairs(idx):
            return {
                (n, int(j))
                for n, row in enumerate(np.asarray(idx))
                for j in row
                if j < particles.num_particles
            }

        assert pairs(own.idx) <= pairs(new.idx) and len(pairs(own.idx)) > 0


def test_a_resumed_batch_cuts_its_node_rows_back_to_the_largest_count_plus_two():
    """``BatchedTest.fitted``: a batch whose tables were widened 6 beyond their need comes back at K =
    (largest count over the members) + 2, by hand from the tables, with each member's (node, sphere)
    candidates unchanged and its face slots 3 K wide; a batch already that narrow is returned as it is."""
    from membrax.config import TriaxialConfig
    from membrax.executor import build_batch
    from membrax.membrane.candidates import candidate_capacities

    configs = [
        TriaxialConfig(
            name=f"p{pressure}",
            particles_across=3,
            layers=4,
            membrane_contact_model="faces",
            cell_pressure_kpa=pressure,
        )
        for pressure in (10.0, 40.0)
    ]
    batch = build_batch(configs, num_devices=1)
    start = batch.initial_state
    needed = int(np.max(np.asarray(start.membrane.candidates.max_count))) + 2  # by hand from the tables
    capacities = candidate_capacities(start.membrane.candidates)._replace(capacity=needed + 6)
    wide = batch.restack(batch._with_capacities(batch.unstack(start), capacities))
    assert wide.membrane.candidates.capacity == needed + 6
    fitted = batch.fitted(wide)
    assert fitted.membrane.candidates.capacity == needed
    assert fitted.membrane.feature_contact.slots.face.shape[-1] == 3 * needed
    num_spheres = batch.tests[0].particles.num_particles
    tables = (np.asarray(wide.membrane.candidates.idx), np.asarray(fitted.membrane.candidates.idx))
    for before, after in zip(*tables, strict=True):
        for row_before, row_after in zip(before, after, strict=True):
            assert set(row_before[row_before < num_spheres]) == set(row_after[row_after < num_spheres])
    assert batch.fitted(fitted) is fitted
