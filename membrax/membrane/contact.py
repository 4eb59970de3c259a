"""Membrane node–sphere contacts: penalty normal spring, Coulomb-capped tangential spring.

Contract. The membrane's nodes (rows of an (n_nodes, 3) array, see :mod:`membrax.membrane.mesh`) touch the
spheres through a node–sphere contact law that is a pure function of the kinematics, a dense candidate
table and the carried tangential springs; it returns the forces on the nodes, the forces and torques on
the spheres, the updated springs and the normal forces (:func:`node_sphere_forces`). The conservative
part (the normal spring) is ``-jax.grad`` of :func:`node_sphere_normal_energy`; the non-conservative part
(the tangential spring with Coulomb slip) is an explicit force function, as in :mod:`membrax.spheres.contact`.
Everything is jittable and vmappable; the normal energy is differentiable in the positions, radii and
thickness.

The law (the issue's "Node–particle contact"; Cundall & Strack 1979, Géotechnique 29(1), 47–65, linear
model, with the membrane's half thickness added to the sphere radius):

- normal: the node is a point on the membrane mid-surface, so it touches sphere i when
  |x_node − x_i| < R_i + t_m/2. Overlap δ = R_i + t_m/2 − |x_node − x_i|, energy U_n = ½ k_n max(δ, 0)²,
  force on the node F_n = −∂U_n/∂x_node = k_n δ n, n = (x_node − x_i)/|x_node − x_i| (outward from the
  sphere centre); the opposite force on the sphere. No force at or beyond the threshold (δ <= 0).
- tangential: an incremental spring s (force on the node) carried per (node, candidate) slot, advanced by
  :func:`membrax.spheres.contact.tangential_spring_update` (rotated into the current tangent plane,
  incremented by −k_t v_t Δt, capped by |s| <= μ |F_n|, cleared when the contact opens). "A node stays on the
  particle until the frictional limit is exceeded or it is pulled away" is exactly this spring: it
  sticks (elastically, displacement s/k_t) below μ F_n, slides at μ F_n above, and is reset when δ <= 0.
- slip velocity and torque: the node carries no rotation, so its force acts at x_node. The sphere's
  material point under the node is at the arm b = x_node − x_i (length R_i + t_m/2 − δ along n); the
  slip velocity is v_t = Π_t[v_node − (v_i + ω_i × b)] and the torque on the sphere is b × (−F). Using
  the same arm in both makes the friction power F·v_rel equal to the mechanical power the pair loses and
  conserves angular momentum exactly: Σ x × F + Σ torques = 0 to round-off. (An arm R_i n, the sphere
  surface, would leave an unbalanced couple (t_m/2 − δ) n × s per contact, because the point node cannot
  take a moment; the two arms differ by t_m/2 − δ in length, i.e. rolling slip is overestimated by the
  factor (R + t_m/2 − δ)/R ≈ 1 + t_m/(2R) against a surface point.)

Defaults (:meth:`MembraneContactParams.default`): k_n = 1e5 N/m, k_t = k_n, μ = tan 25°. Why 1e5 N/m: a
membrane node's lumped mass is (area share) × t_m × ρ; for near-equilateral triangles of edge a each
interior node gets (√3/2) a², so a = 5 mm, t_m = 5 mm, ρ = 1000 kg/m³ give m = 1.08e-4 kg (measured on
:func:`membrax.membrane.mesh.cylinder_mesh`; 5.4e-5 kg on the clamped end rings). Then √(m/k_n) = 3.3e-5 s
(2.3e-5 s on the end rings), so the explicit stable step 2√(m/k) stays above the ~1e-5 s that the
prototype found usable; the sphere–sphere k_n = 1e7 N/m would give √(m/k) = 3.3e-6 s (2.3e-6 s), forcing
a step near 5e-6 s or density scaling of the membrane. The penalty only has to keep δ small against the
sphere size: a node pushed by 1 N (about 100 kPa over a 5 mm mesh cell) sinks δ = F/k_n = 10 µm.

Candidates: :mod:`membrax.membrane.candidates` (the dense node–sphere table this law reads).

Layout: nodes and spheres are rows of (n, 3) arrays; per-slot quantities gather rows (``x[idx]``) and are
then handled component-first (3, n_nodes, K) with :mod:`membrax.vector`; the carried springs stay in that
layout. Sphere forces are sums over
the table's sphere incidence (``NodeCandidates.sphere_slots``, built with the table) of gathered slot
rows; without it, ``jax.ops.segment_sum`` on rows (the same sums, several times slower on XLA-CPU).
SI units: m, s, N, N·m, kg.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from membrax import native, pytree
from membrax.fusion import materialize
from membrax.membrane import _kernels
from membrax.spheres.contact import normal_energy, tangential_spring_update
from membrax.vector import cross, dot, safe_norm, safe_normalize, scale, select

__all__ = [
    "ContactNodes",
    "ContactSpheres",
    "MembraneContactParams",
    "NodeSphereForces",
    "node_sphere_forces",
    "node_sphere_normal_energy",
    "node_sphere_reference",
]


@pytree.dataclass
class MembraneContactParams:
    """Parameters of the node–sphere contact law (SI). Each field is a scalar or an array over batch members.

    Attributes:
      normal_stiffness: k_n, N/m (default 1e5, see the module docstring).
      tangential_stiffness: k_t, N/m (default k_n).
      friction_coefficient: μ = tan φ (default tan 25°).
    """

    normal_stiffness: jnp.ndarray
    tangential_stiffness: jnp.ndarray
    friction_coefficient: jnp.ndarray

    @staticmethod
    def default(
        normal_stiffness: float = 1e5,
        tangential_stiffness: float | None = None,
        friction_angle_deg: float = 25.0,
    ) -> MembraneContactParams:
        """k_n = 1e5 N/m, k_t = k_n unless given, μ = tan 25°."""
        if tangential_stiffness is None:
            tangential_stiffness = normal_stiffness
        return MembraneContactParams(
            normal_stiffness=jnp.asarray(normal_stiffness),
            tangential_stiffness=jnp.asarray(tangential_stiffness),
            friction_coefficient=jnp.asarray(math.tan(math.radians(friction_angle_deg))),
        )


@pytree.dataclass
class ContactNodes:
    """The membrane nodes as the node–sphere law reads them (rows, SI).

    Attributes:
      position: (n_nodes, 3) node positions, m.
      velocity: (n_nodes, 3) node velocities, m/s.
    """

    position: jnp.ndarray
    velocity: jnp.ndarray


@pytree.dataclass
class ContactSpheres:
    """The spheres as the node–sphere law reads them (rows, SI).

    Attributes:
      position: (N, 3) centres, m.
      velocity: (N, 3) m/s.
      angular_velocity: (N, 3) rad/s.
      radius: (N,) m.
    """

    position: jnp.ndarray
    velocity: jnp.ndarray
    angular_velocity: jnp.ndarray
    radius: jnp.ndarray


class NodeSphereForces(NamedTuple):
    """Result of :func:`node_sphere_forces` (unpacks as a tuple).

    Attributes:
      node_force: (n_nodes, 3) total contact force on each node, N.
      sphere_force: (N, 3) total contact force on each sphere, N.
      sphere_torque: (N, 3) total contact torque on each sphere about its centre, N·m.
      spring: (3, n_nodes, K) updated tangential springs (force on the node), N, component-first like the
        slot law itself, so the carried state is the law's own output (a row-major copy would make XLA
        evaluate the law a second time: 28 % of the coupled step at paper size).
      normal_force: (n_nodes, K) |F_n| per slot, N (0 where not touching).
      overlap: (n_nodes, K) δ per slot, m (negative: gap; padded slots −1).
      slot_force: (n_nodes, K, 3) force of the candidate sphere on the node per slot, N (zero if none).
      branch: (n_nodes, K, 3) b = x_node − x_sphere per slot, m (the arm of the torque).
    """

    node_force: jnp.ndarray
    sphere_force: jnp.ndarray
    sphere_torque: jnp.ndarray
    spring: jnp.ndarray
    normal_force: jnp.ndarray
    overlap: jnp.ndarray
    slot_force: jnp.ndarray
    branch: jnp.ndarray


def _component_first(rows):
    """(..., 3) → (3, ...)."""
    return jnp.moveaxis(rows, -1, 0)


def _slot_geometry(node_position, sphere_position, sphere_radius, candidates, membrane_thickness):
    """Branch b = x_node − x_sphere (3, n_nodes, K), reach R + t_m/2 (n_nodes, K) and validity per slot."""
    num_spheres = sphere_position.shape[0]
    valid = candidates < num_spheres
    safe_idx = jnp.where(valid, candidates, 0)
    sphere_rows = sphere_position[safe_idx]  # (n_nodes, K, 3): gathers rows
    branch = _component_first(node_position[:, None, :] - sphere_rows)
    reach = sphere_radius[safe_idx] + 0.5 * membrane_thickness
    return branch, reach, valid, safe_idx


def _slot_energy(branch, reach, valid, normal_stiffness):
    """Sum of the per-slot normal energies ½ k_n max(δ, 0)², δ = reach − |b|; padded slots contribute 0.

    ``branch`` is (3, n_nodes, K) or a tuple of its three components; the gradient with respect to the
    tuple is three arrays, which XLA-CPU forms without padding each component into a (3, ...) array.
    """
    overlap = jnp.where(valid, reach - safe_norm(branch), -1.0)
    return jnp.sum(normal_energy(overlap, normal_stiffness))


def node_sphere_normal_energy(
    node_position, sphere_position, sphere_radius, candidates, normal_stiffness, membrane_thickness
):
    """Total normal penalty energy U = Σ_slots ½ k_n max(δ, 0)², δ = R_i + t_m/2 − |x_node − x_i| (J).

    Its negative gradient w.r.t. ``node_position`` and ``sphere_position`` are the normal contact forces
    (see the module docstring).

    Args:
      node_position: (n_nodes, 3), m.
      sphere_position: (N, 3), m.
      sphere_radius: (N,), m.
      candidates: (n_nodes, K) int sphere ids padded with N.
      normal_stiffness: k_n, N/m.
      membrane_thickness: t_m, m.
    """
    branch, reach, valid, _ = _slot_geometry(
        node_position, sphere_position, sphere_radius, candidates, membrane_thickness
    )
    return _slot_energy(branch, reach, valid, normal_stiffness)


def node_sphere_forces(
    nodes: ContactNodes,
    spheres: ContactSpheres,
    candidates,
    spring,
    dt,
    params: MembraneContactParams,
    membrane_thickness,
    sphere_slots=None,
) -> NodeSphereForces:
    """Node–sphere contact forces, torques and springs for one step (law in the module docstring).

    F_node = k_n δ n + s',  F_sphere = −F_node,  τ_sphere = b × F_sphere,  b = x_node − x_sphere,
    s' = tangential_spring_update(s, n, Π_t[v_node − v_i − ω_i × b], Δt, k_t, μ, k_n δ, δ > 0).

    On the CPU, in float32 or float64, the forces, torques and springs come from a compiled kernel
    (:mod:`membrax.native`, ``node_sphere.cc``) that runs over the slots once, skips the padded ones
    before any gather and applies this law to the touching ones alone. The JAX law below
    (``_reference_node_sphere_forces``) is the definition the tests hold the kernel to (agreement to
    round-off); reverse mode runs a compiled backward kernel (``node_sphere_backward``, the law of each
    touching slot run backwards by hand) that gives the JAX law's derivatives to round-off.

    Args:
      nodes: the nodes' positions and velocities (:class:`ContactNodes`).
      spheres: the spheres' positions, velocities, angular velocities and radii (:class:`ContactSpheres`).
      candidates: (n_nodes, K) int sphere ids padded with N (``NodeCandidates.idx``).
      spring: (3, n_nodes, K) carried tangential springs (force on the node), N.
      dt: time step, s.
      params: :class:`MembraneContactParams`.
      membrane_thickness: t_m, m.
      sphere_slots: optional (N, M) slot incidence of the spheres (``NodeCandidates.sphere_slots``): the
        sphere forces and torques are then sums of gathered slot rows, which XLA-CPU runs several times
        faster than the ``segment_sum`` scatter used without it (same result to round-off).

    Returns:
      A :class:`NodeSphereForces`.
    """
    args = (nodes, spheres, candidates, spring, dt, params, membrane_thickness)
    if not native.enabled_for(jnp.asarray(nodes.position).dtype):
        return _reference_node_sphere_forces(*args, sphere_slots=sphere_slots)
    outputs = _compiled_node_sphere_forces(*args)  # node force, sphere force, sphere torque, springs
    # The per-slot fields from the geometry and the new springs; XLA drops those a caller does not use.
    branch, reach, valid, _ = _slot_geometry(
        nodes.position, spheres.position, spheres.radius, candidates, membrane_thickness
    )
    normal, distance = safe_normalize(branch)
    overlap = jnp.where(valid, reach - distance, -1.0)
    normal_force = jnp.where(distance > 0.0, params.normal_stiffness * jnp.maximum(overlap, 0.0), 0.0)
    force_on_node = select(valid, scale(normal_force, normal) + outputs[3])
    return NodeSphereForces(
        *outputs,
        normal_force=normal_force,
        overlap=overlap,
        slot_force=jnp.moveaxis(force_on_node, 0, -1),
        branch=jnp.moveaxis(branch, 0, -1),
    )


def node_sphere_reference(*args):
    """The four outputs of the compiled node–sphere kernel (membrane/_kernels.py), from the JAX law."""
    result = _reference_node_sphere_forces(*args)
    return result.node_force, result.sphere_force, result.sphere_torque, result.spring


_compiled_node_sphere_forces = native.with_reference(
    _kernels.node_sphere_kernel, node_sphere_reference, _kernels.backward_node_sphere_forces
)


def _reference_node_sphere_forces(
    nodes, spheres, candidates, spring, dt, params, membrane_thickness, sphere_slots=None
) -> NodeSphereForces:
    """:func:`node_sphere_forces` in JAX: the definition of the law, and its derivatives."""
    num_spheres = spheres.position.shape[0]
    branch, reach, valid, safe_idx = _slot_geometry(
        nodes.position, spheres.position, spheres.radius, candidates, membrane_thickness
    )
    normal_force_vector = -jnp.stack(
        jax.grad(_slot_energy)(tuple(branch), reach, valid, params.normal_stiffness)
    )  # on the node
    normal, distance = safe_normalize(branch)
    overlap = jnp.where(valid, reach - distance, -1.0)
    active = overlap > 0.0
    normal_force = dot(normal_force_vector, normal)

    node_velocity_t = jnp.broadcast_to(_component_first(nodes.velocity)[:, :, None], spring.shape)
    sphere_velocity_t = _component_first(spheres.velocity[safe_idx])
    sphere_angular_velocity_t = _component_first(spheres.angular_velocity[safe_idx])
    relative_velocity = node_velocity_t - (sphere_velocity_t + cross(sphere_angular_velocity_t, branch))
    tangential_velocity = relative_velocity - scale(dot(relative_velocity, normal), normal)
    # Stored once each: XLA-CPU would otherwise re-evaluate the law per component and per output.
    normal_force_vector, normal, tangential_velocity, normal_force, active = materialize(
        normal_force_vector, normal, tangential_velocity, normal_force, active
    )
    new_spring = tangential_spring_update(
        spring,
        normal,
        tangential_velocity,
        dt,
        params.tangential_stiffness,
        params.friction_coefficient,
        normal_force,
        active,
    )
    force_on_node = select(valid, normal_force_vector + new_spring)  # (3, n_nodes, K)
    new_spring, force_on_node = materialize(new_spring, force_on_node)
    torque_on_sphere = cross(branch, -force_on_node)

    def to_rows(vector):
        return jnp.moveaxis(vector, 0, -1)  # (3, n, K) → (n, K, 3)

    if sphere_slots is None:
        segment = jnp.where(valid, safe_idx, num_spheres).reshape(-1)

        def scatter(per_slot):
            summed = jax.ops.segment_sum(per_slot.reshape(-1, 3), segment, num_segments=num_spheres + 1)
            return summed[:num_spheres]

        sphere_force, sphere_torque = -scatter(to_rows(force_on_node)), scatter(to_rows(torque_on_sphere))
    else:
        # Force and torque side by side, one padding row for the empty incidence entries.
        per_slot = jnp.concatenate([to_rows(-force_on_node), to_rows(torque_on_sphere)], axis=-1)
        per_slot = jnp.concatenate([per_slot.reshape(-1, 6), jnp.zeros((1, 6), per_slot.dtype)])
        on_spheres = jnp.sum(per_slot[sphere_slots], axis=1)  # (N, 6)
        sphere_force, sphere_torque = on_spheres[:, :3], on_spheres[:, 3:]

    # K adds rather than a sum over the short slot axis, which XLA-CPU reduces several times slower.
    node_force = sum(force_on_node[:, :, k] for k in range(force_on_node.shape[2])).T
    return NodeSphereForces(
        node_force=node_force,
        sphere_force=sphere_force,
        sphere_torque=sphere_torque,
        spring=new_spring,
        normal_force=normal_force,
        overlap=overlap,
        slot_force=to_rows(force_on_node),
        branch=to_rows(branch),
    )
