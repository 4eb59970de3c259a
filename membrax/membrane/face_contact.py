"""Sphere–membrane contact on the mesh's faces, edges and vertices (the closest point of the mid-surface).

Contract. :func:`feature_slots` turns the node–sphere candidate table (:mod:`membrax.membrane.candidates`)
into candidate tables of the mesh's three kinds of feature: each triangle, each interior edge and each
interior node against the spheres any of its nodes has as candidates. :func:`face_contact_energy` is the
normal penalty energy of those contacts and :func:`face_contact_forces` the forces of one step (normal
spring = −grad of the energy, Coulomb-capped tangential spring as an explicit force), on the nodes and on
the spheres, with the carried springs. Pure functions of the kinematics and the tables: jittable,
vmappable, the energy differentiable in positions, radii and thickness.

Why. Node contact (:mod:`membrax.membrane.contact`) lets only the nodes meet the spheres, so a deeply
indented sheet can pass between three nodes through the sphere behind them. Here a sphere meets the
membrane's mid-surface wherever it is closest: the mesh is a surface, not a cloud of points.

The law (Cundall & Strack 1979, linear, as the node law, with the contact point x_p on the mid-surface):

- the closest point x_p of the sphere centre x_i on a feature: the foot of the perpendicular on a
  triangle's plane, on an edge's line, or the node itself; the overlap δ = R_i + t_m/2 − |x_i − x_p|,
  energy U = ½ k_n max(δ, 0)², force on the sphere k_n δ n, n = (x_i − x_p)/|x_i − x_p|;
- the membrane's share of that force goes to the feature's nodes by the barycentric weights w_k of x_p
  (face: the three area coordinates; edge: 1 − τ and τ; node: 1). This is −∂U/∂x_k exactly: the
  distance from x_i to a plane (line) changes with a vertex's position as −w_k n (a rotation about the
  foot point changes it to second order only), so the forces are conservative and sum to zero;
- which feature: each feature counts only where the centre lies in its Voronoi region on the mesh, so a
  sphere over a flat patch has exactly one contact (and a sphere that the sheet wraps has one per face
  it touches). A face counts where the foot of the perpendicular lies inside the triangle (all w_k > 0);
  an interior edge where 0 < τ < 1 and the centre lies beyond the edge as seen in both of its triangles
  (the in-plane normal m_k of the edge in triangle k, pointing away from the opposite vertex:
  (x_i − x_u)·m_k ≥ 0 for both); an interior node where, on every edge (v, w) it belongs to,
  (x_i − x_v)·(x_w − x_v) ≤ 0. On the boundaries between regions the two distances are equal (the
  foot of the perpendicular lies on the shared edge or node), so the energy is continuous; a centre on
  a boundary belongs to one region only: a face's is open (w_k > β), an edge's is open at its ends
  (β < τ < 1 − β) and closed toward its faces, a node's is closed (τ ≤ β along each of its edges), with a
  band β of round-off's width (:func:`_tie_band`), so a sphere over a flat patch has exactly one contact,
  over a face, an edge or a node, even at a lattice's symmetric places;
- tangential: an incremental spring per (feature, candidate) slot, advanced by
  :func:`membrax.spheres.contact.tangential_spring_update` with the slip velocity of x_p on the membrane
  (Σ w_k v_k) relative to the sphere's material point under it (v_i + ω_i × b, b = x_p − x_i), capped at
  μ F_n; the torque on the sphere is b × F_sphere (the node law's arm, so angular momentum is conserved).
  A spring lives in its feature's slot: when the closest point moves to the next feature the spring
  starts again from zero there (a tangential force drop of at most μ F_n at that step).

Left out: the mesh's boundary edges and boundary nodes (the clamped end rings of a specimen's membrane,
the sides of a flat sheet) have no edge or node contact; the triangles next to them have their face
contact. Near a saddle-shaped node the regions of its edges and of the node itself may overlap or leave a
sliver (the regions are exact for a convex or a concave patch).

Kernel. On the CPU, in float32 or float64, :func:`face_contact_forces` runs a compiled kernel
(``membrax/native/face_contact.cc``, :mod:`membrax.native`) that skips the empty slots (about 70 % of
665,000 at paper size) and the spheres out of a feature's reach, applies the law to the others one feature
at a time, and sums the node shares per feature and then per node through the mesh's incidence tables,
without atomics, in the order of the JAX law below (:func:`reference_face_contact_forces`), which stays the
definition: the tests hold the kernel to it to round-off, and it runs on other backends. Reverse mode on
the CPU runs a backward kernel (``face_contact_backward``: each touching slot's ū·(outputs) on dual
numbers, once per input of the slot) that the tests hold to ``jax.vjp`` of the JAX law.

Layout: positions are rows (n, 3); per-slot quantities are component-first (3, F, M) (:mod:`membrax.vector`).
SI units: m, s, N, N·m.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from membrax import native, pytree
from membrax.fusion import materialize
from membrax.membrane import _kernels
from membrax.membrane.candidates import remap_node_history
from membrax.membrane.contact import ContactNodes, ContactSpheres, MembraneContactParams
from membrax.membrane.mesh import MembraneMesh
from membrax.spheres.contact import normal_energy, tangential_spring_update
from membrax.vector import cross, dot, safe_norm, safe_normalize, scale, select

__all__ = [
    "FEATURE_KINDS",
    "FaceContactForces",
    "FeatureContactState",
    "FeatureSlots",
    "carry_springs",
    "widen",
    "face_contact_energy",
    "face_contact_forces",
    "face_contact_reference",
    "reference_face_contact_forces",
    "runs_kernel",
    "feature_slots",
    "closest_point_weights",
    "interior_nodes",
    "longest_edge",
    "MeshNeighbours",
    "mesh_neighbours",
    "zero_springs",
]

#: The features a sphere meets, in the order of :class:`FeatureSlots` and of the springs.
FEATURE_KINDS = ("face", "edge", "node")


@pytree.dataclass
class FeatureSlots:
    """Candidate spheres of each feature (int ids padded with the sphere count N; distinct within a row).

    Attributes:
      face: (T, 3K) the spheres of a triangle's three nodes' candidate rows, repeats padded.
      edge: (E, 2K) the spheres of an interior edge's two nodes' rows, repeats padded.
      node: (n_nodes, K) the node's own row, padded where the node is on the mesh's boundary.
    """

    face: jnp.ndarray
    edge: jnp.ndarray
    node: jnp.ndarray


class FaceContactForces(NamedTuple):
    """Result of :func:`face_contact_forces`.

    Attributes:
      node_force: (n_nodes, 3) force on each node, N.
      sphere_force: (N, 3) force on each sphere, N.
      sphere_torque: (N, 3) torque on each sphere about its centre, N·m.
      spring: tuple of the updated springs per feature kind (:data:`FEATURE_KINDS`), each (3, F, M), N
        (force on the membrane).
      normal_force: tuple of |F_n| per slot, (F, M) each, N (0 where not touching).
      slot_force: (1, S, 3) force of the sphere on the membrane per slot of all kinds, N (zero if none),
        laid out as the node law's (n_nodes, K, 3) for the Love–Weber sum.
      branch: (1, S, 3) b = x_p − x_sphere per slot, m.
      overlap: (S,) δ per slot, m (−1 where the slot is padded or out of its feature's region).
      slots: the :class:`FeatureSlots` these forces are of.
    """

    node_force: jnp.ndarray
    sphere_force: jnp.ndarray
    sphere_torque: jnp.ndarray
    spring: tuple
    normal_force: tuple
    slot_force: jnp.ndarray
    branch: jnp.ndarray
    overlap: jnp.ndarray
    slots: FeatureSlots


class MeshNeighbours(NamedTuple):
    """What the node contacts read of the mesh's topology, built once (:func:`mesh_neighbours`).

    Fixed for a mesh: a stepping caller builds it with the step and passes it to :func:`feature_slots` and
    :func:`face_contact_forces`.

    Attributes:
      ids: (n_nodes, K_h) each node's neighbours along interior edges, padded with n_nodes.
      mask: (n_nodes, K_h) bool, True where ``ids`` holds a neighbour.
      interior: (n_nodes,) bool, the nodes off the mesh's boundary (:func:`interior_nodes`).
    """

    ids: jnp.ndarray
    mask: jnp.ndarray
    interior: jnp.ndarray


# ----------------------------------------------------------------------------------------------- tables


def _first_occurrences(ids, pad):
    """``ids`` (F, M) with every repeat of an id within a row (after its first place) set to ``pad``."""
    earlier = jnp.tril(jnp.ones((ids.shape[1], ids.shape[1]), dtype=bool), k=-1)  # [j, i]: i < j
    repeat = jnp.any((ids[:, :, None] == ids[:, None, :]) & earlier[None], axis=-1)
    return jnp.where(repeat | (ids >= pad), pad, ids)


def _node_neighbours(mesh: MembraneMesh):
    """Each node's neighbours along interior edges, (n_nodes, K_h) padded with n_nodes, and its mask."""
    num_edges = mesh.edges.shape[0]
    entry = mesh.hinge_incidence  # where the node stands in hinge_index: starts, ends, opposites
    on_edge = entry < 2 * num_edges
    safe = jnp.where(on_edge, entry, 0)
    other_end = jnp.where(safe < num_edges, mesh.edges[safe % num_edges, 1], mesh.edges[safe % num_edges, 0])
    return jnp.where(on_edge, other_end, mesh.num_nodes), on_edge


def interior_nodes(mesh: MembraneMesh):
    """(n_nodes,) bool: nodes off the mesh's boundary (as many interior edges as triangles around them)."""
    _, on_edge = _node_neighbours(mesh)
    triangles_around = jnp.sum(mesh.corner_incidence < 3 * mesh.num_triangles, axis=1)
    return jnp.sum(on_edge, axis=1) == triangles_around


def mesh_neighbours(mesh: MembraneMesh) -> MeshNeighbours:
    """The :class:`MeshNeighbours` of ``mesh``: its nodes' neighbours and its interior nodes (jittable)."""
    ids, mask = _node_neighbours(mesh)
    return MeshNeighbours(ids=ids, mask=mask, interior=interior_nodes(mesh))


def feature_slots(
    mesh: MembraneMesh, candidates, num_spheres: int, neighbours: MeshNeighbours | None = None
) -> FeatureSlots:
    """The features' candidate tables from the node–sphere table ``candidates`` (n_nodes, K), padded N.

    A sphere the law could meet on a feature lies within reach of one of its nodes (the node table's
    skin covers the mesh's edge length), so the union of the nodes' rows holds every such sphere.
    ``neighbours``: the mesh's :func:`mesh_neighbours`, if already built (else built here).
    """
    interior = (mesh_neighbours(mesh) if neighbours is None else neighbours).interior
    face = candidates[mesh.triangles].reshape(mesh.num_triangles, -1)
    edge = candidates[mesh.edges].reshape(mesh.edges.shape[0], -1)
    node = jnp.where(interior[:, None], candidates, num_spheres)
    return FeatureSlots(
        face=_first_occurrences(face, num_spheres),
        edge=_first_occurrences(edge, num_spheres),
        node=node,
    )


# -------------------------------------------------------------------------------------------- geometry


def _rows(position, index):
    """Component-first gather: (3, *index.shape) rows of ``position`` (n, 3)."""
    return jnp.moveaxis(position[index], -1, 0)


def closest_point_weights(kind: str, corners, centre, mesh_extras=None):
    """Weights of the closest point on a feature and whether the centre lies in the feature's region.

    Args:
      kind: ``"face"``, ``"edge"`` or ``"node"``.
      corners: the feature's node positions, component-first: face (a, b, c), edge (u, v, o₁, o₂) (the
        opposite vertices of its two triangles), node (v,); each (3, F, 1), broadcasting against ``centre``.
      centre: sphere centres (3, F, M).
      mesh_extras: for ``"node"``, the neighbours' positions (3, F, 1, V) and their mask (F, 1, V).

    Returns:
      (weights, in_region): weights a tuple of (F, M) arrays, one per node of the feature (they sum to
      1 and place the closest point x_p = Σ w_k x_k), and in_region (F, M) bool (module docstring).
    """
    band = _tie_band(centre.dtype)
    if kind == "face":
        a, b, c = corners
        normal = cross(b - a, c - a)
        twice_area = safe_norm(normal)
        unit = scale(1.0 / jnp.where(twice_area > 0.0, twice_area, 1.0), normal)
        inverse_area = 1.0 / jnp.where(twice_area > 0.0, twice_area, 1.0)
        # A feature's own geometry serves all its slots: stored once per feature, where XLA-CPU would
        # evaluate it again in each per-slot, per-component consumer (membrax.fusion); the same bits.
        twice_area, unit, inverse_area = materialize(twice_area, unit, inverse_area)
        foot = centre - scale(dot(centre - a, unit), unit)
        weight_a = dot(cross(c - b, foot - b), unit) * inverse_area
        weight_b = dot(cross(a - c, foot - c), unit) * inverse_area
        weight_c = 1.0 - weight_a - weight_b
        inside = (weight_a > band) & (weight_b > band) & (weight_c > band) & (twice_area > 0.0)
        return (weight_a, weight_b, weight_c), inside
    if kind == "edge":
        u, v, opposite_1, opposite_2 = corners
        along = v - u
        length_squared = dot(along, along)
        safe_length_squared = jnp.where(length_squared > 0.0, length_squared, 1.0)
        along, length_squared, safe_length_squared = materialize(along, length_squared, safe_length_squared)
        fraction = dot(centre - u, along) / safe_length_squared
        in_region = (fraction > band) & (fraction < 1.0 - band) & (length_squared > 0.0)
        for opposite in (opposite_1, opposite_2):
            # The opposite vertex's area coordinate of the centre's foot: ≤ 0 beyond the edge.
            inward = (opposite - u) - scale(dot(opposite - u, along) / safe_length_squared, along)
            height_squared = dot(inward, inward)
            inward, safe_height_squared = materialize(
                inward, jnp.where(height_squared > 0.0, height_squared, 1.0)
            )
            coordinate = dot(centre - u, inward) / safe_height_squared
            in_region = in_region & (coordinate <= band)
        return (1.0 - fraction, fraction), in_region
    if kind == "node":
        (vertex,) = corners
        neighbours, mask = mesh_extras
        spoke = neighbours - vertex[..., None]
        spoke_squared = dot(spoke, spoke)
        spoke, spoke_squared = materialize(spoke, spoke_squared)
        # The centre's place along each edge from the node, τ: the node's region where τ ≤ 0 on every one.
        fraction = dot((centre - vertex)[..., None], spoke) / jnp.where(
            spoke_squared > 0.0, spoke_squared, 1.0
        )
        in_region = jnp.all((fraction <= band) | ~mask, axis=-1)
        return (jnp.ones_like(in_region, dtype=centre.dtype),), in_region
    raise ValueError(f"kind must be one of {FEATURE_KINDS}, got {kind!r}")


def _tie_band(dtype) -> float:
    """The band, in the features' own coordinates (w_k, τ), within which a tie goes to the lower feature.

    √ε of the dtype: 1.5e-8 in float64, 3.5e-4 in float32 (0.15 nm and 3.5 µm on a 10 mm mesh).

    A centre exactly over an edge or a node (a lattice's symmetric places) has coordinates of 0 that the two
    sides compute differently to round-off, which would give it two contacts or none; within the band it
    has the edge's (or the node's) alone, whose distance differs from the face's by O(band²).
    """
    return math.sqrt(float(jnp.finfo(dtype).eps))


def _feature_nodes(mesh: MembraneMesh, kind: str):
    """The node ids (F, k) of each feature of ``kind`` whose positions :func:`closest_point_weights` takes."""
    if kind == "face":
        return mesh.triangles
    if kind == "edge":
        return jnp.concatenate([mesh.edges, mesh.edge_opposite], axis=1)
    return jnp.arange(mesh.num_nodes)[:, None]


def _slot_geometry(kind, node_position, sphere_table, mesh, slots, membrane_thickness, neighbours=None):
    """Per slot of ``kind``: the contact point, weights, node ids, branch, reach and validity.

    ``sphere_table`` (N, C): each sphere's position in its first three columns, its radius in the last,
    whatever else the caller reads per slot between them: gathered once, in one row per slot (a gather's
    cost on XLA-CPU is per row), and returned as ``per_slot`` (C, F, M) with the other results.
    """
    num_spheres = sphere_table.shape[0]
    ids = getattr(slots, kind)
    valid = ids < num_spheres
    safe_ids = jnp.where(valid, ids, 0)
    per_slot = _rows(sphere_table, safe_ids)  # (C, F, M)
    centre = per_slot[:3]
    nodes = _feature_nodes(mesh, kind)
    corners = tuple(_rows(node_position, nodes[:, k])[:, :, None] for k in range(nodes.shape[1]))
    extras = None
    if kind == "node":
        ids, mask = _node_neighbours(mesh) if neighbours is None else (neighbours.ids, neighbours.mask)
        padded = jnp.concatenate([node_position, jnp.zeros((1, 3), node_position.dtype)])
        extras = (_rows(padded, ids)[:, :, None, :], mask[:, None, :])
    weights, in_region = closest_point_weights(kind, corners, centre, extras)
    # Stored once: XLA-CPU would otherwise evaluate the region test again in each consumer (membrax.fusion).
    *weights, in_region = materialize(*weights, in_region)
    weights = tuple(weights)
    contact_point = sum(scale(w, x) for w, x in zip(weights, corners, strict=False))
    branch = contact_point - centre  # from the sphere centre to the membrane point (the node law's b)
    reach = per_slot[-1] + 0.5 * membrane_thickness
    return weights, nodes[:, : len(weights)], branch, reach, valid & in_region, safe_ids, per_slot


def _node_sums(kind, shares, mesh: MembraneMesh):
    """(n_nodes, 3): each node's shares of the features of ``kind`` it belongs to, summed.

    ``shares`` holds one (3, F) array per node of a feature (:func:`_feature_nodes`' columns, the first
    ``len(shares)``). A face's and an edge's shares are gathered through the mesh's incidence tables
    (``corner_incidence``, ``hinge_incidence``): each node sums its own few rows, where a scatter would
    add one row at a time; a node's share is its own.
    """
    if kind == "node":
        return shares[0].T
    if kind == "face":
        # corner_index: the triangles' first corners, then their second and third.
        rows, incidence = jnp.concatenate(shares, axis=1).T, mesh.corner_incidence
    else:
        # hinge_index: the edges' starts, their ends, then the opposite vertices (which get no share).
        rows = jnp.concatenate(shares, axis=1).T
        incidence = jnp.where(mesh.hinge_incidence < rows.shape[0], mesh.hinge_incidence, rows.shape[0])
    padded = jnp.concatenate([rows, jnp.zeros((1, 3), rows.dtype)])
    return _slot_sum(jnp.moveaxis(padded[incidence], 1, -1))


def _slot_sum(values):
    """``values`` (..., M) summed over the last (short) axis, left to right.

    Written as M − 1 adds, which XLA-CPU fuses into one loop: its reduction over a short axis ran several
    times slower (paper-size mesh, float32).
    """
    total = values[..., 0]
    for m in range(1, values.shape[-1]):
        total = total + values[..., m]
    return total


def _slot_contact(branch, reach, active_slot, normal_stiffness):
    """The law's normal part at each slot: (normal n_m, overlap δ, touching, normal force k_n δ).

    δ = reach − |b| at an active slot (−1 at the others); a slot touches where δ > 0 and |b| > 0.
    """
    normal, distance = safe_normalize(branch)
    overlap = jnp.where(active_slot, reach - distance, -1.0)
    touching = (overlap > 0.0) & (distance > 0.0)
    normal_force = jnp.where(touching, normal_stiffness * overlap, 0.0)
    return normal, overlap, touching, normal_force


def _slot_rows(on_membrane, branch, overlap):
    """One kind's per-slot fields in slot order: membrane force and branch as (slots, 3) rows, the overlap."""
    return (
        jnp.moveaxis(on_membrane, 0, -1).reshape(-1, 3),
        jnp.moveaxis(branch, 0, -1).reshape(-1, 3),
        overlap.reshape(-1),
    )


def _with_slot_fields(
    node_force, sphere_force, sphere_torque, springs, normal_forces, slot_rows, slots
) -> FaceContactForces:
    """The :class:`FaceContactForces` of the summed outputs and each kind's :func:`_slot_rows`, in order."""
    slot_force, branch, overlap = (jnp.concatenate(parts) for parts in zip(*slot_rows, strict=True))
    return FaceContactForces(
        node_force=node_force,
        sphere_force=sphere_force,
        sphere_torque=sphere_torque,
        spring=tuple(springs),
        normal_force=tuple(normal_forces),
        slot_force=slot_force[None],
        branch=branch[None],
        overlap=overlap,
        slots=slots,
    )


def face_contact_energy(
    node_position,
    sphere_position,
    sphere_radius,
    mesh: MembraneMesh,
    slots: FeatureSlots,
    normal_stiffness,
    membrane_thickness,
    neighbours: MeshNeighbours | None = None,
):
    """Normal penalty energy of the feature contacts, U = Σ ½ k_n max(δ, 0)², J (module docstring).

    The regions are decided on the current positions and held fixed under differentiation (they are
    piecewise constant), so −grad U is the normal force of :func:`face_contact_forces`. ``neighbours``:
    the mesh's :func:`mesh_neighbours`, if already built.
    """
    total = 0.0
    sphere_table = jnp.concatenate([sphere_position, sphere_radius[:, None]], axis=1)
    for kind in FEATURE_KINDS:
        _, _, branch, reach, active, _, _ = _slot_geometry(
            kind, node_position, sphere_table, mesh, slots, membrane_thickness, neighbours
        )
        overlap = jnp.where(active, reach - safe_norm(branch), -1.0)
        total = total + jnp.sum(normal_energy(overlap, normal_stiffness))
    return total


# --------------------------------------------------------------------------------------------- the law


def face_contact_forces(
    nodes: ContactNodes,
    spheres: ContactSpheres,
    mesh: MembraneMesh,
    slots: FeatureSlots,
    springs,
    dt,
    params: MembraneContactParams,
    membrane_thickness,
    neighbours: MeshNeighbours | None = None,
) -> FaceContactForces:
    """Feature contact forces, torques and springs for one step (law in the module docstring).

    F_membrane = k_n δ n_m + s',  n_m = b/|b| (from the sphere centre to x_p),  F_sphere = −F_membrane,
    τ_sphere = b × F_sphere, node k of the feature gets w_k F_membrane;
    s' = tangential_spring_update(s, n_m, Π_t[Σ w_k v_k − v_i − ω_i × b], Δt, k_t, μ, k_n δ, δ > 0).

    Args:
      nodes: positions and velocities of the nodes (:class:`~membrax.membrane.contact.ContactNodes`).
      spheres: the spheres (:class:`~membrax.membrane.contact.ContactSpheres`).
      mesh: the membrane.
      slots: :func:`feature_slots`.
      springs: the carried springs, a tuple (3, F, M) per kind of :data:`FEATURE_KINDS`.
      dt: time step, s.
      params: k_n, k_t and μ (:class:`~membrax.membrane.contact.MembraneContactParams`).
      membrane_thickness: t_m, m.
      neighbours: the mesh's :func:`mesh_neighbours`, built once by a caller that steps (else built here).

    On the CPU, in float32 or float64, the forces, torques and springs come from a compiled kernel
    (:mod:`membrax.native`, ``face_contact.cc``) that skips the empty slots and applies this law to the
    others, one feature at a time, summing the node shares per feature and then per node without atomics. The
    JAX law (:func:`reference_face_contact_forces`) is the definition the tests hold the kernel to (agreement
    to round-off) and the law used elsewhere; reverse mode runs a compiled backward kernel
    (``face_contact_backward``) that gives the JAX law's derivatives to round-off. The per-slot fields (normal
    forces, slot forces, branches, overlaps) are then computed from the geometry in JAX; XLA drops those a
    caller does not read.

    Returns:
      A :class:`FaceContactForces`.
    """
    springs = tuple(springs)
    if not runs_kernel(jnp.asarray(nodes.position).dtype):
        return reference_face_contact_forces(
            nodes, spheres, mesh, slots, springs, dt, params, membrane_thickness, neighbours
        )
    neighbours = mesh_neighbours(mesh) if neighbours is None else neighbours
    args = (nodes, spheres, mesh, slots, springs, dt, params, membrane_thickness, neighbours)
    node_force, sphere_force, sphere_torque, *new_springs = _compiled_face_contact_forces(*args)
    normal_forces, slot_rows = [], []
    sphere_table = jnp.concatenate([spheres.position, spheres.radius[:, None]], axis=1)
    for kind, spring in zip(FEATURE_KINDS, new_springs, strict=True):
        _, _, branch, reach, active_slot, _, _ = _slot_geometry(
            kind, nodes.position, sphere_table, mesh, slots, membrane_thickness, neighbours
        )
        normal, overlap, touching, normal_force = _slot_contact(
            branch, reach, active_slot, params.normal_stiffness
        )
        on_membrane = select(touching, scale(normal_force, normal) + spring)
        normal_forces.append(normal_force)
        slot_rows.append(_slot_rows(on_membrane, branch, overlap))
    return _with_slot_fields(
        node_force, sphere_force, sphere_torque, new_springs, normal_forces, slot_rows, slots
    )


def runs_kernel(dtype) -> bool:
    """Whether :func:`face_contact_forces` calls the compiled kernel for positions of ``dtype``.

    :func:`membrax.native.enabled_for` (float32 or float64, the kernels built); the kernel then runs on the
    CPU backend and the JAX law elsewhere. A test may replace this function to run the JAX law everywhere
    (or call :func:`reference_face_contact_forces` directly).
    """
    return native.enabled_for(dtype)


def face_contact_reference(*args):
    """The six outputs of the compiled face contact kernel (membrane/_kernels.py), from the JAX law."""
    result = reference_face_contact_forces(*args)
    return (result.node_force, result.sphere_force, result.sphere_torque, *result.spring)


_compiled_face_contact_forces = native.with_reference(
    _kernels.face_contact_kernel, face_contact_reference, _kernels.face_contact_backward
)


def reference_face_contact_forces(
    nodes, spheres, mesh, slots, springs, dt, params, membrane_thickness, neighbours=None
) -> FaceContactForces:
    """:func:`face_contact_forces` in JAX: the definition of the law, and its derivatives (any backend).

    Its arguments are those of :func:`face_contact_forces`.
    """
    num_nodes, num_spheres = nodes.position.shape[0], spheres.position.shape[0]
    dtype = nodes.position.dtype
    node_force = jnp.zeros((num_nodes, 3), dtype)
    sphere_load = jnp.zeros((num_spheres + 1, 6), dtype)  # force, then torque; a padding row last
    new_springs, normal_forces, slot_rows = [], [], []
    # What each slot reads of its sphere, gathered in one row: position, velocity, ω, radius.
    sphere_table = jnp.concatenate(
        [spheres.position, spheres.velocity, spheres.angular_velocity, spheres.radius[:, None]], axis=1
    )
    for kind, spring in zip(FEATURE_KINDS, springs, strict=True):
        weights, feature_nodes, branch, reach, active_slot, safe_ids, per_slot = _slot_geometry(
            kind, nodes.position, sphere_table, mesh, slots, membrane_thickness, neighbours
        )
        normal, overlap, touching, normal_force = _slot_contact(
            branch, reach, active_slot, params.normal_stiffness
        )
        branch, normal, overlap, touching, normal_force = materialize(
            branch, normal, overlap, touching, normal_force
        )
        membrane_velocity = sum(
            scale(w, _rows(nodes.velocity, feature_nodes[:, k])[:, :, None]) for k, w in enumerate(weights)
        )
        sphere_velocity = per_slot[3:6] + cross(per_slot[6:9], branch)
        relative = materialize(membrane_velocity - sphere_velocity)  # else gathered again per use
        tangential = materialize(relative - scale(dot(relative, normal), normal))
        spring = tangential_spring_update(
            spring,
            normal,
            tangential,
            dt,
            params.tangential_stiffness,
            params.friction_coefficient,
            normal_force,
            touching,
            stored=True,
        )
        spring = materialize(spring)
        on_membrane = materialize(select(touching, scale(normal_force, normal) + spring))  # (3, F, M)
        # Force and torque in one scatter (a serial loop over the slots on XLA-CPU, whose cost is per row).
        sphere_index = jnp.where(touching, safe_ids, num_spheres).reshape(-1)
        torque = cross(branch, -on_membrane)
        on_sphere = jnp.moveaxis(jnp.concatenate([-on_membrane, torque]), 0, -1)  # (F, M, 6)
        sphere_load = sphere_load.at[sphere_index].add(on_sphere.reshape(-1, 6))
        # Each node's share summed over its feature's slots first, then over its features (_node_sums):
        # one row per feature node instead of one scatter row per slot.
        shares = tuple(_slot_sum(scale(w, on_membrane)) for w in weights)  # (3, F) each
        node_force = node_force + _node_sums(kind, shares, mesh)
        new_springs.append(spring)
        normal_forces.append(normal_force)
        slot_rows.append(_slot_rows(on_membrane, branch, overlap))
    return _with_slot_fields(
        node_force,
        sphere_load[:num_spheres, :3],
        sphere_load[:num_spheres, 3:],
        new_springs,
        normal_forces,
        slot_rows,
        slots,
    )


def zero_springs(slots: FeatureSlots, dtype):
    """Springs of no contact for ``slots``: a (3, F, M) zero array per kind of :data:`FEATURE_KINDS`."""
    return tuple(jnp.zeros((3, *getattr(slots, kind).shape), dtype) for kind in FEATURE_KINDS)


@pytree.dataclass
class FeatureContactState:
    """What a step carries of the feature contacts: the slots' sphere ids and their springs.

    Attributes:
      slots: the :class:`FeatureSlots` the springs belong to (those of the step that made them).
      spring: a (3, F, M) spring per kind of :data:`FEATURE_KINDS`, N.
    """

    slots: FeatureSlots
    spring: tuple


def carry_springs(state: FeatureContactState, slots: FeatureSlots, num_spheres: int) -> tuple:
    """The springs of ``state`` moved onto ``slots`` by sphere id (zero for a pair new to a feature).

    A step reads its slots from the node table (:func:`feature_slots`), which is rebuilt now and then and
    grown on overflow; carrying by id keeps a (feature, sphere) pair's spring through both. Between
    rebuilds the slots are the same and the springs pass as they are (the carry is skipped).
    """

    def carry(springs):
        return tuple(
            remap_node_history(getattr(state.slots, kind), getattr(slots, kind), spring, num_spheres, True)
            for kind, spring in zip(FEATURE_KINDS, springs, strict=True)
        )

    if any(getattr(state.slots, k).shape != getattr(slots, k).shape for k in FEATURE_KINDS):
        return carry(tuple(state.spring))  # a table of another width (narrowed): the slots differ
    same = jnp.all(jnp.stack([jnp.all(getattr(state.slots, k) == getattr(slots, k)) for k in FEATURE_KINDS]))
    return jax.lax.cond(same, lambda springs: springs, carry, tuple(state.spring))


def longest_edge(mesh: MembraneMesh) -> float:
    """The mesh's longest rest edge, m (host; the node table's extra reach for feature contacts).

    Any point of a triangle lies within its longest edge of its nearest vertex, so a node table that
    reaches this much further lists every sphere within reach of the triangles around its nodes while no
    edge stretches beyond √3 of its rest length (the farthest point from all three vertices of an
    equilateral triangle of edge a is its centroid, a/√3 away).
    """
    import numpy as np

    position = np.asarray(mesh.reference_position, dtype=np.float64)
    triangles = np.asarray(mesh.triangles)
    corners = position[triangles]
    edges = corners - np.roll(corners, 1, axis=1)
    return float(np.sqrt(np.max(np.sum(edges * edges, axis=-1))))


def widen(state: FeatureContactState, capacity: int, num_spheres: int) -> FeatureContactState:
    """``state`` padded to the slot widths of a node table of ``capacity`` K (3K, 2K, K).

    The new slots are empty and their springs zero; after a node table grows, the next step's
    :func:`carry_springs` moves the springs by id.
    """
    widths = {"face": 3 * capacity, "edge": 2 * capacity, "node": capacity}
    slots, springs = {}, []
    for kind, spring in zip(FEATURE_KINDS, state.spring, strict=True):
        ids = getattr(state.slots, kind)
        extra = widths[kind] - ids.shape[1]
        if extra < 0:
            raise ValueError(f"widen: the {kind} slots are {ids.shape[1]} wide, more than {widths[kind]}.")
        slots[kind] = jnp.pad(ids, ((0, 0), (0, extra)), constant_values=num_spheres)
        springs.append(jnp.pad(spring, ((0, 0), (0, 0), (0, extra))))
    return FeatureContactState(slots=FeatureSlots(**slots), spring=tuple(springs))
