"""The membrane's nodes through one step: the node update, and the node half of a coupled step.

Contract. :func:`advance_nodes` is step 4 of :mod:`membrax.membrane.coupled` for every node: the damped
leapfrog of the free nodes under the membrane and contact forces (:class:`MembraneNodes`: positions,
compensations, velocities, lumped masses, free mask and the damping's reference velocity), clamped nodes
held at rest (the coupled step moves them with their platens). :func:`node_step` runs the node–sphere
contacts (:func:`membrax.membrane.contact.node_sphere_forces`), the membrane forces
(:func:`membrax.membrane.energies.nodal_forces`) and :func:`advance_nodes` as one function. Both are pure,
jittable and differentiable; their JAX definitions (``_advance_nodes_reference``, ``_node_step_reference``)
are bound here to the CPU kernels (:mod:`membrax.membrane._kernels`) by
:func:`membrax.native.with_reference`. SI units: m, s, N, kg.

Reverse mode. On the CPU kernels (:mod:`membrax.native`), the coupled step's steps 1, 2 and 4 are one
reverse-mode rule, :func:`node_step`: the same forward kernels, so the same numbers, and backward kernels
chained so that each adds its share of the nodes' position and velocity cotangents to the last one's in
place, where three separate rules left XLA to add three (n, 3) cotangents and copy them into a rollout's
loop carry on every step. Elsewhere (other backends and dtypes, or the kernels off) the three functions
run one after the other.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp

from membrax import native, pytree
from membrax.compensated import compensated_add
from membrax.defaults import STRETCHING_MODELS
from membrax.membrane import _kernels, energies
from membrax.membrane.contact import ContactNodes, ContactSpheres, node_sphere_reference
from membrax.membrane.mesh import MembraneMesh
from membrax.spheres.integrate import DampingParams, apply_damping

__all__ = ["MembraneNodes", "advance_nodes", "node_step"]


@pytree.dataclass
class MembraneNodes:
    """The membrane's nodes as the node update integrates them (rows, SI; the coupled step's step 4).

    Attributes:
      position: (n, 3) node positions y_n, m.
      position_compensation: (n, 3) low-order part of y_n, m.
      velocity: (n, 3) node velocities at the previous half step, m/s.
      mass: (n,) lumped masses, kg.
      free: (n,) bool, the nodes that move (False on the clamped rings).
      reference_velocity: (n, 3) the velocity field the damping is relative to, m/s (the platens' affine
        field, :func:`membrax.spheres.walls.affine_velocity`); None for 0, the absolute law.
    """

    position: jnp.ndarray
    position_compensation: jnp.ndarray
    velocity: jnp.ndarray
    mass: jnp.ndarray
    free: jnp.ndarray
    reference_velocity: jnp.ndarray | None = None

    def for_contact(self) -> ContactNodes:
        """The positions and velocities, as the node–sphere law reads them."""
        return ContactNodes(position=self.position, velocity=self.velocity)


def advance_nodes(membrane_force, contact_force, nodes: MembraneNodes, dt, damping: DampingParams):
    """The coupled step's step 4 for every node: (total force, velocity, position, compensation).

    F = F_membrane + F_contact; F_d = F − α|F| sign(u) − γ m u, u = v − v_ref (``nodes.reference_velocity``,
    0 when None; :func:`membrax.spheres.integrate.apply_damping`); v' = v + Δt F_d/m on the free nodes and
    0 on the others (``nodes.free``); x' + c' = x + c + Δt v' (:func:`membrax.compensated.compensated_add`).
    On the CPU, in float32 or float64, one pass of a compiled kernel (:mod:`membrax.native`,
    ``membrane_nodes.cc``) does it, and reverse mode a compiled backward kernel
    (``membrane_nodes_backward``) that gives this JAX code's derivatives to round-off. The damping
    coefficients are one specimen's (scalars, or arrays of one member).
    """
    args = (membrane_force, contact_force, nodes, dt, damping)
    if native.enabled_for(nodes.position.dtype):
        return _compiled_advance_nodes(*args)
    return _advance_nodes_reference(*args)


def _advance_nodes_reference(membrane_force, contact_force, nodes: MembraneNodes, dt, damping):
    force = membrane_force + contact_force
    member = jnp.zeros(nodes.position.shape[0], dtype=jnp.int32)
    damped = apply_damping(force, nodes.velocity, nodes.mass, damping, member, nodes.reference_velocity)
    velocity = jnp.where(nodes.free[:, None], nodes.velocity + dt * damped / nodes.mass[:, None], 0.0)
    position, compensation = compensated_add(nodes.position, nodes.position_compensation, dt * velocity)
    return force, velocity, position, compensation


_compiled_advance_nodes = native.with_reference(
    _kernels.advance_nodes_kernel,
    _advance_nodes_reference,
    _kernels.advance_nodes_backward,
    _kernels.advance_nodes_residuals,
)


# Steps 1, 2 and 4 of the coupled step for every node, as one reverse-mode rule on the CPU. Run as
# three separate rules, their backward kernels each return a cotangent of the node positions (and two of
# the velocities), which XLA then adds in passes over the whole mesh and copies into the loop's carry;
# chained here, each kernel adds its share in place to the one before (the kernels' addends).
def node_step(
    nodes: MembraneNodes,
    spheres: ContactSpheres,
    candidates,
    spring,
    dt,
    params,
    damping: DampingParams,
    mesh: MembraneMesh,
    model: str = "neo_hookean",
):
    """The node–sphere contacts, the membrane forces and the node update of one step, on the CPU kernels.

    The same numbers as :func:`membrax.membrane.contact.node_sphere_forces` (``nodes.for_contact()``,
    ``spheres``, ``candidates``, ``spring``, ``dt``, ``params.contact``, ``params.contact_thickness``),
    :func:`membrax.membrane.energies.nodal_forces` (at ``nodes.position``, ``mesh``, ``params.modulus``,
    ``params.thickness``, ``params.cell_pressure``, ν of latex, ``params.bending_factor``,
    ``params.locking_jm``) and
    :func:`advance_nodes` (those forces, ``nodes``, ``dt``, ``damping``), from the same kernels, so the
    same bits. Reverse mode runs their three backward kernels one after the other, each adding its share of
    the nodes' cotangents to the last one's in place; it gives the three functions' derivatives to
    round-off (``tests/test_native.py``), also under ``vmap``, and falls back to the JAX definitions' where
    the mesh's rest geometry is differentiated. For float32 and float64 where
    :func:`membrax.native.enabled_for`.

    Args:
      nodes: the nodes' positions, compensations, velocities, masses and free mask.
      spheres: the spheres as the node–sphere law reads them.
      candidates: (n, K) int sphere ids padded with N (``NodeCandidates.idx``).
      spring: (3, n, K) carried tangential springs, N.
      dt: time step, s.
      params: the membrane's parameters (:class:`membrax.membrane.coupled.MembraneParams`, its contact
        law among them).
      damping: the damping law of the nodes (the DEM's).
      mesh: the membrane.
      model: the stretching law (static).

    Returns:
      (contact node force, sphere force, sphere torque, new springs, total node force F, velocity,
      position, compensation), as the three functions return them.
    """
    return _COMPILED_NODE_STEP[model](nodes, spheres, candidates, spring, dt, params, damping, mesh)


def _node_step_reference(*args, model):
    contact, membrane, update = _kernels.node_step_parts(*args)
    contact_outputs = node_sphere_reference(*contact)
    internal = energies.reference_nodal_forces(*membrane[:7], model, *membrane[7:])  # J_m after the model
    return (*contact_outputs, *_advance_nodes_reference(internal, contact_outputs[0], *update))


_COMPILED_NODE_STEP = {
    model: native.with_reference(
        functools.partial(_kernels.node_step_kernel, model=model),
        functools.partial(_node_step_reference, model=model),
        functools.partial(
            _kernels.node_step_backward,
            model=model,
            reference=functools.partial(_node_step_reference, model=model),
        ),
        _kernels.node_step_residuals,
    )
    for model in STRETCHING_MODELS
}
