"""Latex membrane as a triangulated thin shell: its topology, rest geometry and kinematics.

Contract. A :class:`MembraneMesh` is built once on the host (numpy, deterministic) and holds the
connectivity and every rest-state quantity the membrane's laws need. The kinematics are pure ``jnp``
functions of the current node positions (N, 3): the triangles' Green–Lagrange strains and triple products
(:func:`triangle_invariants`), the hinges' bending angles (:func:`dihedral_angle`), the band's area and the
volume it encloses with two flat caps (:func:`enclosed_volume`). They are jittable and differentiable; the
energies and forces that read them are :mod:`membrax.membrane.energies`. SI units throughout: m, m², m³.

The membrane is a band wrapping the specimen: rings of nodes stacked along z, the angle periodic, the
bottom and top rings meant to be clamped to the platens (O-rings). Triangles are near equilateral and
oriented so that (x₂ − x₁) × (x₃ − x₁) points away from the axis.

Layout and speed: nodes are rows of an (N, 3) array; per-triangle and per-edge quantities gather rows and
are then handled component-first (3, M) with :mod:`membrax.vector`, because XLA's CPU backend reduces over
a size-3 axis much more slowly than it adds three rows. All 2 × 2 algebra is written out.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.fusion import materialize
from membrax.validation import check_range
from membrax.vector import cross, dot, scale

__all__ = [
    "MembraneMesh",
    "cylinder_mesh",
    "prism_mesh",
    "flat_mesh",
    "offset_polygon",
    "rounded_offset_path",
    "gather_components",
    "gathered_corners",
    "gathered_hinges",
    "triangle_invariants",
    "green_strain",
    "dihedral_angle",
    "surface_area",
    "inner_volume",
    "band_volume",
    "cap_volume",
    "enclosed_volume",
    "enclosed_volume_of",
    "free_node_mask",
]


@pytree.dataclass
class MembraneMesh:
    """A triangulated membrane and its rest state (see the module docstring).

    Attributes:
      reference_position: (N, 3) rest node positions, m.
      triangles: (T, 3) int32 node indices, outward oriented.
      bottom_ring: (n_θ,) int32 nodes of the lowest ring, in counter-clockwise order seen from +z.
      top_ring: (n_θ,) int32 nodes of the highest ring, same order.
      edges: (E, 2) int32 end nodes (a, b) of the interior edges; (a, b) is the order in which the first
        adjacent triangle runs along the edge.
      edge_opposite: (E, 2) int32 the vertex opposite the edge in the first triangle (a, b, c) and in the
        second triangle (b, a, d).
      reference_inverse: (T, 2, 2) D_m⁻¹, inverse of the rest edge matrix in the triangle's own frame, 1/m.
      reference_area: (T,) rest triangle areas A₀, m².
      rest_dihedral: (E,) rest bending angles θ̄, rad (signed by the triangles' orientation; only θ − θ̄
        enters the energy).
      edge_weight: (E,) 3 |ē|² / Ā_e of Discrete Shells, Ā_e the summed rest area of the two triangles.
      corner_index: (3T,) int32 the triangles' corners, first corners of all triangles, then second, third.
      corner_incidence: (N, K_c) int32 where each node appears in ``corner_index``, padded with 3T.
      hinge_index: (4E,) int32 the hinge vertices: edge starts, edge ends, first and second opposites.
      hinge_incidence: (N, K_h) int32 where each node appears in ``hinge_index``, padded with 4E.
    """

    reference_position: jnp.ndarray
    triangles: jnp.ndarray
    bottom_ring: jnp.ndarray
    top_ring: jnp.ndarray
    edges: jnp.ndarray
    edge_opposite: jnp.ndarray
    reference_inverse: jnp.ndarray
    reference_area: jnp.ndarray
    rest_dihedral: jnp.ndarray
    edge_weight: jnp.ndarray
    corner_index: jnp.ndarray
    corner_incidence: jnp.ndarray
    hinge_index: jnp.ndarray
    hinge_incidence: jnp.ndarray

    @property
    def num_nodes(self) -> int:
        """N."""
        return self.reference_position.shape[0]

    @property
    def num_triangles(self) -> int:
        """T."""
        return self.triangles.shape[0]


# ----------------------------------------------------------------------------------------------------------
# Mesh construction (host, numpy)
# ----------------------------------------------------------------------------------------------------------


def _band_triangles(num_columns: int, num_rows: int, periodic: bool) -> np.ndarray:
    """Triangles of a band of ``num_rows`` rows of nodes; row j is offset by half a column when j is odd.

    Node (j, i) has index j * nodes_per_row + i; a periodic band has ``num_columns`` nodes per row and wraps,
    an open one has ``num_columns + 1``. With u along the row and v along the stack, every triangle runs
    counter-clockwise in (u, v), so its normal is e_u × e_v (outward for a cylinder, +z for a flat sheet).
    """
    per_row = num_columns if periodic else num_columns + 1
    i = np.arange(num_columns)
    right = (i + 1) % per_row
    triangles = []
    for j in range(num_rows - 1):
        low, up = j * per_row, (j + 1) * per_row
        if j % 2 == 0:  # upper row shifted by +½: node U_i sits above the middle of L_i L_{i+1}
            triangles.append(np.stack([low + i, low + right, up + i], axis=1))
            triangles.append(np.stack([low + right, up + right, up + i], axis=1))
        else:  # lower row shifted by +½: node L_i sits below the middle of U_i U_{i+1}
            triangles.append(np.stack([low + i, low + right, up + right], axis=1))
            triangles.append(np.stack([low + i, up + right, up + i], axis=1))
    return np.concatenate(triangles).astype(np.int32)


def _interior_edges(triangles: np.ndarray):
    """Interior edges (E, 2) and their opposite vertices (E, 2), in a deterministic order."""
    first = {}
    edges, opposite = [], []
    for t, (a, b, c) in enumerate(triangles.tolist()):
        for p, q, r in ((a, b, c), (b, c, a), (c, a, b)):
            key = (min(p, q), max(p, q))
            if key in first:
                p0, q0, r0 = first.pop(key)
                if (p0, q0) != (q, p):
                    raise ValueError(f"triangle {t} is not consistently oriented with its neighbour")
                edges.append((p0, q0))
                opposite.append((r0, r))
            else:
                first[key] = (p, q, r)
    return np.asarray(edges, dtype=np.int32).reshape(-1, 2), np.asarray(opposite, dtype=np.int32).reshape(
        -1, 2
    )


def _reference_frames(position: np.ndarray, triangles: np.ndarray):
    """D_m⁻¹ (T, 2, 2) and A₀ (T,) of each rest triangle, in its frame (e₁ along x₂ − x₁, e₂ in-plane)."""
    x1, x2, x3 = (position[triangles[:, k]] for k in range(3))
    edge1, edge2 = x2 - x1, x3 - x1
    length1 = np.linalg.norm(edge1, axis=1)
    u = edge1 / length1[:, None]
    normal = np.cross(edge1, edge2)
    double_area = np.linalg.norm(normal, axis=1)
    if np.any(double_area <= 0.0):
        raise ValueError("degenerate triangle in the reference mesh")
    v = np.cross(normal / double_area[:, None], u)
    matrix = np.zeros((triangles.shape[0], 2, 2))
    matrix[:, 0, 0] = length1
    matrix[:, 0, 1] = np.einsum("ij,ij->i", edge2, u)
    matrix[:, 1, 1] = np.einsum("ij,ij->i", edge2, v)
    return np.linalg.inv(matrix), 0.5 * double_area


def _incidence(index: np.ndarray, num_nodes: int) -> np.ndarray:
    """(num_nodes, K) the slots of ``index`` that hold each node, padded with ``len(index)``."""
    order = np.argsort(index, kind="stable")
    counts = np.bincount(index, minlength=num_nodes)
    rank = np.arange(index.size) - np.repeat(np.cumsum(counts) - counts, counts)
    table = np.full((num_nodes, max(1, int(counts.max(initial=0)))), index.size, dtype=np.int32)
    table[index[order], rank] = order
    return table


def _assemble(position, triangles, bottom_ring, top_ring, dtype) -> MembraneMesh:
    """Compute the rest-state quantities and pack a :class:`MembraneMesh`."""
    position = np.asarray(position, dtype=np.float64)
    edges, opposite = _interior_edges(triangles)
    inverse, area = _reference_frames(position, triangles)
    # rest angle and weight, with the same formulas as the traced code (in float64 on the host)
    corner_index = triangles.T.reshape(-1)
    hinge_index = np.concatenate([edges[:, 0], edges[:, 1], opposite[:, 0], opposite[:, 1]])
    num_nodes = position.shape[0]
    rest = np.asarray(dihedral_angle(position[hinge_index].T))
    triangle_of = {}
    for t, (a, b, c) in enumerate(triangles.tolist()):
        for p, q in ((a, b), (b, c), (c, a)):
            triangle_of.setdefault((min(p, q), max(p, q)), []).append(t)
    pair_area = np.array([area[triangle_of[(min(a, b), max(a, b))]].sum() for a, b in edges.tolist()])
    edge_length_sq = np.sum((position[edges[:, 1]] - position[edges[:, 0]]) ** 2, axis=1)
    dtype = dtype or jnp.result_type(float)
    return MembraneMesh(
        reference_position=jnp.asarray(position, dtype=dtype),
        triangles=jnp.asarray(triangles, dtype=jnp.int32),
        bottom_ring=jnp.asarray(bottom_ring, dtype=jnp.int32),
        top_ring=jnp.asarray(top_ring, dtype=jnp.int32),
        edges=jnp.asarray(edges, dtype=jnp.int32),
        edge_opposite=jnp.asarray(opposite, dtype=jnp.int32),
        reference_inverse=jnp.asarray(inverse, dtype=dtype),
        reference_area=jnp.asarray(area, dtype=dtype),
        rest_dihedral=jnp.asarray(rest, dtype=dtype),
        edge_weight=jnp.asarray(3.0 * edge_length_sq / pair_area, dtype=dtype),
        corner_index=jnp.asarray(corner_index, dtype=jnp.int32),
        corner_incidence=jnp.asarray(_incidence(corner_index, num_nodes)),
        hinge_index=jnp.asarray(hinge_index, dtype=jnp.int32),
        hinge_incidence=jnp.asarray(_incidence(hinge_index, num_nodes)),
    )


def _ring_levels(height: float, target_edge_length: float, z_bottom: float) -> np.ndarray:
    """Ring heights: spacing ≈ target·√3/2 (equilateral rows), adjusted to land on both ends exactly."""
    intervals = max(1, round(height / (target_edge_length * math.sqrt(3.0) / 2.0)))
    return z_bottom + height * np.arange(intervals + 1) / intervals


def _band_mesh(
    point_at, perimeter, height, target_edge_length, z_bottom, dtype, num_around=None
) -> MembraneMesh:
    """Band around a closed curve ``point_at(s)`` (s ∈ [0, 1), counter-clockwise) of length ``perimeter``.

    ``num_around`` (default round(perimeter / target)) fixes n_θ, e.g. to give meshes of several thicknesses
    one topology (:mod:`membrax.sweep`).
    """
    check_range("height", height, lower=0.0, lower_open=True)
    check_range("target_edge_length", target_edge_length, lower=0.0, lower_open=True)
    if num_around is None:
        num_around = max(3, round(perimeter / target_edge_length))
    elif int(num_around) != num_around or num_around < 3:
        raise ValueError(f"num_around must be an integer >= 3 (nodes per ring), got {num_around!r}.")
    num_around = int(num_around)
    levels = _ring_levels(height, target_edge_length, z_bottom)
    rings = []
    for j, z in enumerate(levels):
        xy = point_at((np.arange(num_around) + 0.5 * (j % 2)) / num_around)
        rings.append(np.column_stack([xy, np.full(num_around, z)]))
    position = np.concatenate(rings)
    triangles = _band_triangles(num_around, len(levels), periodic=True)
    bottom = np.arange(num_around)
    top = (len(levels) - 1) * num_around + np.arange(num_around)
    return _assemble(position, triangles, bottom, top, dtype)


def cylinder_mesh(
    radius: float,
    height: float,
    target_edge_length: float,
    z_bottom: float = 0.0,
    dtype=None,
    num_around: int | None = None,
) -> MembraneMesh:
    """Band of near-equilateral triangles on the cylinder r = ``radius``, z ∈ [z_bottom, z_bottom + height].

    n_θ = round(2π R / target) nodes per ring (hoop chord 2R sin(π/n_θ) ≈ target); ring spacing ≈ target·√3/2,
    rounded so that rings sit exactly at both ends; odd rings are turned by half a step (π/n_θ), so the
    triangles are near equilateral. Nodes lie on the cylinder; each ring is a regular n_θ-gon.

    Args:
      radius: R, m, > 0 (the membrane mid-surface).
      height: m, > 0.
      target_edge_length: wanted edge length, m, > 0.
      z_bottom: height of the bottom ring, m.
      dtype: float dtype of the arrays (default: JAX's default float).
      num_around: n_θ, nodes per ring (default as above); fixing it gives meshes of several radii (membrane
        thicknesses) one topology, for batching.
    """
    check_range("radius", radius, lower=0.0, lower_open=True)

    def point_at(s):
        angle = 2.0 * np.pi * s
        return radius * np.column_stack([np.cos(angle), np.sin(angle)])

    return _band_mesh(point_at, 2.0 * np.pi * radius, height, target_edge_length, z_bottom, dtype, num_around)


def offset_polygon(outline_vertices, offset: float) -> np.ndarray:
    """Convex counter-clockwise polygon with every edge moved outward by ``offset`` (mitred corners).

    Vertex k of the result is the intersection of the offset lines of the edges meeting at vertex k:
    v_k + offset (n_{k−1} + n_k)/(1 + n_{k−1}·n_k), n the outward unit edge normals.
    """
    vertices = np.asarray(outline_vertices, dtype=np.float64).reshape(-1, 2)
    edge = np.roll(vertices, -1, axis=0) - vertices
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.linalg.norm(edge, axis=1)[:, None]
    previous = np.roll(normal, 1, axis=0)
    miter = (previous + normal) / (1.0 + np.sum(previous * normal, axis=1))[:, None]
    return vertices + offset * miter


def rounded_offset_path(outline_vertices, offset: float, corner_radius: float):
    """Arc-length parametrisation of a convex polygon's outline offset outward with rounded corners.

    The path is the Minkowski sum of the *core* polygon (the outline moved inward by ``corner_radius``, e.g.
    the polygon of the outer particles' centres when ``corner_radius`` is the particle radius) with a disc
    of radius ρ = corner_radius + offset: straight sides parallel to the outline's faces, offset from them,
    joined by circular arcs of radius ρ about the core's vertices. This is where a membrane touching the
    outer spheres lies, corners included; the mitred offset (:func:`offset_polygon`) leaves a gap of
    ρ (1/cos(θ/2) − 1) at a corner turning by θ, which cell pressure closes by shortening the perimeter.

    Args:
      outline_vertices: (F, 2) convex polygon, counter-clockwise, m.
      offset: outward distance of the path from the outline's faces, m, >= 0.
      corner_radius: inward offset of the core polygon, m, >= 0.

    Returns:
      (point_at, perimeter): ``point_at(s)`` maps s ∈ [0, 1) (array) to (n, 2) points on the path at arc
      length s × perimeter from the start of the arc about core vertex 0, counter-clockwise.
    """
    check_range("offset", offset, lower=0.0)
    check_range("corner_radius", corner_radius, lower=0.0)
    core = offset_polygon(outline_vertices, -corner_radius)
    radius = corner_radius + offset
    edge = np.roll(core, -1, axis=0) - core
    side = np.linalg.norm(edge, axis=1)
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / side[:, None]
    # Corner k turns from the normal of edge k − 1 to that of edge k.
    start_angle = np.arctan2(np.roll(normal, 1, axis=0)[:, 1], np.roll(normal, 1, axis=0)[:, 0])
    turn = np.mod(np.arctan2(normal[:, 1], normal[:, 0]) - start_angle, 2.0 * np.pi)
    # Pieces alternate: arc about vertex k, then the side along edge k.
    length = np.column_stack([radius * turn, side]).ravel()
    start = np.concatenate([[0.0], np.cumsum(length)])
    perimeter = float(start[-1])

    def point_at(s):
        arc = np.asarray(s, dtype=np.float64) * perimeter
        piece = np.clip(np.searchsorted(start, arc, side="right") - 1, 0, len(length) - 1)
        along = arc - start[piece]
        vertex = piece // 2
        angle = start_angle[vertex] + along / max(radius, np.finfo(float).tiny)
        on_arc = core[vertex] + radius * np.column_stack([np.cos(angle), np.sin(angle)])
        on_side = core[vertex] + radius * normal[vertex] + along[:, None] * edge[vertex] / side[vertex, None]
        return np.where((piece % 2 == 0)[:, None], on_arc, on_side)

    return point_at, perimeter


def prism_mesh(
    outline_vertices,
    offset: float,
    height: float,
    target_edge_length: float,
    z_bottom: float = 0.0,
    dtype=None,
    corner_radius: float | None = None,
    num_around: int | None = None,
) -> MembraneMesh:
    """Band around a polygonal (e.g. octagonal) prism, its mid-surface ``offset`` outside the outline.

    Rule: node k of a ring, at parameter s = (k + ½·(j mod 2))/n_θ, is placed at arc length s·P along the
    offset outline (P its perimeter, n_θ = round(P/target)), counter-clockwise. With ``corner_radius`` the
    offset outline has rounded corners (:func:`rounded_offset_path`: the membrane wraps the corner spheres,
    as a real membrane does); without it the corners are mitred (:func:`offset_polygon`), cut by the chord
    where they fall between two nodes.

    Args:
      outline_vertices: (F, 2) convex polygon, counter-clockwise, m (the particle outline).
      offset: outward distance of the mid-surface, m, >= 0 (t_m/2 for a membrane touching the outline).
      height: m, > 0.
      target_edge_length: m, > 0.
      z_bottom: height of the bottom ring, m.
      dtype: float dtype of the arrays (default: JAX's default float).
      corner_radius: round the corners about the outline moved inward by this much (the particle radius
        for a specimen's outline), m, >= 0; None for mitred corners.
      num_around: n_θ, nodes per ring (default round(P/target)); fixing it gives meshes at several offsets
        (membrane thicknesses) the same topology, for batching.
    """
    check_range("offset", offset, lower=0.0)
    if corner_radius is not None:
        point_at, perimeter = rounded_offset_path(outline_vertices, offset, corner_radius)
        return _band_mesh(point_at, perimeter, height, target_edge_length, z_bottom, dtype, num_around)
    polygon = offset_polygon(outline_vertices, offset)
    side = np.linalg.norm(np.roll(polygon, -1, axis=0) - polygon, axis=1)
    start = np.concatenate([[0.0], np.cumsum(side)])
    perimeter = start[-1]

    def point_at(s):
        arc = s * perimeter
        k = np.clip(np.searchsorted(start, arc, side="right") - 1, 0, len(side) - 1)
        fraction = (arc - start[k]) / side[k]
        return polygon[k] + fraction[:, None] * (np.roll(polygon, -1, axis=0)[k] - polygon[k])

    return _band_mesh(point_at, perimeter, height, target_edge_length, z_bottom, dtype, num_around)


def flat_mesh(width: float, length: float, target_edge_length: float, dtype=None) -> MembraneMesh:
    """Flat sheet in the plane z = 0 (normal +z): rows along x stacked along y, odd rows shifted by ½.

    Rows span x ∈ [0, width] (even) or [½a, width + ½a] (odd), a = width/n; row spacing ≈ a√3/2 adjusted
    to span y ∈ [0, length]. ``bottom_ring`` and ``top_ring`` are the first and last rows (there are no
    caps: the volume functions do not apply). For patch and bending tests.
    """
    check_range("width", width, lower=0.0, lower_open=True)
    check_range("target_edge_length", target_edge_length, lower=0.0, lower_open=True)
    columns = max(1, round(width / target_edge_length))
    spacing = width / columns
    levels = _ring_levels(length, target_edge_length, 0.0)
    rows = []
    for j, y in enumerate(levels):
        x = (np.arange(columns + 1) + 0.5 * (j % 2)) * spacing
        rows.append(np.column_stack([x, np.full(columns + 1, y), np.zeros(columns + 1)]))
    triangles = _band_triangles(columns, len(levels), periodic=False)
    bottom = np.arange(columns + 1)
    top = (len(levels) - 1) * (columns + 1) + np.arange(columns + 1)
    return _assemble(np.concatenate(rows), triangles, bottom, top, dtype)


# ----------------------------------------------------------------------------------------------------------
# Geometry and kinematics (traced): gathers, triangle strains, hinge angles, areas and volumes
# ----------------------------------------------------------------------------------------------------------


@jax.custom_vjp
def gather_components(position, index, incidence):
    """``position[index].T``, component-first (3, S), whose gradient gathers instead of scattering.

    Two XLA-CPU costs are avoided. The transpose of a row gather is a scatter-add, which runs as a serial
    loop: with ``incidence`` (N, K), the slots of ``index`` holding each row padded with S (built on the
    host, see :class:`MembraneMesh`), the cotangent is summed by K row gathers instead,
    ∂/∂position_n = Σ_k ḡ[incidence[n, k]], ḡ the cotangent rows with a zero row appended. And the
    gathered, transposed array sits behind an optimisation barrier, so that a backend that keeps it
    (XLA-CPU removes it) does not re-gather it inside every consumer fusion.
    Reverse mode only (``jax.grad``, ``jax.vjp``, reverse over reverse); forward mode is not defined.

    Args:
      position: (N, 3) rows to gather.
      index: (S,) int rows to take.
      incidence: (N, K) int the inverse map of ``index``, padded with S.
    """
    return jax.lax.optimization_barrier(position[index].T)


def _gather_components_forward(position, index, incidence):
    return gather_components(position, index, incidence), incidence


def _gather_components_backward(incidence, cotangent):
    rows = cotangent.T
    padded = jnp.concatenate([rows, jnp.zeros((1, rows.shape[1]), rows.dtype)])
    total = padded[incidence[:, 0]]
    for k in range(1, incidence.shape[1]):  # K ≤ 20: unrolled row gathers
        total = total + padded[incidence[:, k]]
    return total, None, None


gather_components.defvjp(_gather_components_forward, _gather_components_backward)


def gathered_corners(position, mesh: MembraneMesh):
    """Triangle corners component-first, (3, 3T): first corners of all triangles, then second, third."""
    return gather_components(position, mesh.corner_index, mesh.corner_incidence)


def _corners(position, mesh: MembraneMesh):
    """Triangle corners component-first: three (3, T) arrays."""
    return jnp.split(gathered_corners(position, mesh), 3, axis=1)


def gathered_hinges(position, mesh: MembraneMesh):
    """Hinge vertices component-first, (3, 4E): a, b, c, d of all hinges (see :func:`dihedral_angle`)."""
    return gather_components(position, mesh.hinge_index, mesh.hinge_incidence)


@jax.custom_vjp
def triangle_invariants(corners, inverse):
    """Green–Lagrange strain (E₁₁, E₂₂, E₁₂) and triple product x₁·(x₂ × x₃) of each triangle, (T,) each.

    Reverse mode uses the closed-form derivative below (forward mode is not defined, as for
    :func:`gather_components`).

    Args:
      corners: (3, 3T) the gathered corners (:func:`gathered_corners`).
      inverse: (T, 2, 2) the rest frames D_m⁻¹.
    """
    x1, x2, x3 = jnp.split(corners, 3, axis=1)
    return (*_green_strain_of(x1, x2, x3, inverse), dot(x1, cross(x2, x3)))


def _triangle_invariants_forward(corners, inverse):
    return triangle_invariants(corners, inverse), (corners, inverse)


def _triangle_invariants_backward(residuals, cotangents):
    # Standard constant-strain triangle algebra: with f₁, f₂ the columns of F = [e₁ e₂] D_m⁻¹
    # (e₁ = x₂ − x₁, e₂ = x₃ − x₁, m = D_m⁻¹), ∂f₁/∂(x₁, x₂, x₃) = (−m₀₀ − m₁₀, m₀₀, m₁₀) I and
    # ∂f₂/∂(x₁, x₂, x₃) = (−m₀₁ − m₁₁, m₀₁, m₁₁) I; dE₁₁ = f₁·df₁, dE₂₂ = f₂·df₂, dE₁₂ = (f₁·df₂ + f₂·df₁)/2;
    # ∂(x₁·(x₂ × x₃))/∂x₁ = x₂ × x₃ and cyclically. Autodiff of the same formulas made XLA-CPU pad each
    # component of each corner's cotangent into its own array; here they come out as one (3, 3, T) array.
    corners, inverse = residuals
    # Stored once: the per-triangle cotangents would otherwise be recomputed for all nine entries.
    c11, c22, c12, c_volume = materialize(*cotangents)
    num_triangles = inverse.shape[0]
    x = corners.reshape(3, 3, num_triangles)  # (component, corner, triangle)
    x1, x2, x3 = x[:, 0], x[:, 1], x[:, 2]
    edge1, edge2, f1, f2 = _deformation_columns(x1, x2, x3, inverse)
    m00, m01, m10, m11 = inverse[:, 0, 0], inverse[:, 0, 1], inverse[:, 1, 0], inverse[:, 1, 1]
    # ∂E/∂f₁ and ∂E/∂f₂ contracted with the cotangents, then spread on the corners.
    pull1 = scale(c11, f1) + scale(0.5 * c12, f2)
    pull2 = scale(c22, f2) + scale(0.5 * c12, f1)
    along1 = jnp.stack([-(m00 + m10), m00, m10])[None]  # ∂f₁/∂x_k, (1, 3, T)
    along2 = jnp.stack([-(m01 + m11), m01, m11])[None]
    volume = jnp.stack([cross(x2, x3), cross(x3, x1), cross(x1, x2)], axis=1)
    d_corners = pull1[:, None] * along1 + pull2[:, None] * along2 + c_volume[None, None] * volume
    d_inverse = jnp.stack(
        [
            jnp.stack([dot(pull1, edge1), dot(pull2, edge1)], axis=-1),
            jnp.stack([dot(pull1, edge2), dot(pull2, edge2)], axis=-1),
        ],
        axis=1,
    )  # ∂/∂m_ij = pull_j · e_i
    return d_corners.reshape(corners.shape), d_inverse


triangle_invariants.defvjp(_triangle_invariants_forward, _triangle_invariants_backward)


def _deformation_columns(x1, x2, x3, inverse):
    """Edges e₁ = x₂ − x₁, e₂ = x₃ − x₁ and the columns f₁, f₂ of F = [e₁ e₂] D_m⁻¹, (3, T) each."""
    edge1, edge2 = x2 - x1, x3 - x1
    # f_j = e₁ (D_m⁻¹)_{1j} + e₂ (D_m⁻¹)_{2j}
    f1 = edge1 * inverse[None, :, 0, 0] + edge2 * inverse[None, :, 1, 0]
    f2 = edge1 * inverse[None, :, 0, 1] + edge2 * inverse[None, :, 1, 1]
    return edge1, edge2, f1, f2


def _green_strain_of(x1, x2, x3, inverse):
    """Green–Lagrange strain E = (FᵀF − I)/2 of each triangle, F = D_s D_m⁻¹; returns (E₁₁, E₂₂, E₁₂)."""
    _, _, f1, f2 = _deformation_columns(x1, x2, x3, inverse)
    return 0.5 * (dot(f1, f1) - 1.0), 0.5 * (dot(f2, f2) - 1.0), 0.5 * dot(f1, f2)


def green_strain(position, mesh: MembraneMesh):
    """Green–Lagrange strain (E₁₁, E₂₂, E₁₂) of each triangle at the given node positions."""
    return triangle_invariants(gathered_corners(position, mesh), mesh.reference_inverse)[:3]


def _dihedral_and_gradient(hinges, with_gradient=True):
    """Signed bending angle θ of each hinge (E,) and its gradient ∂θ/∂(a, b, c, d) as one (3, 4, E) array.

    ``hinges`` is (3, 4E), the vertices a, b, c, d of every hinge component-first. The edge a → b belongs
    to the first triangle (a, b, c) and, reversed, to the second (b, a, d). With the unnormalised normals
    n₁ = (b − a) × (c − a), n₂ = (a − b) × (d − b) and e = b − a, θ = atan2((n₁ × n₂)·e, |e| n₁·n₂) is the
    angle between the normals without normalising them (both atan2 arguments carry the same positive
    factor); 0 for a flat pair. Its gradient is the classical hinge formula (Bridson, Marino & Fedkiw 2003;
    Tamstorf & Grinspun 2013), with q_i = 1/|n_i|²:

        ∂θ/∂c = −|e| q₁ n₁,   ∂θ/∂d = −|e| q₂ n₂,
        ∂θ/∂a = −[(c − b)·e q₁ n₁ + (d − b)·e q₂ n₂]/|e|,   ∂θ/∂b = −[(a − c)·e q₁ n₁ + (a − d)·e q₂ n₂]/|e|

    (the four sum to zero: a rigid translation does not bend). Collapsed triangles (n_i = 0) or edges give
    θ = 0 with a zero gradient. With ``with_gradient=False`` the gradient is None.
    """
    a, b, c, d = jnp.split(hinges, 4, axis=1)
    edge = b - a
    normal1 = cross(edge, c - a)
    normal2 = cross(a - b, d - b)
    length_sq = dot(edge, edge)
    length = jnp.sqrt(jnp.where(length_sq > 0.0, length_sq, 1.0))
    sine = dot(cross(normal1, normal2), edge)
    cosine = length * dot(normal1, normal2)
    area1_sq, area2_sq = dot(normal1, normal1), dot(normal2, normal2)
    degenerate = (area1_sq == 0.0) | (area2_sq == 0.0) | (length_sq == 0.0)
    angle = jnp.where(degenerate, 0.0, jnp.arctan2(sine, jnp.where(degenerate, 1.0, cosine)))
    if not with_gradient:
        return angle, None
    weight1 = jnp.where(degenerate, 0.0, 1.0 / jnp.where(degenerate, 1.0, area1_sq))
    weight2 = jnp.where(degenerate, 0.0, 1.0 / jnp.where(degenerate, 1.0, area2_sq))
    along1, along2 = scale(weight1, normal1), scale(weight2, normal2)
    along_edge = jnp.stack([dot(c - b, edge), dot(d - b, edge), dot(a - c, edge), dot(a - d, edge)])
    # Stored once: the four vertex gradients share them, and XLA-CPU would recompute them per vertex
    # and component (membrax.fusion).
    along1, along2, length, along_edge = materialize(along1, along2, length, along_edge)
    inverse_length = 1.0 / length
    gradient = jnp.stack(
        [
            -scale(inverse_length, scale(along_edge[0], along1) + scale(along_edge[1], along2)),
            -scale(inverse_length, scale(along_edge[2], along1) + scale(along_edge[3], along2)),
            scale(-length, along1),
            scale(-length, along2),
        ],
        axis=1,
    )
    return angle, gradient


@jax.custom_vjp
def dihedral_angle(hinges):
    """Signed bending angle θ of each hinge, rad, from the gathered hinge vertices (3, 4E) (a, b, c, d).

    See :func:`_dihedral_and_gradient` for the angle and its closed-form gradient, which reverse mode
    uses (forward mode is not defined, as for :func:`gather_components`).
    """
    return _dihedral_and_gradient(hinges, with_gradient=False)[0]


def _dihedral_angle_forward(hinges):
    # The closed-form gradient is one pass over the hinges; autodiff of atan2 and the cross products was
    # 8× slower on XLA-CPU (its backward splits into one fusion per output component).
    angle, gradient = _dihedral_and_gradient(hinges)
    return angle, gradient


def _dihedral_angle_backward(gradient, cotangent):
    # The cotangent stored once: it would otherwise be recomputed for each vertex and component.
    cotangent = materialize(cotangent)
    return ((gradient * cotangent[None, None]).reshape(gradient.shape[0], -1),)


dihedral_angle.defvjp(_dihedral_angle_forward, _dihedral_angle_backward)


def surface_area(position, mesh: MembraneMesh):
    """Current area of the band, Σ_T ½|(x₂ − x₁) × (x₃ − x₁)|, m²."""
    x1, x2, x3 = _corners(position, mesh)
    normal = cross(x2 - x1, x3 - x1)
    return 0.5 * jnp.sum(jnp.sqrt(dot(normal, normal)))


def free_node_mask(mesh: MembraneMesh) -> np.ndarray:
    """(n,) bool, host-side: True for the nodes that move freely, False for the clamped end rings."""
    free = np.ones(mesh.num_nodes, dtype=bool)
    free[np.asarray(mesh.bottom_ring)] = False
    free[np.asarray(mesh.top_ring)] = False
    return free


def inner_volume(position, mesh: MembraneMesh, thickness):
    """Volume inside the membrane's inner face, V_mid − ½ t_m A_band, m³ (first order in t_m/R).

    V_mid is :func:`enclosed_volume` (mid-surface and flat caps), A_band the band's :func:`surface_area`:
    the specimen volume of the membrane test.
    """
    return enclosed_volume(position, mesh) - 0.5 * thickness * surface_area(position, mesh)


def band_volume(position, mesh: MembraneMesh):
    """(1/6) Σ_triangles x₁·(x₂ × x₃) over the band alone, m³ (origin-dependent: the band is open)."""
    triple = triangle_invariants(gathered_corners(position, mesh), mesh.reference_inverse)[3]
    return jnp.sum(triple) / 6.0


def cap_volume(position, ring, upward: bool):
    """Volume term of a flat cap closing a ring, m³: a fan of triangles to the ring's centroid.

    The cap triangles are (c, x_k, x_{k+1}) for the top (``upward``, normal +z, ring counter-clockwise seen
    from +z) and (c, x_{k+1}, x_k) for the bottom, c the centroid of the ring nodes (so the cap follows the
    ring, and its pressure force is passed to the ring nodes). Like :func:`band_volume`, origin-dependent.
    """
    points = position[ring]
    centre = jnp.mean(points, axis=0)
    here = points.T
    after = jnp.roll(points, -1, axis=0).T
    first, second = (here, after) if upward else (after, here)
    triple = centre[0] * (first[1] * second[2] - first[2] * second[1])
    triple += centre[1] * (first[2] * second[0] - first[0] * second[2])
    triple += centre[2] * (first[0] * second[1] - first[1] * second[0])
    return jnp.sum(triple) / 6.0


def enclosed_volume(position, mesh: MembraneMesh):
    """Volume enclosed by the band and two flat end caps, m³ (reference §9, divergence theorem).

        V = (1/6) Σ_f x₁·(x₂ × x₃)   over the band triangles and the cap fans of :func:`cap_volume`.

    The caps stand for the platens: the end rings are meant to be clamped to them, where the fan is
    exactly the platen's face. The surface is closed for any node positions, so V is exact and independent
    of the origin; for rings lying in planes it is the exact volume of the polyhedron.
    """
    return enclosed_volume_of(band_volume(position, mesh), position, mesh)


def enclosed_volume_of(band, position, mesh: MembraneMesh):
    """:func:`enclosed_volume` from the band's own term (:func:`band_volume`)."""
    return (
        band
        + cap_volume(position, mesh.bottom_ring, upward=False)
        + cap_volume(position, mesh.top_ring, upward=True)
    )
