"""Membrane measurements: penetration, stretches, radius, indentation and hoop strain of the mesh.

Contract. Every function here is a pure ``jnp`` function of the current node positions (n_nodes, 3) (and,
where it applies, the spheres and the node → sphere candidate table of :mod:`membrax.membrane.candidates`),
jittable and vmappable. The geometric quantities (distances, penetrations, stretches, radius, normal
displacement) are differentiable in the positions; the indentation field is differentiable almost
everywhere (it is a difference of a windowed maximum). Static arguments (the mesh's row length, the
indentation window) come from array shapes or Python ints. SI units: m, N.

Quantities:

- :func:`point_triangle_distance`: distance from a point to a closed triangle, with the region tests of
  Ericson, *Real-Time Collision Detection* (2005) §5.1.5, written branch-free; safe (finite values and
  gradients) for degenerate triangles.
- :func:`sphere_penetration`, :func:`max_sphere_penetration`: how far spheres pass through the membrane
  mid-surface between the nodes, P = R_i − d(x_i, triangle), from the candidate spheres of each triangle's
  three nodes. A sphere resting properly on the membrane (node–sphere contact at |x_node − x_i| = R_i +
  t_m/2) has P ≈ −t_m/2; P > 0 means the sphere surface crosses the mid-surface (a sphere poking through
  the membrane between nodes, which the node-based contact cannot see). Runs should keep P < t_m/2.
- :func:`triangle_stretches`: principal in-plane stretches (λ₁ ≥ λ₂) of each constant-strain triangle.
- :func:`mean_radius`, :func:`radial_strain`: equivalent radius r = √(V/(πH)) of the volume enclosed by the
  band and its end caps, and ε_r = 1 − r/r₀ (compression positive: bulging gives ε_r < 0).
- :func:`rest_outward_normal`, :func:`normal_displacement`, :func:`indentation_field`: outward normal
  displacement u_n of each node and its local depth below the neighbouring outermost nodes (membrane
  penetration into the voids between particles, ≥ 0).
- :func:`hoop_strain`: the mid-height ring's circumferential strain (what a circumference tape measures).

The records of a membrane triaxial test, built on these, are in :mod:`membrax.membrane.records`.

The band functions (:func:`mean_radius`, :func:`normal_displacement`, :func:`indentation_field`) assume a
band mesh from :func:`membrax.membrane.mesh.cylinder_mesh` or :func:`membrax.membrane.mesh.prism_mesh`: rows
of n_θ = len(bottom_ring) nodes stacked in z, node index row · n_θ + column, the column periodic.

Layout: per-triangle and per-pair geometry is component-first (3, ...) with :mod:`membrax.vector`
(XLA's CPU backend reduces over a trailing size-3 axis slowly); node arrays are rows (n_nodes, 3).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from membrax.membrane.mesh import MembraneMesh, enclosed_volume
from membrax.vector import cross, dot, safe_norm, safe_normalize, scale

__all__ = [
    "closest_point_on_triangle",
    "point_triangle_distance",
    "sphere_penetration",
    "max_sphere_penetration",
    "triangle_stretches",
    "mean_radius",
    "radial_strain",
    "rest_outward_normal",
    "normal_displacement",
    "indentation_field",
    "hoop_strain",
]


# ----------------------------------------------------------------------------------------------------------
# Point–triangle distance
# ----------------------------------------------------------------------------------------------------------


def _safe_divide(numerator, denominator):
    """Return numerator / denominator, 0 where the denominator is 0 (finite values and gradients)."""
    nonzero = denominator != 0.0
    return jnp.where(nonzero, numerator / jnp.where(nonzero, denominator, 1.0), 0.0)


def _segment_parameter(point, start, end):
    """Parameter t ∈ [0, 1] of the closest point start + t (end − start) of a segment (0 if a point)."""
    direction = end - start
    return jnp.clip(_safe_divide(dot(point - start, direction), dot(direction, direction)), 0.0, 1.0)


def _edges_barycentric(point, a, b, c):
    """(β_b, β_c) of the closest point on the three edges: the closed triangle when it is degenerate."""
    best_b, best_c, best_sq = None, None, None
    for start, end, weights in (
        (a, b, lambda t: (t, jnp.zeros_like(t))),  # a + t (b − a)
        (b, c, lambda t: (1.0 - t, t)),  # b + t (c − b)
        (c, a, lambda t: (jnp.zeros_like(t), 1.0 - t)),  # c + t (a − c)
    ):
        t = _segment_parameter(point, start, end)
        gap = point - start - scale(t, end - start)
        gap_sq = dot(gap, gap)
        weight_b, weight_c = weights(t)
        if best_sq is None:
            best_b, best_c, best_sq = weight_b, weight_c, gap_sq
        else:
            closer = gap_sq < best_sq
            best_b = jnp.where(closer, weight_b, best_b)
            best_c = jnp.where(closer, weight_c, best_c)
            best_sq = jnp.where(closer, gap_sq, best_sq)
    return best_b, best_c


def _closest_barycentric(point, a, b, c):
    """(β_b, β_c): the closest point of the closed triangle is a + β_b (b − a) + β_c (c − a).

    Ericson's region tests, see :func:`closest_point_on_triangle`.
    """
    ab, ac = b - a, c - a
    ap, bp, cp = point - a, point - b, point - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    in_a = (d1 <= 0.0) & (d2 <= 0.0)
    in_b = (d3 >= 0.0) & (d4 <= d3)
    in_ab = (vc <= 0.0) & (d1 >= 0.0) & (d3 <= 0.0)
    in_c = (d6 >= 0.0) & (d5 <= d6)
    in_ac = (vb <= 0.0) & (d2 >= 0.0) & (d6 <= 0.0)
    in_bc = (va <= 0.0) & ((d4 - d3) >= 0.0) & ((d5 - d6) >= 0.0)
    zero, one = jnp.zeros_like(d1), jnp.ones_like(d1)
    total = va + vb + vc
    on_bc = _safe_divide(d4 - d3, (d4 - d3) + (d5 - d6))
    # Ericson's order: the first region that holds wins, so select from the last to the first.
    regions = (
        (in_bc, 1.0 - on_bc, on_bc),
        (in_ac, zero, _safe_divide(d2, d2 - d6)),
        (in_c, zero, one),
        (in_ab, _safe_divide(d1, d1 - d3), zero),
        (in_b, one, zero),
        (in_a, zero, zero),
    )
    beta_b, beta_c = _safe_divide(vb, total), _safe_divide(vc, total)  # face
    for inside, weight_b, weight_c in regions:
        beta_b = jnp.where(inside, weight_b, beta_b)
        beta_c = jnp.where(inside, weight_c, beta_c)
    normal = cross(ab, ac)
    eps = jnp.finfo(jnp.result_type(normal)).eps
    degenerate = dot(normal, normal) <= eps * (dot(ab, ab) * dot(ac, ac))
    edge_b, edge_c = _edges_barycentric(point, a, b, c)
    return jnp.where(degenerate, edge_b, beta_b), jnp.where(degenerate, edge_c, beta_c)


def closest_point_on_triangle(point, a, b, c):
    """Closest point of the closed triangle (a, b, c) to ``point``, component-first.

    Ericson's region tests (Real-Time Collision Detection §5.1.5). With ab = b − a, ac = c − a and
    d₁ = ab·(p−a), d₂ = ac·(p−a), d₃ = ab·(p−b), d₄ = ac·(p−b), d₅ = ab·(p−c), d₆ = ac·(p−c), the first
    region that holds, in this order, gives the point q = a + β_b ab + β_c ac:

    - vertex a: d₁ ≤ 0 and d₂ ≤ 0 → (β_b, β_c) = (0, 0);
    - vertex b: d₃ ≥ 0 and d₄ ≤ d₃ → (1, 0);
    - edge ab: v_c = d₁d₄ − d₃d₂ ≤ 0, d₁ ≥ 0, d₃ ≤ 0 → (d₁/(d₁ − d₃), 0);
    - vertex c: d₆ ≥ 0 and d₅ ≤ d₆ → (0, 1);
    - edge ac: v_b = d₅d₂ − d₁d₆ ≤ 0, d₂ ≥ 0, d₆ ≤ 0 → (0, d₂/(d₂ − d₆));
    - edge bc: v_a = d₃d₆ − d₅d₄ ≤ 0, d₄ − d₃ ≥ 0, d₅ − d₆ ≥ 0 → (1 − w, w),
      w = (d₄ − d₃)/((d₄ − d₃) + (d₅ − d₆));
    - face: (v_b, v_c)/(v_a + v_b + v_c).

    All candidates are evaluated and selected with ``jnp.where`` (no branching on data); divisions are
    guarded so unselected branches stay finite. A degenerate triangle (|ab × ac|² ≤ ε |ab|²|ac|², ε the
    dtype's machine epsilon: collinear or coincident corners) is a segment or a point, for which the region
    tests fail; there the closest of the three edges' closest points is taken instead.

    Args:
      point: (3, ...) the query point(s), m.
      a: (3, ...) first corner(s), same rank as ``point`` (shapes broadcast, e.g. (3, T, 1) vs (3, T, K)).
      b: (3, ...) second corner(s).
      c: (3, ...) third corner(s).

    Returns:
      (3, ...) the closest point(s), m (differentiable: the projection's derivative within each region).
    """
    beta_b, beta_c = _closest_barycentric(point, a, b, c)
    return a + scale(beta_b, b - a) + scale(beta_c, c - a)


def point_triangle_distance(point, a, b, c):
    """Distance from ``point`` to the closed triangle (a, b, c), m: d = |p − q|, q its closest point.

    q = a + β_b (b − a) + β_c (c − a) with the barycentric weights of :func:`closest_point_on_triangle`
    (Ericson §5.1.5 region tests, degenerate triangles handled). Gradient: d = min over the simplex of
    |p − Σ β_k x_k|, so by Danskin's theorem ∂d/∂p = (p − q)/d and ∂d/∂x_k = −β_k (p − q)/d with the
    minimising β held fixed; the weights are therefore computed under ``stop_gradient`` (exact, and the
    region tests stay out of the derivative). The norm is :func:`membrax.vector.safe_norm` (zero gradient
    where d = 0).

    Args:
      point: (3, ...) query point(s), m.
      a: (3, ...) first corner(s), same rank as ``point`` (broadcastable shapes).
      b: (3, ...) second corner(s).
      c: (3, ...) third corner(s).

    Returns:
      (...) distances, m.
    """
    beta_b, beta_c = jax.lax.stop_gradient(_closest_barycentric(point, a, b, c))
    return safe_norm(point - a - scale(beta_b, b - a) - scale(beta_c, c - a))


# ----------------------------------------------------------------------------------------------------------
# Sphere penetration through the mid-surface
# ----------------------------------------------------------------------------------------------------------


def sphere_penetration(node_position, triangles, sphere_position, sphere_radius, candidate_idx):
    """Largest penetration of a sphere through the mid-surface, per triangle, m.

    The candidate spheres of triangle (n₁, n₂, n₃) are the union of its nodes' candidate ids,
    ``candidate_idx[triangles]`` (T, 3K); ids equal to N (padding) are ignored (a sphere listed by several
    nodes is simply counted several times). For each (triangle, candidate i):

        P = R_i − d(x_i, triangle),   d from :func:`point_triangle_distance`,

    positive when the sphere's surface crosses the membrane mid-surface. The membrane is meant to sit
    R_i + t_m/2 from a sphere centre (node–sphere contact law), so a sphere resting properly on a face has
    P = −t_m/2; require P < t_m/2 (the sphere does not come out through the far face of the membrane).

    Args:
      node_position: (n_nodes, 3) node positions, m.
      triangles: (T, 3) int node indices (``mesh.triangles``).
      sphere_position: (N, 3) sphere centres, m.
      sphere_radius: (N,) sphere radii, m.
      candidate_idx: (n_nodes, K) int sphere ids padded with N (``NodeCandidates.idx``).

    Returns:
      (T,) max_i P per triangle, m; −inf for a triangle with no candidate sphere.
    """
    num_spheres = sphere_position.shape[0]
    num_triangles = triangles.shape[0]
    candidate = candidate_idx[triangles].reshape(num_triangles, -1)  # (T, 3K)
    valid = candidate < num_spheres
    safe_idx = jnp.where(valid, candidate, 0)
    centre = jnp.moveaxis(sphere_position[safe_idx], -1, 0)  # (3, T, 3K)
    a, b, c = (node_position[triangles[:, k]].T[:, :, None] for k in range(3))  # (3, T, 1)
    penetration = sphere_radius[safe_idx] - point_triangle_distance(centre, a, b, c)
    return jnp.max(jnp.where(valid, penetration, -jnp.inf), axis=1)


def max_sphere_penetration(node_position, triangles, sphere_position, sphere_radius, candidate_idx):
    """Largest over triangles of :func:`sphere_penetration` (scalar, m; −inf when there is no candidate)."""
    return jnp.max(
        sphere_penetration(node_position, triangles, sphere_position, sphere_radius, candidate_idx)
    )


# ----------------------------------------------------------------------------------------------------------
# Stretches
# ----------------------------------------------------------------------------------------------------------


def _safe_sqrt(x):
    """√x with a finite (zero) gradient at x = 0 and 0 for x < 0."""
    positive = x > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def triangle_stretches(node_position, mesh: MembraneMesh):
    """Principal in-plane stretches (λ₁ ≥ λ₂) of each constant-strain triangle.

    F = D_s D_m⁻¹ (3 × 2) with D_s = [x₂ − x₁, x₃ − x₁] and D_m⁻¹ = ``mesh.reference_inverse`` (rest edge
    matrix in the triangle's own frame), so its columns are f_j = (x₂ − x₁)(D_m⁻¹)₁ⱼ + (x₃ − x₁)(D_m⁻¹)₂ⱼ
    (as in :mod:`membrax.membrane.mesh`). The right Cauchy–Green tensor C = FᵀF = [[f₁·f₁, f₁·f₂], [f₁·f₂,
    f₂·f₂]] has the eigenvalues

        λ₁² = m + r,   λ₂² = det C / λ₁²,   m = (C₁₁ + C₂₂)/2,   r = √(((C₁₁ − C₂₂)/2)² + C₁₂²),

    with det C = |f₁ × f₂|² (the squared area ratio, free of cancellation). Rigid motions give (1, 1).

    Args:
      node_position: (n_nodes, 3) node positions, m.
      mesh: the membrane.

    Returns:
      (λ₁, λ₂), each (T,), dimensionless, λ₁ ≥ λ₂ ≥ 0.
    """
    triangles = mesh.triangles
    x1, x2, x3 = (node_position[triangles[:, k]].T for k in range(3))
    edge1, edge2 = x2 - x1, x3 - x1
    inverse = mesh.reference_inverse
    f1 = edge1 * inverse[None, :, 0, 0] + edge2 * inverse[None, :, 1, 0]
    f2 = edge1 * inverse[None, :, 0, 1] + edge2 * inverse[None, :, 1, 1]
    c11, c22, c12 = dot(f1, f1), dot(f2, f2), dot(f1, f2)
    area_normal = cross(f1, f2)
    det_c = dot(area_normal, area_normal)
    half_difference = 0.5 * (c11 - c22)
    major_sq = 0.5 * (c11 + c22) + _safe_sqrt(half_difference * half_difference + c12 * c12)
    minor_sq = _safe_divide(det_c, major_sq)
    return _safe_sqrt(major_sq), _safe_sqrt(minor_sq)


# ----------------------------------------------------------------------------------------------------------
# Radius and radial strain of the band
# ----------------------------------------------------------------------------------------------------------


def _band_height(node_position, mesh: MembraneMesh):
    """H = mean z of the top ring − mean z of the bottom ring, m."""
    return jnp.mean(node_position[mesh.top_ring, 2]) - jnp.mean(node_position[mesh.bottom_ring, 2])


def mean_radius(node_position, mesh: MembraneMesh):
    """Equivalent radius of the membrane, r = √(V / (π H)), m.

    V is :func:`membrax.membrane.mesh.enclosed_volume` (band closed by the two flat end caps, the platens) and
    H the mean height of the top ring minus that of the bottom ring: r is the radius of the circular
    cylinder of the same height and volume. For the rest :func:`membrax.membrane.mesh.cylinder_mesh` it is a
    little below the mid-surface radius R (the rings are inscribed n_θ-gons).

    Args:
      node_position: (n_nodes, 3) node positions, m.
      mesh: a band membrane (cylinder or prism mesh).

    Returns:
      Scalar r, m.
    """
    volume = enclosed_volume(node_position, mesh)
    return jnp.sqrt(volume / (jnp.pi * _band_height(node_position, mesh)))


def radial_strain(node_position, mesh: MembraneMesh, reference_radius=None):
    """Radial strain of the membrane, ε_r = 1 − r / r₀ (geotechnical convention: compression positive).

    r is :func:`mean_radius`; bulging (r > r₀) gives ε_r < 0. With ε_a the axial strain, the volumetric
    strain of the specimen is ε_v ≈ ε_a + 2 ε_r at small strain.

    Args:
      node_position: (n_nodes, 3) node positions, m.
      mesh: a band membrane.
      reference_radius: r₀, m; ``None`` takes :func:`mean_radius` of ``mesh.reference_position``.

    Returns:
      Scalar ε_r, dimensionless.
    """
    if reference_radius is None:
        reference_radius = mean_radius(mesh.reference_position, mesh)
    return 1.0 - mean_radius(node_position, mesh) / reference_radius


# ----------------------------------------------------------------------------------------------------------
# Normal displacement and indentation
# ----------------------------------------------------------------------------------------------------------


def rest_outward_normal(mesh: MembraneMesh):
    """Rest outward unit normal of the band at each node, horizontal, (n_nodes, 3).

    n₀ ∝ P_xy Σ_{T ∋ node} A_T n_T: the area-weighted sum of the incident rest triangles' normals
    (each ½ (x₂ − x₁) × (x₃ − x₁), outward for the band meshes), with its z component removed, normalised.
    Computed from ``mesh.reference_position`` with ``jnp`` (jittable). For a cylinder mesh it is the
    radial direction of the node (exactly, by the mesh's mirror symmetry about each node's radial plane).
    A node whose horizontal sum vanishes (a flat sheet) gets a zero normal.
    """
    position = mesh.reference_position
    triangles = mesh.triangles
    x1, x2, x3 = (position[triangles[:, k]].T for k in range(3))
    area_normal = 0.5 * cross(x2 - x1, x3 - x1)  # (3, T)
    rows = jnp.concatenate([area_normal.T, area_normal.T, area_normal.T])
    nodes = jnp.concatenate([triangles[:, 0], triangles[:, 1], triangles[:, 2]])
    summed = jax.ops.segment_sum(rows, nodes, num_segments=mesh.num_nodes).T  # (3, n_nodes)
    horizontal = jnp.stack([summed[0], summed[1], jnp.zeros_like(summed[2])])
    return safe_normalize(horizontal)[0].T


def normal_displacement(node_position, mesh: MembraneMesh):
    """Outward normal displacement of each node, u_n = (x − x₀)·n₀, (n_nodes,), m.

    x₀ = ``mesh.reference_position``, n₀ = :func:`rest_outward_normal` (horizontal). u_n > 0 outward
    (bulging), < 0 inward (the membrane pressed into the specimen).
    """
    normal = rest_outward_normal(mesh).T
    return dot((node_position - mesh.reference_position).T, normal)


def indentation_field(node_position, mesh: MembraneMesh, window: int):
    """Local depth of each node below the locally outermost membrane surface, (n_nodes,), m, ≥ 0.

        indentation_i = max_{j ∈ W(i)} u_n,j − u_n,i,

    u_n from :func:`normal_displacement`, W(i) the nodes within ±``window`` rows and ±``window`` columns of
    node i (columns periodic around the band; rows cut at the end rings), node i included. Under a cell
    pressure the membrane wraps the specimen: the nodes resting on particle tops are the locally outermost
    (indentation 0) and the nodes pushed into the voids between particles get a positive indentation, their
    depth below the envelope of the particle tops. Choose ``window`` ≈ one particle diameter / edge length,
    so that each window holds at least one particle top; a uniform bulge or contraction gives zero.

    Uses the band's row × column layout (node = row · n_θ + column, n_θ = len(bottom_ring)) and a
    ``jax.lax.reduce_window`` maximum on the (rows, n_θ) grid (the odd rows' half-column offset is
    ignored). Differentiable almost everywhere.

    Args:
      node_position: (n_nodes, 3) node positions, m.
      mesh: a band membrane (cylinder or prism mesh).
      window: half-width of the window in rows and columns, a non-negative Python int (static).

    Returns:
      (n_nodes,) indentation, m.
    """
    window = int(window)
    if window < 0:
        raise ValueError(f"window must be a non-negative int, got {window}")
    per_row = mesh.bottom_ring.shape[0]
    num_nodes = mesh.num_nodes
    if num_nodes % per_row:
        raise ValueError(f"{num_nodes} nodes do not form rows of {per_row}: not a band mesh")
    grid = normal_displacement(node_position, mesh).reshape(num_nodes // per_row, per_row)
    wrapped = grid[:, np.arange(-window, per_row + window) % per_row]  # periodic columns
    size = 2 * window + 1
    envelope = jax.lax.reduce_window(
        wrapped,
        jnp.array(-jnp.inf, dtype=grid.dtype),
        jax.lax.max,
        window_dimensions=(size, size),
        window_strides=(1, 1),
        padding=((window, window), (0, 0)),
    )
    return (envelope - grid).reshape(num_nodes)


# ----------------------------------------------------------------------------------------------------------
# Hoop strain
# ----------------------------------------------------------------------------------------------------------


def hoop_strain(node_position, mesh):
    """The membrane's circumferential strain at mid-height, ε_θ = L/L₀ − 1 (tension positive).

    L is the length of the closed polyline through the nodes of the band's middle ring, L₀ its length in
    the rest mesh (the unstretched membrane). A laboratory measures the same with a circumference tape
    where the membrane bridges the voids. Hoop theory (Henkel & Gilbert 1952) turns it into the
    membrane's radial stress, Δσ_r = 2 E_m t_m ε_θ / D₀ (:func:`membrax.theory.hoop_tension_correction`).
    """
    around = mesh.bottom_ring.shape[0]
    rings = (mesh.top_ring[0] - mesh.bottom_ring[0]) // around + 1
    middle = mesh.bottom_ring + around * (rings // 2)

    def length(position):
        ring = position[middle]
        step = jnp.roll(ring, -1, axis=0) - ring
        return jnp.sum(jnp.sqrt(jnp.sum(step * step, axis=1)))

    return length(node_position) / length(mesh.reference_position.astype(node_position.dtype)) - 1.0
