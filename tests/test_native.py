"""Compiled CPU kernels (membrax.native) against the JAX laws they stand for.

Each kernel must give the numbers of its JAX definition to round-off (float64: 1e-12 of the largest
entry; the torques lose about three digits to the cancellation of arm × normal force, so 1e-10), keep
the conservation laws of the definition (momentum, angular momentum), and carry the definition's
derivatives through ``jax.grad``; ``vmap`` must equal a loop. Without a compiler, or with the kernels
switched off, everything falls back to the JAX code, with a warning when a build fails.
"""

import dataclasses
import math
import os
import shutil
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax import native
from membrax.defaults import LATEX_POISSON_RATIO
from membrax.membrane import energies
from membrax.membrane.contact import (
    ContactNodes,
    ContactSpheres,
    MembraneContactParams,
    _reference_node_sphere_forces,
    node_sphere_forces,
)
from membrax.membrane.mesh import cylinder_mesh, free_node_mask

pytestmark = pytest.mark.skipif(
    not (os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")),
    reason="no C++ compiler: the JAX code runs instead (tested everywhere else)",
)


def _relative_error(result, reference):
    result, reference = np.asarray(result), np.asarray(reference)
    return np.max(np.abs(result - reference)) / max(np.max(np.abs(reference)), 1e-300)


def test_kernels_build_and_register():
    """With a compiler at hand the kernels must build: a silent fallback would hide a broken kernel."""
    assert native.available()
    assert native.build().exists()


def _deformed_cylinder(seed=0, dtype=jnp.float64, edge=0.02):
    mesh = cylinder_mesh(0.1, 0.2, edge)
    rng = np.random.default_rng(seed)
    position = mesh.reference_position * jnp.asarray([1.03, 1.03, 0.98])[None, :] + jnp.asarray(
        rng.normal(0.0, 1e-3, mesh.reference_position.shape)
    )
    if dtype == jnp.float32:
        mesh = jax.tree.map(lambda a: a.astype(jnp.float32) if a.dtype == jnp.float64 else a, mesh)
        position = position.astype(jnp.float32)
    return mesh, position


#: J_m of the Gent cases: the deformed cylinder's triangles have I₁ − 3 of 0.035 (median) to 0.3–0.5, so
#: s = (I₁ − 3)/J_m is 0.24 in the median and the top few per cent pass the lock fraction (the continuation).
_LOCKING_JM = 0.15


@pytest.mark.parametrize("model", ["neo_hookean", "svk", "gent"])
@pytest.mark.parametrize("bending_factor", [0.0, 1.0])
def test_membrane_forces_kernel_matches_jax(model, bending_factor):
    mesh, position = _deformed_cylinder()
    args = (position, mesh, 1.4e6, 0.005, 1e4, 0.45, bending_factor, model, _LOCKING_JM)
    compiled = jax.jit(energies.nodal_forces, static_argnums=(6,))(
        position, mesh, 1.4e6, 0.005, 1e4, 0.45, model, bending_factor, _LOCKING_JM
    )
    reference = energies.reference_nodal_forces(*args)
    assert _relative_error(compiled, reference) < 1e-12
    # Band and caps close the surface, so every energy is invariant under translation: Σ F = 0.
    assert np.max(np.abs(np.sum(compiled, axis=0))) < 1e-12 * compiled.shape[0] * np.max(np.abs(compiled))


def test_membrane_forces_kernel_float32_as_accurate_as_jax():
    """In float32 the kernel and XLA make errors of the same size against the float64 forces."""
    mesh64, position64 = _deformed_cylinder()
    mesh32, position32 = _deformed_cylinder(dtype=jnp.float32)
    exact = energies.reference_nodal_forces(position64, mesh64, 1.4e6, 0.005, 1e4, 0.5, 1.0, "neo_hookean")

    def call(fn):
        return fn(position32, mesh32, jnp.float32(1.4e6), jnp.float32(0.005), jnp.float32(1e4), 0.5)

    compiled = call(lambda *a: energies.nodal_forces(*a, bending_factor=jnp.float32(1.0)))
    reference = call(lambda *a: energies.reference_nodal_forces(*a, jnp.float32(1.0), "neo_hookean"))
    assert compiled.dtype == jnp.float32
    error_kernel = _relative_error(compiled.astype(jnp.float64), exact)
    error_jax = _relative_error(reference.astype(jnp.float64), exact)
    assert error_kernel < 1e-4
    assert error_kernel < 3.0 * error_jax


@pytest.mark.slow
def test_membrane_forces_kernel_gradients_and_vmap():
    mesh, position = _deformed_cylinder(seed=1)
    direction = jnp.asarray(np.random.default_rng(2).normal(size=position.shape))

    def work(fn, x, modulus, pressure):
        return jnp.sum(direction * fn(x, mesh, modulus, 0.004, pressure, 0.5, 0.7, "neo_hookean"))

    def compiled(x, mesh, modulus, thickness, pressure, nu, bending, model):
        return energies.nodal_forces(x, mesh, modulus, thickness, pressure, nu, model, bending)

    for wrt in (0, 1, 2):
        got = jax.grad(work, argnums=1 + wrt)(compiled, position, 1.4e6, 2e4)
        want = jax.grad(work, argnums=1 + wrt)(energies.reference_nodal_forces, position, 1.4e6, 2e4)
        assert _relative_error(got, want) < 1e-12
    # The Hessian–vector product −∂F/∂x·v against a central difference of the kernel's forces.
    step = 1e-7
    hvp = jax.grad(work, argnums=1)(compiled, position, 1.4e6, 2e4)
    plus = compiled(position + step * direction, mesh, 1.4e6, 0.004, 2e4, 0.5, 0.7, "neo_hookean")
    minus = compiled(position - step * direction, mesh, 1.4e6, 0.004, 2e4, 0.5, 0.7, "neo_hookean")
    central = jnp.sum(direction * (plus - minus)) / (2 * step)
    assert float(jnp.sum(hvp * direction)) == pytest.approx(float(central), rel=1e-6)

    pressures = jnp.asarray([1e4, 5e4, 1e5])
    batched = jax.vmap(lambda p: compiled(position, mesh, 1.4e6, 0.004, p, 0.5, 0.0, "svk"))(pressures)
    for k, pressure in enumerate(pressures):
        single = energies.reference_nodal_forces(position, mesh, 1.4e6, 0.004, pressure, 0.5, 0.0, "svk")
        assert _relative_error(batched[k], single) < 1e-12


def _node_sphere_case(seed=3, num_nodes=400, num_spheres=12, capacity=4):
    """Nodes on and around spheres, with carried springs: sticking, sliding and open slots, padding."""
    rng = np.random.default_rng(seed)
    sphere_position = rng.uniform(-0.05, 0.05, (num_spheres, 3))
    radius = rng.uniform(0.008, 0.012, num_spheres)
    owner = rng.integers(0, num_spheres, num_nodes)
    direction = rng.normal(size=(num_nodes, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    # Distances from R − 1 mm (touching, t_m/2 = 2.5 mm) to R + 4 mm (open).
    distance = radius[owner] + rng.uniform(-0.001, 0.004, num_nodes)
    node_position = sphere_position[owner] + distance[:, None] * direction
    node_position[0] = sphere_position[owner[0]]  # a node at a sphere centre: zero normal
    candidates = np.full((num_nodes, capacity), num_spheres, dtype=np.int32)
    candidates[:, 0] = owner
    candidates[:, 1] = (owner + 1) % num_spheres
    candidates[::3, 2] = (owner[::3] + 2) % num_spheres
    spring = rng.normal(0.0, 60.0, (3, num_nodes, capacity))  # N: some slots stick, some slide
    return dict(
        nodes=ContactNodes(
            position=jnp.asarray(node_position),
            velocity=jnp.asarray(rng.normal(0.0, 0.1, (num_nodes, 3))),
        ),
        spheres=ContactSpheres(
            position=jnp.asarray(sphere_position),
            velocity=jnp.asarray(rng.normal(0.0, 0.1, (num_spheres, 3))),
            angular_velocity=jnp.asarray(rng.normal(0.0, 10.0, (num_spheres, 3))),
            radius=jnp.asarray(radius),
        ),
        candidates=jnp.asarray(candidates),
        spring=jnp.asarray(spring),
        dt=1e-5,
        params=MembraneContactParams.default(),
        membrane_thickness=0.005,
    )


def test_node_sphere_kernel_matches_jax_and_conserves_momentum():
    case = _node_sphere_case()
    compiled = jax.jit(node_sphere_forces)(**case)
    reference = _reference_node_sphere_forces(**case)
    touching = reference.overlap > 0.0
    limit = math.tan(math.radians(25.0)) * reference.normal_force
    sliding = touching & (jnp.linalg.norm(reference.spring, axis=0) >= 0.999 * limit)
    touching, sliding = int(jnp.sum(touching)), int(jnp.sum(sliding))
    assert touching > 100 and sliding > 10  # both regimes of the law are exercised
    for field in reference._fields:
        tolerance = 1e-10 if field == "sphere_torque" else 1e-12
        assert _relative_error(getattr(compiled, field), getattr(reference, field)) < tolerance, field
    # Newton's third law and angular momentum about the origin (torques about the sphere centres).
    assert np.allclose(np.sum(compiled.node_force, 0), -np.sum(compiled.sphere_force, 0), atol=1e-12)
    moment = (
        np.sum(np.cross(case["nodes"].position, compiled.node_force), 0)
        + np.sum(np.cross(case["spheres"].position, compiled.sphere_force), 0)
        + np.sum(compiled.sphere_torque, 0)
    )
    assert np.max(np.abs(moment)) < 1e-12 * float(np.max(np.abs(compiled.node_force)))


def test_node_sphere_kernel_gradients_and_vmap():
    case = _node_sphere_case(seed=4, num_nodes=60)
    weights = jnp.asarray(np.random.default_rng(5).normal(size=(60, 3)))

    def work(fn, node_position, thickness):
        nodes = case["nodes"].set(position=node_position)
        result = fn(**{**case, "nodes": nodes, "membrane_thickness": thickness})
        return jnp.sum(weights * result.node_force) + jnp.sum(result.spring**2)

    for argnum in (1, 2):
        got = jax.grad(work, argnums=argnum)(node_sphere_forces, case["nodes"].position, 0.005)
        want = jax.grad(work, argnums=argnum)(_reference_node_sphere_forces, case["nodes"].position, 0.005)
        assert _relative_error(got, want) < 1e-12
    thicknesses = jnp.asarray([0.003, 0.005])
    batched = jax.vmap(lambda t: node_sphere_forces(**{**case, "membrane_thickness": t}).node_force)(
        thicknesses
    )
    for k, thickness in enumerate(thicknesses):
        single = _reference_node_sphere_forces(**{**case, "membrane_thickness": thickness}).node_force
        assert _relative_error(batched[k], single) < 1e-12


def test_forward_kernels_run_asynchronously_with_the_same_bits_and_report_bad_sizes():
    """The forward kernels of the membrane forces, the node–sphere law and the sphere pairs run on XLA's
    thread pool from 8,192 elements on, so that XLA goes on with independent work meanwhile (parallel.h,
    ``on_pool``). Two independent node–sphere calls over 8,400 slots in one program, which XLA may run side
    by side, give the JAX law's numbers and, to the bit, those of each call alone (a task that shared
    scratch or read a finished call's arguments would show here); a call with inconsistent sizes fails with
    the kernel's message (the future's error path)."""
    case = _node_sphere_case(num_nodes=2100)
    other = _node_sphere_case(seed=8, num_nodes=2100)
    assert case["candidates"].size >= 8192  # kMinAsyncElements: handed to the pool

    def both(first, second):
        return node_sphere_forces(**first), node_sphere_forces(**second)

    together = jax.jit(both)(case, other)
    alone = (jax.jit(node_sphere_forces)(**case), jax.jit(node_sphere_forces)(**other))
    for inputs, single, paired in zip((case, other), alone, together, strict=True):
        reference = _reference_node_sphere_forces(**inputs)
        for field in single._fields:
            assert np.array_equal(np.asarray(getattr(single, field)), np.asarray(getattr(paired, field))), (
                field
            )
            tolerance = 1e-10 if field == "sphere_torque" else 1e-12
            assert _relative_error(getattr(paired, field), getattr(reference, field)) < tolerance, field

    f64, n, num_spheres, capacity, slots = jnp.float64, 8, 4, 3, 6

    def zeros(*shape, dtype=f64):
        return jnp.zeros(shape, dtype)

    def struct(*shape):
        return jax.ShapeDtypeStruct(shape, f64)

    calls = {  # each with one wrong size: 4 scalars for 5, and a (2, C − 1) neighbour list for (2, C)
        "node_sphere_forces": (
            (struct(n, 3), struct(num_spheres, 3), struct(num_spheres, 3), struct(3, n, capacity)),
            (
                zeros(n, 3),
                zeros(n, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres),
                zeros(n, capacity, dtype=jnp.int32),
                zeros(3, n, capacity),
                zeros(4),
            ),
            {},
        ),
        "membrane_forces": (
            struct(n, 3),
            (
                zeros(n, 3),
                zeros(3, dtype=jnp.int32),
                zeros(1, 2, 2),
                zeros(1),
                zeros(0, dtype=jnp.int32),
                zeros(0),
                zeros(0),
                zeros(2, dtype=jnp.int32),
                zeros(2, dtype=jnp.int32),
                zeros(4),
            ),
            {"model": np.int64(0)},
        ),
        "dem_pairs": (
            (struct(num_spheres, 6), struct(slots, 3), struct(slots, 3)),
            (
                zeros(num_spheres, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres, 3),
                zeros(num_spheres),
                zeros(2, slots - 1, dtype=jnp.int32),
                zeros(slots, 3),
                zeros(slots),
                zeros(slots),
                zeros(slots),
                zeros(1),
            ),
            {},
        ),
    }
    for name, (results, args, attributes) in calls.items():
        with pytest.raises(Exception, match=f"{name}: "):
            jax.block_until_ready(native.call(name, f64, results, *args, **attributes))


def test_failed_build_warns_and_falls_back_to_jax(tmp_path):
    """A compiler that fails: one warning, no kernels, and the JAX numbers."""
    script = textwrap.dedent(
        """
        import warnings
        import jax
        jax.config.update("jax_enable_x64", True)
        from membrax import native
        from membrax.membrane import energies
        from membrax.membrane.mesh import cylinder_mesh, free_node_mask
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ok = native.available()
        mesh = cylinder_mesh(0.1, 0.1, 0.03)
        x = mesh.reference_position * 1.01
        same = bool((energies.nodal_forces(x, mesh, 1e6, 0.003, 1e4)
                     == energies.reference_nodal_forces(x, mesh, 1e6, 0.003, 1e4, 0.5, 1.0,
                                                         "neo_hookean")).all())
        ours = [str(w.message) for w in caught if "membrax" in str(w.message)]
        print(ok, len(ours), "compiling the membrax kernels failed" in ours[0], same)
        """
    )
    environment = {**os.environ, "CXX": "false", "MEMBRAX_CACHE_DIR": str(tmp_path)}
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=environment, check=True
    )
    assert result.stdout.split() == ["False", "1", "True", "True"]


def _dem_case(seed=9, num_spheres=150, num_slots=900):
    """Spheres in a box, a neighbour list with padding (i = N), springs and stiffnesses varying by slot:
    ``_pair_totals_*``' arguments (spheres, idx, springs, law, Δt)."""
    from membrax.spheres.contact import ContactParams, PairSpheres

    rng = np.random.default_rng(seed)
    position = rng.uniform(0.0, 0.08, (num_spheres, 3))
    position[1] = position[0]  # two spheres at one centre: a zero normal, which the law guards
    compensation = rng.normal(0.0, 1e-9, (num_spheres, 3))
    radius = rng.uniform(0.009, 0.011, num_spheres)
    distance = np.linalg.norm(position[:, None] - position[None], axis=2)
    i, j = np.nonzero(np.triu(distance < 0.025, 1))
    count = min(len(i), num_slots - 50)
    idx = np.full((2, num_slots), num_spheres, dtype=np.int32)
    idx[0, :count], idx[1, :count] = i[:count], j[:count]
    spheres = PairSpheres(
        position=jnp.asarray(position),
        position_compensation=jnp.asarray(compensation),
        velocity=jnp.asarray(rng.normal(0.0, 0.1, (num_spheres, 3))),
        angular_velocity=jnp.asarray(rng.normal(0.0, 5.0, (num_spheres, 3))),
        radius=jnp.asarray(radius),
        member=jnp.arange(num_spheres, dtype=jnp.int32),  # one member per sphere: k_n varies by slot
    )
    law = ContactParams(
        normal_stiffness=jnp.asarray(rng.uniform(0.5e7, 1.5e7, num_spheres)),
        tangential_stiffness=jnp.asarray(5e6),
        friction_coefficient=jnp.asarray(math.tan(math.radians(25.0))),
        wall_normal_stiffness=jnp.asarray(1e7),  # the walls' fields are not the pairs' business
        wall_tangential_stiffness=jnp.asarray(5e6),
        wall_friction_coefficient=jnp.asarray(0.0),
    )
    return spheres, jnp.asarray(idx), jnp.asarray(rng.normal(0.0, 20.0, (num_slots, 3))), law, 1e-6


def test_dem_pair_kernel_matches_jax_and_conserves_momentum():
    from membrax.spheres import integrate

    args = _dem_case()
    compiled = jax.jit(integrate._compiled_pair_totals)(*args)
    reference = integrate._pair_totals_reference(*args)
    for got, want in zip(compiled[1:], reference[1:], strict=True):  # springs, forces per slot
        assert _relative_error(got, want) < 1e-12
    assert _relative_error(compiled[0][:, :3], reference[0][:, :3]) < 1e-12
    assert _relative_error(compiled[0][:, 3:], reference[0][:, 3:]) < 1e-10
    touching = int(jnp.sum(jnp.linalg.norm(reference[2], axis=1) > 0.0))
    assert touching > 100
    # Newton's third law and angular momentum: Σ F = 0 and Σ (x × F + T) = 0 over the spheres.
    position = np.asarray(args[0].position + args[0].position_compensation)
    force, torque = np.asarray(compiled[0][:, :3]), np.asarray(compiled[0][:, 3:])
    scale = np.max(np.abs(force))
    assert np.max(np.abs(np.sum(force, 0))) < 1e-11 * scale
    assert np.max(np.abs(np.sum(np.cross(position, force) + torque, 0))) < 1e-11 * scale * 0.1
    # Derivatives are the reference's.
    weights = jnp.asarray(np.random.default_rng(10).normal(size=(150, 6)))

    def work(fn, position):
        return jnp.sum(weights * fn(args[0].set(position=position), *args[1:])[0])

    got = jax.grad(work, argnums=1)(integrate._compiled_pair_totals, args[0].position)
    want = jax.grad(work, argnums=1)(integrate._pair_totals_reference, args[0].position)
    assert _relative_error(got, want) < 1e-12
    frictions = jnp.asarray([0.2, 0.5])

    def with_friction(mu):
        spheres, idx, spring, law, dt = args
        return spheres, idx, spring, law.set(friction_coefficient=mu), dt

    batched = jax.vmap(lambda mu: integrate._compiled_pair_totals(*with_friction(mu))[1])(frictions)
    for k, mu in enumerate(frictions):
        single = integrate._pair_totals_reference(*with_friction(mu))[1]
        assert _relative_error(batched[k], single) < 1e-12


def _node_update_case():
    """advance_nodes' arguments: two forces, 500 nodes (the first 40 clamped, some at rest, some moving at
    their reference velocity, the damping's affine field), Δt, damping."""
    from membrax.membrane import node_update
    from membrax.spheres import integrate

    rng = np.random.default_rng(11)
    n = 500
    free = np.ones(n, dtype=bool)
    free[:40] = False  # clamped ring nodes
    membrane_force = jnp.asarray(rng.normal(0.0, 1.0, (n, 3)))
    contact_force = jnp.asarray(rng.normal(0.0, 0.5, (n, 3)))
    velocity = rng.normal(0.0, 0.01, (n, 3)) * (rng.random((n, 3)) > 0.1)  # some v = 0
    reference = np.where(rng.random((n, 3)) > 0.1, rng.normal(0.0, 0.01, (n, 3)), velocity)  # some u = 0
    nodes = node_update.MembraneNodes(
        position=jnp.asarray(rng.uniform(-0.2, 0.2, (n, 3))),
        position_compensation=jnp.asarray(rng.normal(0.0, 1e-18, (n, 3))),
        velocity=jnp.asarray(velocity),
        mass=jnp.asarray(rng.uniform(5e-5, 1.5e-4, n)),
        free=jnp.asarray(free),
        reference_velocity=jnp.asarray(reference),
    )
    damping = integrate.DampingParams(local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(5.0))
    return membrane_force, contact_force, nodes, 2e-6, damping


def test_node_update_kernel_matches_jax_and_keeps_the_compensated_sum():
    from membrax.membrane import node_update

    args = _node_update_case()
    compiled = jax.jit(node_update._compiled_advance_nodes)(*args)
    reference = node_update._advance_nodes_reference(*args)
    for got, want in zip(compiled[:3], reference[:3], strict=True):  # force, velocity, position
        assert _relative_error(got, want) < 1e-14
    assert np.all(np.asarray(compiled[1])[:40] == 0.0)
    # Fast2Sum: (x' − x) + (c' − c) is the increment Δt v' to the last bits (x' − x is exact).
    nodes = args[2]
    step = (compiled[2] - nodes.position) + (compiled[3] - nodes.position_compensation)
    assert _relative_error(step, 2e-6 * compiled[1]) < 1e-12


# Sizes above parallel.h's kMinParallelElements (4,096), so that the backward kernels split their loops.
_LARGE = {
    "edge": 0.005,
    "node_sphere": dict(num_nodes=9000, num_spheres=60),
    "dem": dict(num_spheres=1500, num_slots=9000),
}


def _cotangent_cases(large=False):
    """(FFI target, compiled, reference, positional args) of each kernel with a compiled reverse-mode rule;
    ``large``: sizes at which the membrane, node–sphere and pair kernels run in two halves (parallel.h)."""
    from membrax.membrane import contact, node_update
    from membrax.spheres import integrate

    mesh, position = _deformed_cylinder(seed=1, edge=_LARGE["edge"] if large else 0.02)
    forces = {
        model: (
            "membrane_forces_backward",
            lambda x, *scalars, model=model: energies._COMPILED_NODAL_FORCES[model](x, mesh, *scalars),
            lambda x, *scalars, model=model: energies.reference_nodal_forces(
                x, mesh, *scalars[:5], model, scalars[5]
            ),
            (position, 1.4e6, 0.004, 2e4, 0.45, 0.7, _LOCKING_JM),  # x, E_m, t_m, p, ν, f_b, J_m
        )
        for model in ("neo_hookean", "svk", "gent")
    }
    node_sphere = _node_sphere_case(**(_LARGE["node_sphere"] if large else {}))
    return [
        forces["neo_hookean"],
        forces["svk"],
        (
            "node_sphere_backward",
            contact._compiled_node_sphere_forces,
            contact.node_sphere_reference,
            tuple(node_sphere.values()),
        ),
        (
            "membrane_nodes_backward",
            node_update._compiled_advance_nodes,
            node_update._advance_nodes_reference,
            _node_update_case(),
        ),
        (
            "dem_pairs_backward",
            integrate._compiled_pair_totals,
            integrate._pair_totals_reference,
            _dem_case(**(_LARGE["dem"] if large else {})),
        ),
        forces["gent"],
    ]


@pytest.mark.parametrize("case", range(6))
def test_compiled_backward_kernels_give_the_reference_cotangents(case):
    """Each compiled reverse-mode rule (``with_reference``'s ``backward``) against ``jax.vjp`` of the JAX
    definition, for every argument at once (positions, velocities, springs, radii, material scalars, time
    step): equal to round-off (float64, 1e-12 of the largest entry), and really the compiled rule (its FFI
    target is in the program: a silent fallback to the reference would pass the comparison)."""
    target, compiled, reference, values = _cotangent_cases()[case]
    pullback = _check_cotangents(target, compiled, reference, values, seed=case)
    assert f"membrax_{target}_f64" in pullback.lower(*values).as_text()


def _check_cotangents(target, compiled, reference, values, seed):
    """Asserts the compiled pullback of random cotangents equals ``jax.vjp`` of the reference (float64,
    1e-12 of the largest entry) for at least six arguments; returns the jitted compiled pullback."""
    outputs = compiled(*values)
    rng = np.random.default_rng(seed)
    cotangents = jax.tree.map(lambda out: jnp.asarray(rng.normal(size=out.shape)), outputs)
    pullback = jax.jit(lambda *v: jax.vjp(compiled, *v)[1](cotangents))
    want = jax.vjp(reference, *values)[1](cotangents)
    checked = 0
    for g, w in zip(jax.tree.leaves(pullback(*values)), jax.tree.leaves(want), strict=True):
        if jnp.dtype(w.dtype) == jax.dtypes.float0:
            continue
        assert _relative_error(g, w) < 1e-12, (target, checked)
        checked += 1
    assert checked >= 6
    return pullback


@pytest.mark.parametrize("case", [0, 2, 4, 5])  # membrane forces, node–sphere, pairs, Gent forces
def test_backward_kernels_in_two_halves_give_the_reference_cotangents_and_the_same_bits_every_call(case):
    """Above 4,096 elements (parallel.h) the membrane, node–sphere and pair backward kernels run their
    element loops in two halves, the second offered to XLA's thread pool. Against ``jax.vjp`` of the JAX
    definition as above (float64, 1e-12 of the largest entry), and identical to the bit over repeated calls:
    each half covers fixed elements and sums them in order, so which thread ran it must not show."""
    target, compiled, reference, values = _cotangent_cases(large=True)[case]
    # Loops split: over triangles (more than the nodes), over nodes (and touching slots), over pair slots.
    first = values[2] if case == 4 else values[0]  # the springs (C, 3); the positions (n, 3) or nodes
    split = (first.position if case == 2 else first).shape[0]
    assert split >= 4096  # kMinParallelElements
    pullback = _check_cotangents(target, compiled, reference, values, seed=case)
    got = pullback(*values)
    for _ in range(4):
        again = pullback(*values)
        for g, a in zip(jax.tree.leaves(got), jax.tree.leaves(again), strict=True):
            assert np.array_equal(np.asarray(g), np.asarray(a)), target
    assert f"membrax_{target}_f64" in pullback.lower(*values).as_text()


def test_membrane_backward_at_zero_bending_skips_the_hinges_only_when_their_derivative_is_not_wanted():
    """At f_b = 0 (the paper's pure membrane) the hinges add nothing to the forces, so the backward kernel
    skips them unless ∂/∂f_b is asked for. Both ways against ``jax.vjp`` of the JAX definition: with f_b
    differentiated, ū·∂F/∂f_b = ū·F_bend(f_b = 1) (the forces are linear in f_b) is not zero and matches;
    with f_b a constant, the positions' and E_m's cotangents still match."""
    mesh, position = _deformed_cylinder(seed=4)
    compiled = energies._COMPILED_NODAL_FORCES["neo_hookean"]

    def reference(x, *scalars):
        return energies.reference_nodal_forces(x, mesh, *scalars, "neo_hookean")

    scalars = (1.4e6, 0.004, 2e4, 0.45, 0.0)
    cotangent = jnp.asarray(np.random.default_rng(5).normal(size=position.shape))
    got = jax.vjp(lambda x, *s: compiled(x, mesh, *s), position, *scalars)[1](cotangent)
    want = jax.vjp(reference, position, *scalars)[1](cotangent)
    for g, w in zip(got, want, strict=True):
        assert _relative_error(g, w) < 1e-12
    bending = reference(position, *scalars[:4], 1.0) - reference(position, *scalars[:4], 0.0)
    assert float(got[5]) == pytest.approx(float(jnp.sum(cotangent * bending)), rel=1e-9)
    assert abs(float(got[5])) > 0.0

    def work(fn, x, modulus):
        return jnp.sum(cotangent * fn(x, modulus))

    constant_bending = jax.grad(
        lambda x, e: work(lambda y, m: compiled(y, mesh, m, *scalars[1:]), x, e), argnums=(0, 1)
    )(position, scalars[0])
    reference_grad = jax.grad(
        lambda x, e: work(lambda y, m: reference(y, m, *scalars[1:]), x, e), argnums=(0, 1)
    )(position, scalars[0])
    for g, w in zip(constant_bending, reference_grad, strict=True):
        assert _relative_error(g, w) < 1e-12


def test_membrane_forces_differentiated_in_the_rest_geometry_use_the_reference_rule():
    """The membrane backward kernel covers the positions and the scalars; a derivative in the rest mesh
    (here the rest areas, which scale each triangle's stretching force linearly) falls back to the JAX
    definition's. Checked against that and against the hand calculation: with F_stretch ∝ A₀ per triangle,
    Σ_t A₀ ∂(ū·F)/∂A₀ = ū·F_stretch, the stretching part alone (pressure and bending off)."""
    mesh, position = _deformed_cylinder(seed=2)
    direction = jnp.asarray(np.random.default_rng(3).normal(size=position.shape))
    forces = energies._COMPILED_NODAL_FORCES["svk"]

    def work(fn, area):
        deformed = dataclasses.replace(mesh, reference_area=area)
        return jnp.sum(direction * fn(position, deformed, 1.4e6, 0.004, 0.0, 0.45, 0.0))

    def reference(x, m, *scalars):
        return energies.reference_nodal_forces(x, m, *scalars, "svk")

    area = mesh.reference_area
    got = jax.grad(lambda a: work(forces, a))(area)
    want = jax.grad(lambda a: work(reference, a))(area)
    assert _relative_error(got, want) < 1e-12
    assert float(jnp.sum(area * got)) == pytest.approx(float(work(forces, area)), rel=1e-12)


def _node_step_case(seed=5, num_spheres=30, capacity=3):
    """node_step's arguments on a deformed cylinder: spheres just inside it, some nodes pressed into them
    (t_m/2 = 2 mm, overlaps from −1 to 2 mm), carried springs, padded candidate slots, clamped rings."""
    from membrax.membrane import coupled, node_update
    from membrax.spheres import integrate

    mesh, position = _deformed_cylinder(seed=seed)
    position = np.asarray(position)
    rng = np.random.default_rng(seed)
    num_nodes = position.shape[0]
    pick = rng.choice(num_nodes, num_spheres, replace=False)
    radius = rng.uniform(0.008, 0.012, num_spheres)
    inward = position[pick] * np.array([1.0, 1.0, 0.0])
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    thickness = 0.004
    reach = radius + thickness / 2 - rng.uniform(-0.001, 0.002, num_spheres)
    centre = position[pick] - inward * reach[:, None]
    gap = np.linalg.norm(position[:, None, :] - centre[None], axis=2) - radius[None]
    candidates = np.argsort(gap, axis=1)[:, :capacity].astype(np.int32)
    candidates[::5, -1] = num_spheres  # padding
    node_velocity = jnp.asarray(rng.normal(0.0, 0.05, (num_nodes, 3)))
    spheres = ContactSpheres(
        position=jnp.asarray(centre),
        velocity=jnp.asarray(rng.normal(0.0, 0.05, (num_spheres, 3))),
        angular_velocity=jnp.asarray(rng.normal(0.0, 5.0, (num_spheres, 3))),
        radius=jnp.asarray(radius),
    )
    spring = jnp.asarray(rng.normal(0.0, 20.0, (3, num_nodes, capacity)))
    nodes = node_update.MembraneNodes(
        position=jnp.asarray(position),
        position_compensation=jnp.asarray(rng.normal(0.0, 1e-18, (num_nodes, 3))),
        velocity=node_velocity,
        mass=jnp.asarray(rng.uniform(5e-4, 1.5e-3, num_nodes)),
        free=jnp.asarray(free_node_mask(mesh)),
        reference_velocity=jnp.asarray(rng.normal(0.0, 0.05, (num_nodes, 3))),  # the damping's affine field
    )
    params = coupled.MembraneParams(
        modulus=jnp.asarray(1.4e6),
        thickness=jnp.asarray(thickness),
        cell_pressure=jnp.asarray(2e4),
        contact=MembraneContactParams.default(),
        bending_factor=jnp.asarray(0.7),
        contact_offset_factor=jnp.asarray(1.0),  # the contact's thickness is t_m
        locking_jm=jnp.asarray(_LOCKING_JM),
    )
    damping = integrate.DampingParams(local_coefficient=jnp.asarray(0.3), viscous_rate=jnp.asarray(5.0))
    args = (nodes, spheres, jnp.asarray(candidates), spring, 1e-5, params, damping, mesh)
    return node_update, args


@pytest.mark.parametrize("model", ["neo_hookean", "svk", "gent"])
def test_node_step_chains_the_three_backward_kernels_with_their_cotangents_and_their_forward_bits(model):
    """``node_update.node_step`` runs the node–sphere law, the membrane forces and the node update as one
    reverse-mode rule whose three backward kernels add their shares of the nodes' cotangents in place.
    Its forward must be the three compiled functions' to the bit (the same kernels), its cotangents those
    of ``jax.vjp`` of the three JAX definitions composed, for every argument at once (float64, 1e-12 of the
    largest entry), and all three backward kernels must be in the program."""
    from membrax.membrane import contact

    node_update, args = _node_step_case()
    *values, mesh = args

    def without_mesh(function):  # the rest geometry is not differentiated here (see the next test)
        return lambda *a: function(*a, mesh, model=model)

    got = jax.jit(without_mesh(node_update.node_step))(*values)
    nodes, spheres, candidates, spring, dt, params, damping = values
    contact_outputs = jax.jit(contact.node_sphere_forces)(
        nodes.for_contact(), spheres, candidates, spring, dt, params.contact, params.contact_thickness
    )[:4]
    material = (params.modulus, params.thickness, params.cell_pressure, LATEX_POISSON_RATIO)
    internal = jax.jit(energies.nodal_forces, static_argnums=6)(
        nodes.position, mesh, *material, model, params.bending_factor, params.locking_jm
    )
    update = jax.jit(node_update.advance_nodes)(internal, contact_outputs[0], nodes, dt, damping)
    for g, w in zip(got, (*contact_outputs, *update), strict=True):
        assert np.array_equal(np.asarray(g), np.asarray(w))
    pullback = _check_cotangents(
        "node_step",
        without_mesh(node_update.node_step),
        without_mesh(node_update._node_step_reference),
        values,
        seed=7,
    )
    program = pullback.lower(*values).as_text()
    for target in ("membrane_nodes_backward", "membrane_forces_backward", "node_sphere_backward"):
        assert f"membrax_{target}_f64" in program

    # vmap over two moduli (the kernels run once per member, their aliases in each) equals a loop.
    def loss(modulus):
        changed = (*values[:5], params.set(modulus=modulus), damping)
        return sum(jnp.sum(out**2) for out in without_mesh(node_update.node_step)(*changed)[4:7])

    moduli = jnp.asarray([1.4e6, 2.1e6])
    batched = jax.jit(jax.vmap(jax.value_and_grad(loss)))(moduli)
    for k in range(2):
        one = jax.jit(jax.value_and_grad(loss))(moduli[k])
        assert _relative_error(batched[0][k], one[0]) < 1e-14
        assert _relative_error(batched[1][k], one[1]) < 1e-12


def test_node_step_differentiated_in_the_rest_geometry_uses_the_reference_rule():
    """Where the mesh's rest geometry is differentiated, node_step keeps all its arguments and takes the
    JAX definitions' rule: the rest areas' cotangent against ``jax.vjp`` of the composed definitions
    (float64, 1e-12 of the largest entry), with the positions' and moduli's beside it."""
    node_update, args = _node_step_case(seed=6)
    nodes, spheres, candidates, spring, dt, params, damping, mesh = args
    outputs = node_update.node_step(*args)
    rng = np.random.default_rng(8)
    cotangents = tuple(jnp.asarray(rng.normal(size=out.shape)) for out in outputs)

    def pulled(function, area, position, modulus):
        def run(a, x, e):
            changed_mesh = dataclasses.replace(mesh, reference_area=a)
            changed = (nodes.set(position=x), spheres, candidates, spring, dt, params.set(modulus=e), damping)
            return function(*changed, changed_mesh)

        return jax.vjp(run, area, position, modulus)[1](cotangents)

    reference = jax.tree_util.Partial(node_update._node_step_reference, model="neo_hookean")
    primals = (mesh.reference_area, nodes.position, params.modulus)
    got = jax.jit(lambda *v: pulled(node_update.node_step, *v))(*primals)
    want = pulled(reference, *primals)
    for g, w in zip(got, want, strict=True):
        assert _relative_error(g, w) < 1e-12


def test_node_step_cotangents_in_float32_hold_the_float64_ones():
    """What users run: node_step's compiled rule in float32 against the float64 reference rule (the JAX
    definitions'), every floating argument, within float32's round-off grown by the step's sums (1e-4 of
    the largest entry; the contact law's sliding branch and the membrane's dual numbers lose a few digits)."""
    node_update, args = _node_step_case(seed=9)
    *values64, mesh = args

    def as32(value):
        if isinstance(value, jnp.ndarray) and value.dtype == jnp.float64:
            return value.astype(jnp.float32)
        return value

    def without_mesh(function, the_mesh):
        return lambda *a: function(*a, the_mesh, model="neo_hookean")

    values32 = jax.tree.map(as32, values64)
    mesh32 = jax.tree.map(as32, mesh)
    outputs = without_mesh(node_update._node_step_reference, mesh)(*values64)
    rng = np.random.default_rng(10)
    cotangents64 = tuple(jnp.asarray(rng.normal(size=out.shape)) for out in outputs)
    want = jax.vjp(without_mesh(node_update._node_step_reference, mesh), *values64)[1](cotangents64)
    compiled = without_mesh(node_update.node_step, mesh32)
    got = jax.jit(lambda *v: jax.vjp(compiled, *v)[1](jax.tree.map(as32, cotangents64)))(*values32)
    checked = 0
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        if jnp.dtype(w.dtype) == jax.dtypes.float0:
            continue
        assert g.dtype == jnp.float32 or g.ndim == 0  # Python-float arguments have weak float64 cotangents
        assert _relative_error(np.asarray(g, np.float64), w) < 1e-4, checked
        checked += 1
    assert checked >= 10


@pytest.mark.slow
def test_rollout_gradient_is_the_same_through_whole_windows_loop_windows_and_the_jax_path(monkeypatch):
    """A checkpointed rollout's gradient is the same whichever way its windows run (float64, round-off).

    ``checkpoint_window`` runs each window as a loop (two steps per iteration, the default) or, with
    ``unroll`` ≥ ``window``, whole, without a loop (no residual stacks); the gradient must not move. With
    the kernels switched off the step is XLA's JAX code and each step is checkpointed inside the windows
    (its residuals are ~20× the kernels' per step); nor there.
    """
    from helpers import SMALL_MEMBRANE_TEST

    from membrax import gradients

    config = dataclasses.replace(SMALL_MEMBRANE_TEST, viscous_damping=True)  # smooth: a derivative exists
    wrt = ("membrane_modulus_kpa", "membrane_friction_angle_deg")
    weights = jnp.asarray(np.random.default_rng(7).normal(size=(1, 6)))

    def gradient_and_program(rollout, unroll=None):  # None: the rollout's own (a loop by 2)
        theta = jnp.asarray(rollout.theta0)
        objective = lambda t: jnp.sum(weights * rollout.outputs_and_errors(t, unroll)[0])  # noqa: E731
        program = jax.jit(jax.grad(objective)).lower(theta)
        jaxpr = str(jax.make_jaxpr(objective)(theta))  # the program's own path
        return np.asarray(program.compile()(theta)), program.as_text(), jaxpr.count("remat")

    with jax.enable_x64(True):
        rollout = gradients.consolidation_rollout(config, wrt, steps=40, window=5)
        kernels, kernel_program, kernel_checkpoints = gradient_and_program(rollout)
        whole_windows, whole_program, _ = gradient_and_program(rollout, unroll=5)
        with monkeypatch.context() as patch:
            patch.setenv("MEMBRAX_NATIVE", "0")
            native.available.cache_clear()
            try:  # the same members and start states, traced again (a fresh Rollout compiles anew)
                jax_code, jax_program, jax_checkpoints = gradient_and_program(dataclasses.replace(rollout))
            finally:
                native.available.cache_clear()
    assert "membrax_" in kernel_program and "membrax_" not in jax_program  # each path what it says
    assert jax_checkpoints == kernel_checkpoints + 1  # each step checkpointed inside the windows
    assert np.all(np.abs(kernels) > 0.0)
    assert _relative_error(jax_code, kernels) < 1e-9  # measured 2e-11 over 200 steps
    assert _relative_error(whole_windows, kernels) < 1e-9
    # a whole window calls its five steps' kernels; a loop window's body one step's (its unroll is a
    # parameter of the scan until XLA compiles it)
    assert whole_program.count("membrax_node_sphere") > kernel_program.count("membrax_node_sphere")


def test_the_chunks_scheduler_option_changes_the_order_not_the_bits():
    """``native.compiler_options`` (XLA-CPU's memory-optimised scheduler) reorders a step's thunks; 300
    coupled steps of a consolidating specimen in float32, sheared by its servo, end on the same bits."""
    from membrax.spheres import fcc
    from membrax.triaxial import membrane_cell

    def run(options):
        steps = lambda s: jax.lax.fori_loop(0, 300, lambda _, x: test.runner.step_fn(x, test.params), s)  # noqa: E731
        return jax.device_get(jax.jit(steps, compiler_options=options)(state))

    with jax.enable_x64(False):
        specimen = fcc.fcc_specimen(0.025, 4, 5)
        test = membrane_cell.membrane_test(
            specimen, cell_pressure=1e4, membrane_thickness=0.005, edges_per_diameter=2.0
        )
        state = test.set_platens(test.initial_state, True, 0.0, test.cell_pressure)
        assert state.dem.position.dtype == jnp.float32
        default, reordered = run(None), run(native.compiler_options())
    assert float(np.abs(default.dem.velocity).max()) > 0.0  # it moved
    for a, b in zip(jax.tree.leaves(default), jax.tree.leaves(reordered), strict=True):
        np.testing.assert_array_equal(a, b)
    if jax.default_backend() == "cpu":  # and the option is read: the compiled order differs
        assert native.compiler_options() == {"xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"}
        with jax.enable_x64(False):
            orders = [
                jax.jit(test.runner.step_fn, compiler_options=o).lower(state, test.params).compile().as_text()
                for o in (None, native.compiler_options())
            ]
        assert orders[0] != orders[1]


# ---- The face contact kernel (face_contact.cc) against face_contact.reference_face_contact_forces.

#: Per dtype, the largest error of the kernel's fields relative to the reference's largest entry: float64
#: round-off (the torques lose about three digits to the cancellation of arm × force, as above); float32
#: measured 7e-7 (forces, springs) and 2e-6 (torques) on this case.
_FACE_TOLERANCE = {"float64": (1e-12, 1e-10), "float32": (1e-5, 5e-5)}


def _face_contact_case(dtype, seed=0, edge=0.006):
    """A wrinkled 120 mm sheet (6 mm triangles, or ``edge``) indented by 16 spheres, 0 to 1.5 mm deep,
    moving and spinning, with carried springs of up to ~100 N (some beyond μ F_n: sliding), in ``dtype``."""
    from membrax.membrane import face_contact
    from membrax.membrane.candidates import build_candidates
    from membrax.membrane.mesh import flat_mesh

    rng = np.random.default_rng(seed)
    mesh = flat_mesh(0.12, 0.12, edge, dtype=dtype)
    position = np.asarray(mesh.reference_position, np.float64).copy()
    position[:, 2] += 1e-3 * rng.standard_normal(len(position))
    radius, thickness = 0.0125, 0.002
    grid = np.linspace(0.02, 0.1, 4)
    centres = np.array(
        [
            [
                x + 4e-3 * rng.standard_normal(),
                y + 4e-3 * rng.standard_normal(),
                -(radius + thickness / 2) + 1.5e-3 * rng.random(),
            ]
            for x in grid
            for y in grid
        ]
    )
    num_spheres = len(centres)
    radii = radius * (1.0 + 0.1 * rng.random(num_spheres))
    table = build_candidates(
        jnp.asarray(position), jnp.asarray(centres), jnp.asarray(radii), thickness, 0.008, 3, grid=None
    )
    slots = face_contact.feature_slots(mesh, table.idx, num_spheres)

    def cast(array):
        return jnp.asarray(array, dtype)

    springs = tuple(
        cast(50.0 * rng.standard_normal(spring.shape)) for spring in face_contact.zero_springs(slots, dtype)
    )
    return dict(
        nodes=ContactNodes(
            position=cast(position), velocity=cast(0.01 * rng.standard_normal(position.shape))
        ),
        spheres=ContactSpheres(
            position=cast(centres),
            velocity=cast(0.01 * rng.standard_normal((num_spheres, 3))),
            angular_velocity=cast(rng.standard_normal((num_spheres, 3))),
            radius=cast(radii),
        ),
        mesh=mesh,
        slots=slots,
        springs=springs,
        dt=cast(1e-5),
        params=jax.tree.map(cast, MembraneContactParams.default(normal_stiffness=1e5)),
        membrane_thickness=cast(thickness),
    )


def _face_fields(result):
    """A FaceContactForces' arrays by name (the springs and normal forces one per feature kind)."""
    fields = {name: getattr(result, name) for name in ("node_force", "sphere_force", "sphere_torque")}
    fields.update({name: getattr(result, name) for name in ("slot_force", "branch", "overlap")})
    for kind, spring, normal in zip(
        ("face", "edge", "node"), result.spring, result.normal_force, strict=True
    ):
        fields[f"spring_{kind}"], fields[f"normal_force_{kind}"] = spring, normal
    return fields


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_face_contact_kernel_matches_the_jax_law_and_conserves_momentum(dtype):
    """The compiled face contact law (it runs: its custom call is in the program) gives the JAX law's
    forces, torques, springs and per-slot fields on a sheet indented at faces, edges and nodes, with
    sticking and sliding springs, to round-off of the dtype; momentum and angular momentum are conserved."""
    from membrax.membrane import face_contact

    case = _face_contact_case(jnp.dtype(dtype))
    assert "membrax_face_contact_forces" in jax.jit(face_contact.face_contact_forces).lower(**case).as_text()
    compiled = jax.jit(face_contact.face_contact_forces)(**case)
    reference = jax.jit(face_contact.reference_face_contact_forces)(**case)
    touching = [int(jnp.sum(force > 0.0)) for force in reference.normal_force]
    assert min(touching) > 0 and sum(touching) > 25, touching  # every kind of feature meets a sphere
    limit = [case["params"].friction_coefficient * force for force in reference.normal_force]  # μ F_n
    sliding = sum(
        int(jnp.sum((force > 0.0) & (jnp.linalg.norm(spring, axis=0) >= 0.999 * cap)))
        for force, spring, cap in zip(reference.normal_force, reference.spring, limit, strict=True)
    )
    assert 0 < sliding < sum(touching)  # both regimes of the spring
    tolerance, torque_tolerance = _FACE_TOLERANCE[dtype]
    got, want = _face_fields(compiled), _face_fields(reference)
    for name, value in want.items():
        bound = torque_tolerance if name == "sphere_torque" else tolerance
        assert _relative_error(got[name], value) < bound, (name, _relative_error(got[name], value))
    scale = float(np.max(np.abs(np.asarray(compiled.node_force, np.float64))))
    node_force, sphere_force = (
        np.asarray(a, np.float64) for a in (compiled.node_force, compiled.sphere_force)
    )
    np.testing.assert_allclose(node_force.sum(0), -sphere_force.sum(0), atol=10 * tolerance * scale)
    moment = (
        np.cross(np.asarray(case["nodes"].position, np.float64), node_force).sum(0)
        + np.cross(np.asarray(case["spheres"].position, np.float64), sphere_force).sum(0)
        + np.asarray(compiled.sphere_torque, np.float64).sum(0)
    )
    assert np.max(np.abs(moment)) < 10 * tolerance * scale * 0.12


def test_face_contact_kernel_gradients_vmap_and_repeatable_bits():
    """Reverse mode through the kernel runs its backward kernel (``face_contact_backward``) and gives the
    JAX law's gradient in every floating input (node and sphere positions, velocities, spins, radii,
    springs, thickness, k_n, k_t, μ, Δt) to round-off, float64 and float32; ``vmap`` over the thickness
    equals a loop of the reference, and two calls give the same bits; inconsistent sizes fail with the
    kernel's message."""
    from membrax.membrane import face_contact

    for dtype, tolerance in (("float64", 1e-12), ("float32", 1e-5)):  # float32 measured 1.1e-6
        case = _face_contact_case(jnp.dtype(dtype), seed=1)
        rng = np.random.default_rng(2)
        node_weights = jnp.asarray(rng.normal(size=case["nodes"].position.shape), dtype)
        sphere_weights = jnp.asarray(rng.normal(size=case["spheres"].position.shape), dtype)
        nodes, spheres, params = case["nodes"], case["spheres"], case["params"]

        def work(
            fn,
            nodes,
            spheres,
            springs,
            thickness,
            params,
            dt,
            case=case,
            weights=(node_weights, sphere_weights),
        ):
            result = fn(
                **{
                    **case,
                    "nodes": nodes,
                    "spheres": spheres,
                    "springs": springs,
                    "membrane_thickness": thickness,
                    "params": params,
                    "dt": dt,
                }
            )
            return (
                jnp.sum(weights[0] * result.node_force)
                + jnp.sum(weights[1] * (result.sphere_force + 100.0 * result.sphere_torque))
                + sum(jnp.sum(spring**2) for spring in result.spring)
            )

        args = (nodes, spheres, case["springs"], case["membrane_thickness"], params, case["dt"])
        argnums = tuple(range(len(args)))
        compiled = jax.jit(jax.grad(lambda *a: work(face_contact.face_contact_forces, *a), argnums))
        assert "membrax_face_contact_backward" in compiled.lower(*args).as_text()
        got = compiled(*args)
        want = jax.jit(jax.grad(lambda *a: work(face_contact.reference_face_contact_forces, *a), argnums))(
            *args
        )
        for got_leaf, want_leaf in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            assert float(jnp.max(jnp.abs(want_leaf))) > 0.0
            assert _relative_error(got_leaf, want_leaf) < tolerance, dtype

    case = _face_contact_case(jnp.dtype("float64"), seed=1)
    thicknesses = jnp.asarray([0.0015, 0.002, 0.0025])
    batched = jax.vmap(
        lambda t: face_contact.face_contact_forces(**{**case, "membrane_thickness": t}).node_force
    )(thicknesses)
    for k, thickness in enumerate(thicknesses):
        single = face_contact.reference_face_contact_forces(**{**case, "membrane_thickness": thickness})
        assert _relative_error(batched[k], single.node_force) < 1e-12
    first = jax.jit(face_contact.face_contact_forces)(**case)
    second = jax.jit(face_contact.face_contact_forces)(**case)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second), strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))

    f64, n, num_spheres = jnp.float64, 4, 2

    def zeros(*shape, dtype=f64):
        return jnp.zeros(shape, dtype)

    rows, sphere_rows = jax.ShapeDtypeStruct((n, 3), f64), jax.ShapeDtypeStruct((num_spheres, 3), f64)
    springs = [jax.ShapeDtypeStruct(shape, f64) for shape in ((3, 2, 3), (3, 1, 2), (3, n, 1))]
    arguments = (
        *(zeros(n, 3) for _ in range(2)),
        *(zeros(num_spheres, 3) for _ in range(3)),
        zeros(num_spheres),
        zeros(2, 3, dtype=jnp.int32),
        zeros(1, 2, dtype=jnp.int32),
        zeros(n, 1, dtype=jnp.int32),
        zeros(2, 3, dtype=jnp.int32),
        zeros(1, 4, dtype=jnp.int32),
        zeros(n, 3, dtype=jnp.int32),
        zeros(n, 3, dtype=jnp.int32),
        zeros(n, 3, dtype=jnp.int32),
        zeros(3, 2, 3),
        zeros(3, 1, 2),
        zeros(3, n, 1),
        zeros(4),  # 4 scalars for 5
    )
    with pytest.raises(Exception, match="face_contact_forces: "):
        jax.block_until_ready(
            native.call("face_contact_forces", f64, (rows, sphere_rows, sphere_rows, *springs), *arguments)
        )


def _face_contact_bits():
    """The face contact kernel's outputs and a gradient through its backward kernel, float64 and float32, on
    a 120 mm sheet of 1.5 mm triangles: 14,720 faces, 21,908 edges and 7,533 nodes, above parallel.h's
    thresholds (8,192 slots, 4,096 features of each kind), so that both kernels run in two halves."""
    from membrax.membrane import face_contact

    bits = {}
    for dtype in ("float64", "float32"):
        case = _face_contact_case(jnp.dtype(dtype), seed=1, edge=0.0015)
        assert min(getattr(case["slots"], kind).shape[0] for kind in ("face", "edge", "node")) >= 4096
        rng = np.random.default_rng(2)
        node_weights = jnp.asarray(rng.normal(size=case["nodes"].position.shape), dtype)
        sphere_weights = jnp.asarray(rng.normal(size=case["spheres"].position.shape), dtype)

        def work(nodes, spheres, springs, params, case=case, weights=(node_weights, sphere_weights)):
            result = face_contact.face_contact_forces(
                **{**case, "nodes": nodes, "spheres": spheres, "springs": springs, "params": params}
            )
            return (
                jnp.sum(weights[0] * result.node_force)
                + jnp.sum(weights[1] * (result.sphere_force + 100.0 * result.sphere_torque))
                + sum(jnp.sum(spring**2) for spring in result.spring)
            )

        args = (case["nodes"], case["spheres"], case["springs"], case["params"])
        outputs = jax.tree.leaves(jax.jit(face_contact.face_contact_forces)(**case))
        gradient = jax.tree.leaves(jax.jit(jax.grad(work, argnums=(0, 1, 2, 3)))(*args))
        for name, leaves in (("forward", outputs), ("gradient", gradient)):
            bits.update({f"{dtype}_{name}_{k}": np.asarray(leaf) for k, leaf in enumerate(leaves)})
    return bits


def test_face_contact_kernels_in_halves_give_the_serial_kernels_bits(tmp_path):
    """Above parallel.h's thresholds the face contact kernels split each kind's features in two halves (the
    forward's as two pool tasks, the backward's second half offered to the pool) and add the spheres'
    reactions and the cotangents up after them, in slot order. Their forward outputs and gradients, float64
    and float32, equal to the bit those of a second call and those of the same kernels run serially
    (``MEMBRAX_NATIVE_THREADS=1``: every loop in its caller, in a fresh process)."""
    threaded = _face_contact_bits()
    assert sum(int(np.count_nonzero(value)) > 0 for value in threaded.values()) == len(threaded)
    again = _face_contact_bits()
    saved = tmp_path / "serial.npz"
    script = textwrap.dedent(
        f"""
        import sys
        import jax
        jax.config.update("jax_enable_x64", True)
        import numpy as np
        sys.path.insert(0, {str(os.path.dirname(__file__))!r})
        import test_native
        np.savez({str(saved)!r}, **test_native._face_contact_bits())
        """
    )
    environment = {**os.environ, "MEMBRAX_NATIVE_THREADS": "1"}
    subprocess.run([sys.executable, "-c", script], env=environment, check=True)
    serial = dict(np.load(saved))
    assert serial.keys() == threaded.keys() == again.keys()
    for name, value in threaded.items():
        assert value.dtype == serial[name].dtype
        assert np.array_equal(value, again[name]), name
        assert np.array_equal(value, serial[name]), name


def test_coupled_step_with_face_contact_runs_the_kernel_with_the_jax_laws_numbers(monkeypatch):
    """The coupled step of a specimen with face contact (``contact_model="faces"``) calls the compiled face
    contact law on the CPU, and one step of it gives the step with the JAX law (``face_contact.runs_kernel``
    False) to round-off: from the start of a 4 × 4 × 5 FCC specimen's consolidation at 10 kPa (float64)
    and from its state 300 steps on (springs sticking and sliding).

    (Step by step from the same state: whole trajectories do not compare, as the local damping's sign of
    the spheres' spins, zero to round-off at the start, turns round-off into 0.1 rad/s within three steps.)
    """
    from membrax.membrane import face_contact
    from membrax.spheres import fcc
    from membrax.triaxial.membrane_cell import membrane_test

    test = membrane_test(
        fcc.fcc_specimen(0.025, 4, 5),
        cell_pressure=1e4,
        membrane_thickness=5e-3,
        edges_per_diameter=3.0,
        contact_model="faces",
    )
    start = test.set_platens(test.initial_state, True, 0.0, test.cell_pressure)
    step = jax.jit(lambda s: test.runner.step_fn(s, test.params))
    later = jax.jit(lambda s: jax.lax.fori_loop(0, 300, lambda _, x: test.runner.step_fn(x, test.params), s))(
        start
    )
    assert "membrax_face_contact_forces" in step.lower(start).as_text()
    with_kernel = [step(state) for state in (start, later)]
    monkeypatch.setattr(face_contact, "runs_kernel", lambda dtype: False)
    jax_step = jax.jit(lambda s: test.runner.step_fn(s, test.params))
    assert "membrax_face_contact_forces" not in jax_step.lower(start).as_text()
    with_jax = [jax_step(state) for state in (start, later)]
    springs_moved = float(
        jnp.max(jnp.abs(jnp.concatenate([s.ravel() for s in later.membrane.feature_contact.spring])))
    )
    assert springs_moved > 0.0
    fields = {  # each field's absolute bound: round-off of its scale (m, m/s, rad/s, N)
        "node position": (lambda s: s.membrane.position, 1e-15),
        "node velocity": (lambda s: s.membrane.velocity, 1e-12),
        "sphere position": (lambda s: s.dem.position, 1e-15),
        "sphere velocity": (lambda s: s.dem.velocity, 1e-13),
        "sphere spin": (lambda s: s.dem.angular_velocity, 1e-11),
        "contact force on the spheres": (lambda s: s.membrane.sphere_force, 1e-10),
        "springs": (lambda s: jnp.concatenate([x.ravel() for x in s.membrane.feature_contact.spring]), 1e-11),
    }
    for got, want in zip(with_kernel, with_jax, strict=True):
        assert int(got.error) == int(want.error)
        for name, (get, bound) in fields.items():
            difference = float(jnp.max(jnp.abs(get(got) - get(want))))
            assert difference < bound, (name, difference)
