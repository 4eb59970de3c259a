"""Membrane indentation into a square and a triangular array of spheres (membrax.membrane.indentation).

The issue's test: a sheet pressed by pressure onto a fixed array of spheres (square, or triangular: a
hexagonal close-packed layer) indents deeper with pressure and less with thickness. Asserted: the
pressure potential's forces (a hand check, exact to round-off), the triangular lattice and its voids by
hand, monotonicity in p and t_m for both arrays, a sub-linear positive exponent d ln α / d ln p (square),
that the smaller triangular void is indented less than the square one at the same p and t_m, and that
the penalty contact does not blur the geometry. Molenkamp & Luger's α/D and exponent 1/3 are printed
beside the simulated values, not asserted (their constant spans 0.15–0.4; the example
examples/membrane_indentation.py fits both arrays' exponents on finer meshes).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax import theory
from membrax.membrane import indentation
from membrax.membrane.mesh import band_volume, flat_mesh

DIAMETER = 0.025
RADIUS = 0.5 * DIAMETER
MODULUS = 1.4e6
THICKNESSES = (2.5e-3, 5e-3)
PRESSURES = np.array([10e3, 40e3, 100e3])


def _perturbed_sheet(seed):
    """A flat 40 × 30 mm sheet: interior nodes moved in x, y, z; outline nodes moved in z only."""
    mesh = flat_mesh(0.04, 0.03, 0.005)
    rng = np.random.default_rng(seed)
    shift = 1e-3 * rng.standard_normal(mesh.reference_position.shape)
    shift[indentation.boundary_nodes(mesh), :2] = 0.0
    return mesh, mesh.reference_position + jnp.asarray(shift)


def test_pressure_potential_gives_p_times_projected_area_and_consistent_nodal_loads():
    """Hand check of V = Σ A_xy (z̄ − z_ref): total force (0, 0, −p A), interior loads −p Σ A n / 3.

    With the outline moved only vertically, the projected area of the sheet is that of the flat patch
    (the sum of the rest areas), so the pressure's resultant is exactly −p A ẑ: positive p pushes down.
    On interior nodes the force equals the consistent load of the cone volume (1/6) Σ x₁·(x₂ × x₃)
    (:func:`membrax.membrane.mesh.band_volume`) and does not depend on the reference plane.
    """
    mesh, position = _perturbed_sheet(0)
    pressure = 70e3
    area = float(jnp.sum(mesh.reference_area))
    force = -jax.grad(indentation.sheet_pressure_energy)(position, mesh, pressure)
    total = np.asarray(jnp.sum(force, axis=0))
    np.testing.assert_allclose(total, [0.0, 0.0, -pressure * area], rtol=0.0, atol=1e-10 * pressure * area)

    interior = np.setdiff1d(np.arange(mesh.num_nodes), indentation.boundary_nodes(mesh))
    cone = -pressure * jax.grad(band_volume)(position, mesh)
    shifted = -jax.grad(indentation.sheet_pressure_energy)(position, mesh, pressure, -0.3)
    scale = pressure * area / interior.size
    np.testing.assert_allclose(np.asarray(force[interior]), np.asarray(cone[interior]), atol=1e-10 * scale)
    np.testing.assert_allclose(np.asarray(force[interior]), np.asarray(shifted[interior]), atol=1e-10 * scale)


def test_boundary_nodes_of_flat_mesh_are_its_outline():
    mesh = flat_mesh(0.04, 0.03, 0.005)
    position = np.asarray(mesh.reference_position)
    outline = indentation.boundary_nodes(mesh)
    rows = position.reshape(-1, mesh.bottom_ring.shape[0], 3)
    expected = {*np.asarray(mesh.bottom_ring).tolist(), *np.asarray(mesh.top_ring).tolist()}
    columns = rows.shape[1]
    expected |= {r * columns for r in range(rows.shape[0])} | {
        r * columns + columns - 1 for r in range(rows.shape[0])
    }
    assert set(outline.tolist()) == expected


def _depth_series(mesh, spheres, thickness, pressures, measure, *cell):
    """α at each pressure (each solve starts from the previous one), k_n = 1e6 N/m, E_m = 1400 kPa.

    ``measure(position, *cell, top_height)`` is :func:`indentation.indentation_depth` or
    :func:`indentation.polygon_indentation_depth`.
    """
    previous, depth = None, np.zeros(len(pressures))
    for j, pressure in enumerate(pressures):
        solution = indentation.solve_sheet_on_spheres(
            mesh,
            spheres,
            np.full(spheres.shape[0], RADIUS),
            float(pressure),
            MODULUS,
            thickness,
            normal_stiffness=1e6,
            initial_position=previous,
        )
        previous = solution.position
        assert solution.success
        depth[j] = measure(solution.position, *cell, RADIUS + 0.5 * thickness)
        # the penalty's overlap is a small error on the indentation
        assert solution.max_overlap < 0.01 * depth[j]
    return depth


@functools.cache
def _square_depths():
    """α (len(THICKNESSES), len(PRESSURES)) in the central void of 3 × 3 square cells, edge D/6."""
    depth = np.zeros((len(THICKNESSES), PRESSURES.size))
    for i, thickness in enumerate(THICKNESSES):
        mesh, spheres, low, high = indentation.sheet_on_square_array(3, DIAMETER, DIAMETER / 6, thickness)
        depth[i] = _depth_series(
            mesh, spheres, thickness, PRESSURES, indentation.indentation_depth, low, high
        )
    depth.setflags(write=False)
    return depth


def test_indentation_grows_with_pressure_and_falls_with_thickness():
    """3 × 3 cells of D = 25 mm spheres, edge D/6, outline pinned; α in the central void.

    E_m = 1400 kPa, t_m = 2.5 and 5 mm, p = 10, 40, 100 kPa (each pressure starts from the previous
    solution), frictionless penalty k_n = 1e6 N/m. α/D ≈ 0.146, 0.233, 0.315 (2.5 mm) and 0.051, 0.129,
    0.195 (5 mm).
    """
    void_ratio = 6.0 / np.pi - 1.0  # simple cubic: the square array's void ratio
    depth = _square_depths()
    print("\n t_m/mm  p/kPa  alpha/D (sim)  alpha/D (M&L)")
    for i, thickness in enumerate(THICKNESSES):
        for j, pressure in enumerate(PRESSURES):
            ratio = float(
                theory.molenkamp_luger_indentation_ratio(void_ratio, DIAMETER, thickness, pressure, MODULUS)
            )
            print(
                f"{thickness * 1e3:7.1f} {pressure / 1e3:6.0f} {depth[i, j] / DIAMETER:14.4f} {ratio:14.4f}"
            )

    assert np.all(depth > 0.0)
    assert np.all(np.diff(depth, axis=1) > 0.0), "α must grow with p"
    assert np.all(depth[1] < depth[0]), "α must fall with t_m"
    for i, thickness in enumerate(THICKNESSES):
        exponent = np.polyfit(np.log(PRESSURES), np.log(depth[i]), 1)[0]
        print(f"t_m = {thickness * 1e3:g} mm: d ln(alpha)/d ln(p) = {exponent:.3f} (Molenkamp & Luger: 1/3)")
        # sub-linear: the membrane stiffens as it stretches (and it cannot pass through the spheres)
        assert 0.0 < exponent < 1.0
    # the deepest indentation stays inside the void: above the sphere centres' plane
    assert np.all(depth < RADIUS + 0.5 * max(THICKNESSES))


def test_triangular_lattice_by_hand():
    """3 rows of 3 (+ 1 in the odd row) touching spheres, and the voids of the sheet's array.

    By hand, h = D√3/2: rows at y = −h, 0, h; x = −D, 0, D in the outer rows and ±D/2, ±3D/2 in the middle
    one. Nearest neighbours at D, six of them around each of the two middle spheres. Between a row of 3
    and a row of 4 there are 3 + 4 − 2 = 5 voids, so 10 in all; each is equilateral of side D, its
    centroid at D/√3 from its three centres, its area √3 D²/4 ≈ 0.433 D² (the square void: D²).
    """
    h = 0.5 * np.sqrt(3.0) * DIAMETER
    centre = np.array([0.1, -0.2])
    spheres = indentation.triangular_sphere_array(3, 3, DIAMETER, centre, height=0.3)
    expected = [(x, -h) for x in (-1.0, 0.0, 1.0)] + [(x, 0.0) for x in (-1.5, -0.5, 0.5, 1.5)]
    expected += [(x, h) for x in (-1.0, 0.0, 1.0)]
    expected = np.array([(x * DIAMETER, y) for x, y in expected]) + centre[None, :]
    np.testing.assert_allclose(spheres[:, :2], expected, rtol=0.0, atol=1e-15)
    np.testing.assert_array_equal(spheres[:, 2], 0.3)

    distance = np.linalg.norm(spheres[:, None, :] - spheres[None, :, :], axis=-1)
    np.fill_diagonal(distance, np.inf)
    np.testing.assert_allclose(distance.min(axis=1), DIAMETER, rtol=1e-12)
    neighbours = np.sum(np.isclose(distance, DIAMETER, rtol=1e-12), axis=1)
    np.testing.assert_array_equal(neighbours, [3, 4, 3, 3, 6, 6, 3, 3, 4, 3])

    voids = indentation.triangle_voids(spheres, DIAMETER)
    assert voids.shape == (10, 3)
    corners = spheres[voids][:, :, :2]
    sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=-1)
    np.testing.assert_allclose(sides, DIAMETER, rtol=1e-12)
    to_centroid = np.linalg.norm(corners - corners.mean(axis=1, keepdims=True), axis=-1)
    np.testing.assert_allclose(to_centroid, DIAMETER / np.sqrt(3.0), rtol=1e-12)
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    np.testing.assert_allclose(  # counter-clockwise, area √3 D²/4
        0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]), np.sqrt(3.0) / 4.0 * DIAMETER**2, rtol=1e-12
    )

    # the sheet's array: 3D × 2√3 D, 5 rows (4 + 5 + 4 + 5 + 4 spheres), the measured void nearest its centre
    mesh, spheres, void = indentation.sheet_on_triangular_array(3, DIAMETER, DIAMETER / 6, 2.5e-3)
    xy = np.asarray(mesh.reference_position)[:, :2]
    np.testing.assert_allclose(np.ptp(xy[:, 1]), 4.0 * h, rtol=1e-12)
    assert spheres.shape == (22, 3)
    np.testing.assert_allclose(np.ptp(spheres[:, 1]), 4.0 * h, rtol=1e-12)
    np.testing.assert_allclose(spheres[:, 2], 0.0)
    np.testing.assert_allclose(mesh.reference_position[:, 2], RADIUS + 1.25e-3)
    centroid = void.mean(axis=0)
    np.testing.assert_allclose(np.linalg.norm(void - centroid, axis=1), DIAMETER / np.sqrt(3.0), rtol=1e-12)
    middle = 0.5 * (xy.min(axis=0) + xy.max(axis=0))
    np.testing.assert_allclose(centroid - middle, [0.0, h / 3.0], atol=1e-15)  # the void above the centre
    is_corner = np.all(np.isclose(spheres[:, None, :2], void[None, :, :], rtol=0.0, atol=1e-15), axis=-1)
    np.testing.assert_array_equal(is_corner.sum(axis=0), 1)  # each corner is a sphere centre
    inside = indentation.nodes_in_polygon(mesh.reference_position, void)
    assert 10 < inside.sum() < 40  # about area / (√3 a²/2) = 0.433 D² / (0.024 D²) ≈ 18 nodes
    np.testing.assert_array_equal(indentation.nodes_in_polygon(mesh.reference_position, void[::-1]), inside)
    with pytest.raises(ValueError, match="cells = 2"):
        indentation.sheet_on_triangular_array(2, DIAMETER, DIAMETER / 6, 2.5e-3)


def test_rectangle_depth_is_polygon_depth():
    """indentation_depth(low, high) = polygon_indentation_depth of the rectangle; edges count as inside."""
    _, position = _perturbed_sheet(1)
    position = np.array(position)
    low, high = np.array([0.01, 0.005]), np.array([0.03, 0.02])
    position[7, :2] = low  # a node on a corner
    position[7, 2] = -0.5
    rectangle = [low, [high[0], low[1]], high, [low[0], high[1]]]
    assert indentation.indentation_depth(position, low, high, 0.1) == pytest.approx(0.6, rel=1e-15)
    inside = (position[:, :2] >= low).all(axis=1) & (position[:, :2] <= high).all(axis=1)
    np.testing.assert_array_equal(indentation.nodes_in_polygon(position, rectangle), inside)
    np.testing.assert_array_equal(indentation.nodes_in_polygon(position, rectangle[::-1]), inside)


def test_triangular_indentation_grows_with_pressure_falls_with_thickness_and_is_below_square():
    """3 cells (3D × 2√3 D sheet, 22 spheres), edge D/6, α in the void nearest the centre.

    E_m = 1400 kPa, t_m = 2.5 and 5 mm, p = 10 and 40 kPa, k_n = 1e6 N/m. α/D ≈ 0.113, 0.175 (2.5 mm)
    and 0.037, 0.092 (5 mm), against 0.146, 0.233 and 0.051, 0.129 in the square array's void: the
    triangular void (three centres at D/√3) is smaller than the square one (four at D/√2), so at the same
    p and t_m the sheet indents it less.
    """
    pressures = PRESSURES[:2]
    depth = np.zeros((len(THICKNESSES), pressures.size))
    for i, thickness in enumerate(THICKNESSES):
        mesh, spheres, void = indentation.sheet_on_triangular_array(3, DIAMETER, DIAMETER / 6, thickness)
        depth[i] = _depth_series(
            mesh, spheres, thickness, pressures, indentation.polygon_indentation_depth, void
        )
    print("\ntriangular alpha/D:", np.round(depth / DIAMETER, 4).tolist())
    assert np.all(depth > 0.0)
    assert np.all(np.diff(depth, axis=1) > 0.0), "α must grow with p"
    assert np.all(depth[1] < depth[0]), "α must fall with t_m"
    square = _square_depths()[:, :2]
    assert np.all(depth < square), "the triangular void is the smaller: α must be below the square's"
