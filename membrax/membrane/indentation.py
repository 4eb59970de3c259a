"""Membrane indentation: a flat latex sheet pressed by a uniform pressure onto a fixed array of spheres.

Contract. Static equilibrium of an open sheet (:func:`membrax.membrane.mesh.flat_mesh`) lying on a fixed array
of equal touching spheres, square (:func:`sheet_on_square_array`) or triangular, i.e. a hexagonal
close-packed layer like an FCC {111} face (:func:`sheet_on_triangular_array`), loaded by a uniform
pressure p on its upper face (positive p pushes the sheet down, −z). The total potential energy

    Π(x) = W_stretch(x) + W_bend(x) + p V(x) + U_contact(x)

is minimised over the free node coordinates with scipy's L-BFGS-B on jax gradients (float64 is up to the
caller: enable x64 first). The pieces:

- W_stretch, W_bend: :func:`membrax.membrane.mesh.stretching_energy` (incompressible neo-Hookean) and
  :func:`membrax.membrane.mesh.bending_energy`;
- p V: the load potential of the pressure, V the volume between the sheet and a horizontal reference
  plane z = z_ref below it (:func:`projected_volume`). For a piecewise-linear sheet this is exact per
  triangle: V_T = A_T^xy (z̄_T − z_ref), A_T^xy the signed area of the triangle's projection on the plane
  z = 0 (positive where the normal (x₂ − x₁) × (x₃ − x₁) points up) and z̄_T the mean height of its three
  corners. Lowering the sheet lowers V, so +p V pushes it down. Its gradient gives the nodal pressure
  forces: Σ_nodes (−p ∂V/∂x) = (0, 0, −p Σ_T A_T^xy) exactly (V is invariant under horizontal
  translations), and on nodes not on the boundary −p ∂V/∂x_i = −p Σ_{T ∋ i} A_T n_T / 3, the usual
  consistent pressure load, because V differs from the cone volume (1/6) Σ x₁·(x₂ × x₃) only by terms in
  the boundary nodes (both close the same open surface);
- U_contact: :func:`membrax.membrane.contact.node_sphere_normal_energy` (frictionless penalty, the node a
  point on the mid-surface touching when |x − x_i| < R + t_m/2).

Boundary condition: the nodes on the sheet's outline (edges that belong to one triangle) are pinned at
their initial positions (:func:`boundary_nodes`); the others are free in x, y and z.

Indentation depth (:func:`indentation_depth`, :func:`polygon_indentation_depth`): α = (z_top − min z)
over the nodes whose (x, y) lies in a given cell (a rectangle, or a convex polygon such as the triangle of
three touching spheres' centres), z_top = z_sphere + R + t_m/2 the height of the mid-surface resting on
the sphere tops. It is the largest downward deflection of the mid-surface into that cell's void, measured
from the plane of the sphere tops. SI units throughout: m, Pa, N, J.

Lattice geometry, spheres of diameter D touching their neighbours:

- square: centres on a square grid of spacing D; a void is the square of four centres, its centre at
  D/√2 from each;
- triangular: rows of spacing D along x, stacked at h = D√3/2 along y, every other row shifted by D/2;
  each centre has six neighbours at D, and a void is the equilateral triangle of three mutually touching
  centres, its centroid at D/√3 from each (circumradius of a side-D equilateral triangle). The
  triangular void is the smaller: the largest circle between the spheres' outlines in the plane of the
  centres has radius D/√3 − D/2 ≈ 0.077 D against D/√2 − D/2 ≈ 0.207 D for the square one.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from membrax.membrane import energies
from membrax.membrane.contact import node_sphere_normal_energy
from membrax.membrane.mesh import MembraneMesh, flat_mesh

__all__ = [
    "IndentationSolution",
    "projected_volume",
    "sheet_pressure_energy",
    "boundary_nodes",
    "square_sphere_array",
    "triangular_sphere_array",
    "sheet_on_square_array",
    "sheet_on_triangular_array",
    "triangle_voids",
    "nodes_in_polygon",
    "indentation_depth",
    "polygon_indentation_depth",
    "solve_sheet_on_spheres",
]


class IndentationSolution(NamedTuple):
    """Result of :func:`solve_sheet_on_spheres`.

    Attributes:
      position: (n_nodes, 3) equilibrium node positions, m.
      max_overlap: largest node–sphere penalty overlap δ, m (the penalty's error in the contact geometry).
      residual: largest |force| on a free node at the end, N (gradient of Π).
      iterations: L-BFGS-B iterations.
      success: scipy's convergence flag.
    """

    position: np.ndarray
    max_overlap: float
    residual: float
    iterations: int
    success: bool


def projected_volume(position, triangles, reference_height=0.0):
    """Volume between an open triangulated sheet and the plane z = ``reference_height``, m³.

        V = Σ_T A_T^xy (z̄_T − z_ref),   A_T^xy = ½ [(x₂ − x₁)(y₃ − y₁) − (x₃ − x₁)(y₂ − y₁)],

    z̄_T the mean z of the triangle's corners (exact for planar triangles; signed: triangles whose normal
    points down count negative).

    Args:
      position: (N, 3) node positions, m.
      triangles: (T, 3) int node ids.
      reference_height: z_ref, m.
    """
    x1, x2, x3 = (position[triangles[:, k]].T for k in range(3))
    area_xy = 0.5 * ((x2[0] - x1[0]) * (x3[1] - x1[1]) - (x3[0] - x1[0]) * (x2[1] - x1[1]))
    mean_height = (x1[2] + x2[2] + x3[2]) / 3.0
    return jnp.sum(area_xy * (mean_height - reference_height))


def sheet_pressure_energy(position, mesh: MembraneMesh, pressure, reference_height=0.0):
    """Load potential p V of a pressure on the upper face of an open sheet, J (positive p pushes down).

    V from :func:`projected_volume`; with the outline pinned, the forces on the free nodes do not depend
    on ``reference_height``.
    """
    return pressure * projected_volume(position, mesh.triangles, reference_height)


def boundary_nodes(mesh: MembraneMesh) -> np.ndarray:
    """Sorted ids of the nodes on the sheet's outline (ends of edges that belong to a single triangle)."""
    triangles = np.asarray(mesh.triangles)
    edges = np.sort(
        np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1
    )
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return np.unique(unique[counts == 1])


def square_sphere_array(num_per_side: int, diameter: float, centre_xy, height: float = 0.0) -> np.ndarray:
    """Centres of a touching square array of equal spheres, (num_per_side², 3), m.

    Centres at (c_x + (i − (n − 1)/2) D, c_y + (j − (n − 1)/2) D, height), i, j = 0 … n − 1, so the array
    is centred on ``centre_xy``; with n even a void (a cell of four spheres) is centred there.
    """
    offsets = (np.arange(num_per_side) - 0.5 * (num_per_side - 1)) * diameter
    gx, gy = np.meshgrid(centre_xy[0] + offsets, centre_xy[1] + offsets, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)])


def triangular_sphere_array(
    num_per_row: int, num_rows: int, diameter: float, centre_xy, height: float = 0.0
) -> np.ndarray:
    """Centres of a touching triangular (hexagonal close-packed) layer of equal spheres, (S, 3), m.

    Row j = 0 … m − 1 (m = ``num_rows``) lies at y_j = c_y + (j − (m − 1)/2) h, h = D√3/2. Even rows hold
    n = ``num_per_row`` centres at x = c_x + (i − (n − 1)/2) D, i = 0 … n − 1; odd rows are shifted by D/2
    and hold n + 1 centres at x = c_x + (i − n/2) D, i = 0 … n, so they overhang the even rows by D/2 at
    both ends. Every centre is at D from its (up to six) neighbours, the array is symmetric about
    ``centre_xy``, and S = ⌈m/2⌉ n + ⌊m/2⌋ (n + 1).
    """
    row_spacing = 0.5 * math.sqrt(3.0) * diameter
    rows = []
    for j in range(num_rows):
        count = num_per_row + (j % 2)
        x = centre_xy[0] + (np.arange(count) - 0.5 * (count - 1)) * diameter
        y = centre_xy[1] + (j - 0.5 * (num_rows - 1)) * row_spacing
        rows.append(np.column_stack([x, np.full(count, y), np.full(count, height)]))
    return np.concatenate(rows)


def _sheet_on_sphere_tops(
    width: float, length: float, diameter: float, target_edge_length, thickness, contact_offset_factor=1.0
):
    """A flat sheet resting on the tops of spheres of diameter D centred at z = 0, and its (x, y) centre.

    :func:`membrax.membrane.mesh.flat_mesh` of ``width`` × ``length`` lifted to z = R + f t_m/2 (f the
    ``contact_offset_factor`` of :func:`solve_sheet_on_spheres`; a rigid shift:
    the rest quantities are unchanged). The centre is that of its (x, y) bounding box
    [0, width + a/2] × [0, length], m, a the mesh's column spacing (flat_mesh shifts odd rows by a/2);
    the callers centre their sphere arrays on it.
    """
    flat = flat_mesh(width, length, target_edge_length)
    position = flat.reference_position.at[:, 2].set(0.5 * diameter + 0.5 * contact_offset_factor * thickness)
    mesh = dataclasses.replace(flat, reference_position=position)
    xy = np.asarray(position[:, :2])
    return mesh, 0.5 * (xy.min(axis=0) + xy.max(axis=0))


def sheet_on_square_array(
    cells: int, diameter: float, target_edge_length: float, thickness: float, contact_offset_factor=1.0
):
    """A flat sheet over cells × cells of a touching square sphere array, resting on the sphere tops.

    The sheet is :func:`membrax.membrane.mesh.flat_mesh` of side cells·D lifted to z = R + t_m/2 (a rigid
    shift: the rest quantities are unchanged); the (cells + 1)² sphere centres lie at z = 0, centred under
    the sheet's bounding box, so the sheet's outline runs along the outer rows of spheres.

    Returns:
      ``(mesh, sphere_position, cell_min_xy, cell_max_xy)``: the mesh, the (S, 3) centres, and the corners
      of the central cell (for :func:`indentation_depth`; with ``cells`` odd it is a void between four
      spheres).
    """
    mesh, centre = _sheet_on_sphere_tops(
        cells * diameter, cells * diameter, diameter, target_edge_length, thickness, contact_offset_factor
    )
    spheres = square_sphere_array(cells + 1, diameter, centre)
    return mesh, spheres, centre - 0.5 * diameter, centre + 0.5 * diameter


def triangle_voids(sphere_position, diameter: float, tolerance: float = 1e-9) -> np.ndarray:
    """The triangular voids of a touching sphere layer: (V, 3) ids of mutually touching sphere triples.

    Spheres i and j touch when | |x_i − x_j|_xy − D | ≤ ``tolerance`` · D; each triple (i < j < k) of
    mutually touching spheres is listed once, in lexicographic order, as counter-clockwise seen from +z.
    Dense O(S³) booleans: meant for the small arrays of this module.
    """
    xy = np.asarray(sphere_position, dtype=np.float64)[:, :2]
    distance = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    touch = np.abs(distance - diameter) <= tolerance * diameter
    i, j, k = np.nonzero(touch[:, :, None] & touch[:, None, :] & touch[None, :, :])
    triples = np.column_stack([i, j, k])[(i < j) & (j < k)]
    e1, e2 = xy[triples[:, 1]] - xy[triples[:, 0]], xy[triples[:, 2]] - xy[triples[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0.0
    triples[clockwise] = triples[clockwise][:, [0, 2, 1]]
    return triples


def sheet_on_triangular_array(
    cells: int, diameter: float, target_edge_length: float, thickness: float, contact_offset_factor=1.0
):
    """A flat sheet over a touching triangular sphere array (:func:`triangular_sphere_array`), on the tops.

    The sheet is :func:`membrax.membrane.mesh.flat_mesh` of cells·D along x by 2k·h along y (h = D√3/2 the row
    spacing, k = max(1, round(cells/√3)), so that the sheet is nearly square: k rectangular lattice cells
    D × √3 D of two rows each), lifted to z = R + t_m/2. The 2k + 1 rows of spheres (cells + 1 centres in
    the even rows, cells + 2 in the odd ones) lie at z = 0, centred under the sheet's bounding box as in
    :func:`sheet_on_square_array`. The sheet's outline along x runs over the first and last rows of
    centres (touching spheres, as in the square array); along y, where the lattice has no row of touching
    spheres, it runs over the end centres of the even rows and the contact points of the odd rows' two end
    spheres, bisecting the voids between them; the odd rows overhang it by D/2, so that the sheet is
    supported up to its outline. For cells = 3 the sheet is 3D × 2√3 D over 22 spheres.

    Args:
      cells: sheet width in D, >= 3 (so that the measured void is at least h ≈ 0.87 D from the pinned
        outline; fewer puts it against the outline).
      diameter: D, m.
      target_edge_length: mesh edge, m.
      thickness: t_m, m.
      contact_offset_factor: f, the sheet starts at z = R + f t_m/2 (:func:`solve_sheet_on_spheres`).

    Returns:
      ``(mesh, sphere_position, void_xy)``: the mesh, the (S, 3) centres, and the (3, 2) counter-clockwise
      (x, y) corners of the measured void, the triangle of three touching centres whose centroid is the
      nearest to the sheet's centre (ties to the larger y, then the smaller x; for odd cells it lies
      h/3 above the centre); pass it to :func:`polygon_indentation_depth`.
    """
    if cells < 3:
        raise ValueError(f"cells = {cells}: need >= 3 to keep the measured void off the pinned outline")
    rows = 2 * max(1, round(cells / math.sqrt(3.0)))
    mesh, centre = _sheet_on_sphere_tops(
        cells * diameter,
        rows * 0.5 * math.sqrt(3.0) * diameter,
        diameter,
        target_edge_length,
        thickness,
        contact_offset_factor,
    )
    spheres = triangular_sphere_array(cells + 1, rows + 1, diameter, centre)
    voids = triangle_voids(spheres, diameter)
    corners = spheres[voids][:, :, :2]
    centroid = corners.mean(axis=1)
    gap = np.round(np.linalg.norm(centroid - centre[None, :], axis=1) / diameter, 9)
    nearest = np.lexsort((centroid[:, 0], -centroid[:, 1], gap))[0]
    return mesh, spheres, corners[nearest]


def nodes_in_polygon(position, vertices_xy) -> np.ndarray:
    """(N,) bool: the nodes whose (x, y) lies in the closed convex polygon ``vertices_xy`` (K, 2).

    Node p is inside when (v_{k+1} − v_k) × (p − v_k) ≥ 0 for every edge of the counter-clockwise polygon
    (a clockwise one is reversed first); points on an edge count as inside. For an axis-aligned rectangle
    this is exactly cell_min ≤ (x, y) ≤ cell_max (the signs of the differences are exact in floating
    point).
    """
    xy = np.asarray(position)[:, :2]
    vertices = np.asarray(vertices_xy, dtype=xy.dtype).reshape(-1, 2)
    following = np.roll(vertices, -1, axis=0)
    if np.sum(vertices[:, 0] * following[:, 1] - following[:, 0] * vertices[:, 1]) < 0.0:  # clockwise
        vertices = vertices[::-1]
    edge = np.roll(vertices, -1, axis=0) - vertices
    relative = xy[:, None, :] - vertices[None, :, :]
    cross = edge[None, :, 0] * relative[:, :, 1] - edge[None, :, 1] * relative[:, :, 0]
    return np.all(cross >= 0.0, axis=1)


def polygon_indentation_depth(position, vertices_xy, top_height) -> float:
    """α = top_height − min z over the nodes in the convex polygon ``vertices_xy``, m (module docstring).

    Nodes selected by :func:`nodes_in_polygon`; e.g. the void triangle of
    :func:`sheet_on_triangular_array`.
    """
    position = np.asarray(position)
    inside = nodes_in_polygon(position, vertices_xy)
    if not np.any(inside):
        raise ValueError("no node lies in the cell; refine the mesh")
    return float(top_height - np.min(position[inside, 2]))


def indentation_depth(position, cell_min_xy, cell_max_xy, top_height) -> float:
    """α = top_height − min z over the nodes with cell_min ≤ (x, y) ≤ cell_max, m (see module docstring)."""
    (x0, y0), (x1, y1) = np.asarray(cell_min_xy), np.asarray(cell_max_xy)
    return polygon_indentation_depth(position, [[x0, y0], [x1, y0], [x1, y1], [x0, y1]], top_height)


def _positions(u, base, free_rows, length):
    """Node positions from the scaled displacements u of the free rows."""
    return base.at[free_rows].set(base[free_rows] + length * u.reshape(-1, 3))


def _scaled_energy(u, base, free_rows, mesh, spheres, radii, candidates, params, length):
    """Π / (E t L²) as a function of the scaled free displacements u (module docstring)."""
    pressure, modulus, thickness, stiffness, contact_thickness = (params[k] for k in range(5))
    x = _positions(u, base, free_rows, length)
    total = energies.stretching_energy(x, mesh, modulus, thickness)
    total = total + energies.bending_energy(x, mesh, modulus, thickness)
    total = total + sheet_pressure_energy(x, mesh, pressure)
    total = total + node_sphere_normal_energy(x, spheres, radii, candidates, stiffness, contact_thickness)
    return total / (modulus * thickness * length * length)


_value_and_grad = jax.jit(jax.value_and_grad(_scaled_energy))


def solve_sheet_on_spheres(
    mesh: MembraneMesh,
    sphere_position,
    sphere_radius,
    pressure,
    modulus,
    thickness,
    normal_stiffness=1e7,
    initial_position=None,
    length_scale=None,
    max_iterations=5000,
    tolerance=1e-10,
    contact_offset_factor=1.0,
) -> IndentationSolution:
    """Static equilibrium of the sheet on fixed spheres under pressure (module docstring), by L-BFGS-B.

    The outline (:func:`boundary_nodes`) stays at ``mesh.reference_position``; the free nodes start from
    ``initial_position`` (default the reference). Unknowns are scaled by ``length_scale`` (default the
    first sphere's diameter) and the energy by E t L², so the tolerances are dimensionless. Every sphere is
    a contact candidate of every node (dense, exact for the small arrays this is meant for).

    Args:
      mesh: the sheet (e.g. :func:`membrax.membrane.mesh.flat_mesh` lifted onto the sphere tops).
      sphere_position: (S, 3) fixed sphere centres, m.
      sphere_radius: (S,) radii, m.
      pressure: p, Pa (positive pushes down).
      modulus: E_m, Pa.
      thickness: t_m, m.
      normal_stiffness: penalty k_n, N/m (default 1e7: stiffer than the dynamic default 1e5 so that the
        contact overlap stays far below the indentation; see ``max_overlap``).
      initial_position: (n_nodes, 3) start (e.g. the solution at a lower pressure), m.
      length_scale: L, m.
      max_iterations: L-BFGS-B iteration cap.
      tolerance: L-BFGS-B ``ftol`` on the scaled energy (``gtol`` is 100 × smaller).
      contact_offset_factor: nodes touch spheres at R + f t_m/2 (1: the sheet's lower face on the sphere;
        0: its nodes, the mid-surface, on the sphere surface; as in :mod:`membrax.membrane.coupled`).
    """
    reference = jnp.asarray(mesh.reference_position)
    dtype = reference.dtype
    n = reference.shape[0]
    spheres = jnp.asarray(sphere_position, dtype=dtype)
    radii = jnp.asarray(sphere_radius, dtype=dtype)
    num_spheres = spheres.shape[0]
    candidates = jnp.tile(jnp.arange(num_spheres, dtype=jnp.int32)[None, :], (n, 1))
    free = np.ones(n, dtype=bool)
    free[boundary_nodes(mesh)] = False
    free_rows = jnp.asarray(np.flatnonzero(free))
    length = float(np.asarray(radii)[0]) * 2.0 if length_scale is None else float(length_scale)
    start = reference if initial_position is None else jnp.asarray(initial_position, dtype=dtype)
    contact_thickness = contact_offset_factor * thickness
    params = jnp.asarray([pressure, modulus, thickness, normal_stiffness, contact_thickness], dtype=dtype)

    data = (start, free_rows, mesh, spheres, radii, candidates, params, jnp.asarray(length, dtype=dtype))

    def objective(u):
        value, grad = _value_and_grad(jnp.asarray(u, dtype=dtype), *data)
        return float(value), np.asarray(grad, dtype=np.float64)

    result = minimize(
        objective,
        np.zeros(3 * int(free.sum())),
        jac=True,
        method="L-BFGS-B",
        options={
            "maxiter": max_iterations,
            "maxfun": 2 * max_iterations,
            "ftol": tolerance,
            "gtol": 1e-2 * tolerance,
        },
    )
    u = jnp.asarray(result.x, dtype=dtype)
    x = _positions(u, start, free_rows, data[-1])
    distance = jnp.linalg.norm(x[:, None, :] - spheres[None, :, :], axis=-1)
    overlap = jnp.max(radii[None, :] + 0.5 * contact_thickness - distance)
    _, grad = _value_and_grad(u, *data)
    residual = float(jnp.max(jnp.abs(grad))) * modulus * thickness * length
    return IndentationSolution(
        position=np.asarray(x),
        max_overlap=max(float(overlap), 0.0),
        residual=residual,
        iterations=int(result.nit),
        success=bool(result.success),
    )
