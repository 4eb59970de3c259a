"""Membrane measurements (membrax.membrane.measure): each test checks numbers against a hand calculation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tolerance

from membrax.membrane import energies, records
from membrax.membrane import measure as mm
from membrax.membrane.coupled import platen_reaction
from membrax.membrane.mesh import cylinder_mesh, enclosed_volume, flat_mesh
from membrax.spheres.measure import principal_axisymmetric

# jitted once: eager dispatch of these many small ops is slower than one compilation
distance_to_triangle = jax.jit(mm.point_triangle_distance)
penetration_of = jax.jit(mm.sphere_penetration)
stretches_of = jax.jit(mm.triangle_stretches)
radial_strain_of = jax.jit(mm.radial_strain)
indentation_of = jax.jit(mm.indentation_field, static_argnums=2)
max_penetration_and_gradient = jax.jit(jax.value_and_grad(mm.max_sphere_penetration, argnums=2))
membrane_forces = jax.jit(energies.nodal_forces, static_argnames=("model",))

# ------------------------------------------------------------------------------------- point–triangle


def _triangle():
    """A scalene triangle in a general orientation, with its unit normal."""
    a = np.array([0.1, -0.2, 0.3])
    b = np.array([1.3, 0.1, -0.2])
    c = np.array([0.4, 0.9, 0.5])
    normal = np.cross(b - a, c - a)
    return a, b, c, normal / np.linalg.norm(normal)


def _distance(points, a, b, c):
    """point_triangle_distance on rows (P ≤ 64, 3) of points against one triangle (padded: one compile)."""
    corner = [jnp.asarray(x)[:, None] for x in (a, b, c)]
    padded = np.zeros((64, 3))
    padded[: len(points)] = points
    return np.asarray(distance_to_triangle(jnp.asarray(padded).T, *corner))[: len(points)]


def _brute_force(points, a, b, c, divisions):
    """min over a barycentric grid with spacing 1/divisions; overestimates by at most max edge/divisions."""
    i, j = np.meshgrid(np.arange(divisions + 1), np.arange(divisions + 1), indexing="ij")
    keep = i + j <= divisions
    u, v = i[keep] / divisions, j[keep] / divisions
    samples = a[None] + u[:, None] * (b - a)[None] + v[:, None] * (c - a)[None]
    return np.array([np.min(np.linalg.norm(samples - p[None], axis=1)) for p in points])


def test_point_triangle_distance_in_every_voronoi_region():
    a, b, c, n = _triangle()
    points, expected = [], []
    for h in (0.37, -0.37, 0.0):  # both sides and in the plane
        # vertex regions: along the outward bisector of the two edges, distance √(α² |ê₁ + ê₂|² + h²)
        for vertex, p, q in ((a, b, c), (b, c, a), (c, a, b)):
            bisector = -(p - vertex) / np.linalg.norm(p - vertex) - (q - vertex) / np.linalg.norm(q - vertex)
            points.append(vertex + 0.25 * bisector + h * n)
            expected.append(np.hypot(0.25 * np.linalg.norm(bisector), h))
        # edge regions: from the edge midpoint along the in-plane outward normal, distance √(α² + h²)
        for start, end in ((a, b), (b, c), (c, a)):
            outward = np.cross(end - start, n)
            outward /= np.linalg.norm(outward)
            points.append(0.5 * (start + end) + 0.2 * outward + h * n)
            expected.append(np.hypot(0.2, h))
        # face region: above/below the centroid at height h
        points.append((a + b + c) / 3.0 + h * n)
        expected.append(abs(h))
    points = np.array(points)
    distance = _distance(points, a, b, c)
    np.testing.assert_allclose(distance, expected, rtol=1e-13, atol=1e-15)
    assert np.sum(distance < 1e-15) == 1  # the in-plane centroid
    # and the brute-force minimum over a dense barycentric grid agrees within its sampling bound
    divisions = 300
    bound = max(np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c)) / divisions
    brute = _brute_force(points, a, b, c, divisions)
    assert np.all(brute >= distance - 1e-14)
    assert np.all(brute - distance <= bound)
    # gradients (Danskin: the closest point's weights held fixed) against central differences of Σ d,
    # leaving out the point on the face (d = 0 is a kink of |p − q|)
    points = points[distance > 1e-12]
    gradient = jax.jit(jax.grad(lambda *x: jnp.sum(mm.point_triangle_distance(*x)), argnums=(1, 2, 3)))
    analytic = gradient(jnp.asarray(points).T, *(jnp.asarray(x)[:, None] for x in (a, b, c)))
    step = 1e-6
    for k in range(3):
        for axis in range(3):
            shifted = [a.copy(), b.copy(), c.copy()]
            shifted[k][axis] += step
            plus = np.sum(_distance(points, *shifted))
            shifted[k][axis] -= 2.0 * step
            minus = np.sum(_distance(points, *shifted))
            assert float(analytic[k][axis, 0]) == pytest.approx((plus - minus) / (2.0 * step), abs=1e-7)


def test_point_triangle_distance_random_points_against_brute_force():
    a, b, c, _ = _triangle()
    rng = np.random.default_rng(3)
    points = rng.uniform(-1.0, 2.0, size=(60, 3))
    divisions = 300
    bound = max(np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c)) / divisions
    distance = _distance(points, a, b, c)
    brute = _brute_force(points, a, b, c, divisions)
    assert np.all(brute >= distance - 1e-14)
    assert np.max(brute - distance) <= bound  # bound ≈ 5e-3; the typical gap is far smaller


def test_point_above_centroid_and_degenerate_triangles():
    a, b, c, n = _triangle()
    centroid = (a + b + c) / 3.0
    assert _distance((centroid + 0.123 * n)[None], a, b, c)[0] == pytest.approx(0.123, rel=1e-14)
    p = np.array([0.3, 0.8, -0.4])
    o = np.array([0.1, 0.2, 0.3])
    e = np.array([1.0, 2.0, -1.0]) / np.sqrt(6.0)
    # a point triangle: |p − o|
    assert _distance(p[None], o, o, o)[0] == pytest.approx(np.linalg.norm(p - o), rel=1e-14)
    # collinear, c between a and b, and a = b: the distance to the segment [o, o + 2e]
    t = np.clip(np.dot(p - o, e), 0.0, 2.0)
    to_segment = np.linalg.norm(p - o - t * e)
    assert 0.0 < t < 2.0
    assert _distance(p[None], o, o + 2.0 * e, o + 0.7 * e)[0] == pytest.approx(to_segment, rel=1e-12)
    assert _distance(p[None], o, o, o + 2.0 * e)[0] == pytest.approx(to_segment, rel=1e-12)
    # gradients stay finite on degenerate triangles and equal the unit vector from the closest point
    corners = [jnp.asarray(x) for x in (o, o, o + 2.0 * e)]
    gradient = jax.jit(jax.grad(lambda q: mm.point_triangle_distance(q, *corners)))
    g = np.asarray(gradient(jnp.asarray(p)))
    np.testing.assert_allclose(g, (p - o - t * e) / to_segment, rtol=1e-12)


# ----------------------------------------------------------------------------------- sphere penetration


def _sheet():
    mesh = flat_mesh(0.4, 0.4, 0.1)
    return mesh, np.asarray(mesh.reference_position), np.asarray(mesh.triangles)


def _candidates(num_nodes, listing, num_spheres, capacity=3):
    """Dense (n_nodes, K) table padded with N from {node: [sphere ids]}."""
    idx = np.full((num_nodes, capacity), num_spheres, dtype=np.int32)
    for node, ids in listing.items():
        idx[node, : len(ids)] = ids
    return jnp.asarray(idx)


def _penetration_case():
    """Sphere 0 above triangle 5 (P = R − z), sphere 1 resting under triangle 30 (P = −t/2),
    sphere 2 large and close but in no candidate list (also the sphere a clamped padding id would hit)."""
    mesh, x, tri = _sheet()
    thickness = 0.004
    radius = np.array([0.05, 0.03, 1.0])
    above = x[tri[5]].mean(axis=0) + np.array([0.0, 0.0, 0.03])
    below = x[tri[30]].mean(axis=0) - np.array([0.0, 0.0, 0.03 + 0.5 * thickness])
    spheres = np.array([above, below, [0.2, 0.2, 0.5]])
    listing = {int(k): [0] for k in tri[5]}
    listing.update({int(k): [1] for k in tri[30]})
    idx = _candidates(mesh.num_nodes, listing, num_spheres=3)
    args = (mesh.reference_position, mesh.triangles, jnp.asarray(spheres), jnp.asarray(radius), idx)
    return mesh, tri, thickness, listing, args


def test_sphere_penetration_flat_sheet():
    _, tri, thickness, listing, args = _penetration_case()
    assert not set(tri[5]) & set(tri[30])
    penetration = np.asarray(penetration_of(*args))
    assert penetration[5] == pytest.approx(0.05 - 0.03, abs=1e-15)  # foot inside: R − z
    assert penetration[30] == pytest.approx(-0.5 * thickness, abs=1e-15)  # resting: −t_m/2
    # triangles that share a node with a listing see the sphere farther away (foot outside them)
    listed = np.array([any(int(k) in listing for k in t) for t in tri])
    assert np.all(np.isfinite(penetration) == listed)
    near_5 = np.array([bool(set(t) & set(tri[5])) for t in tri])
    near_5[5] = False
    assert np.all(penetration[near_5] < 0.02)
    assert np.all(penetration[near_5] > 0.05 - np.hypot(0.03, 0.1))  # within one edge of the foot
    # the unlisted sphere 2 (R = 1 m, 0.5 m away: P = +0.5 m) and the padding are ignored;
    # ∂P/∂z_sphere = −1 (face region), ∂P/∂x = ∂P/∂y = 0
    largest, gradient = max_penetration_and_gradient(*args)
    assert float(largest) == pytest.approx(0.02, abs=1e-15)
    np.testing.assert_allclose(np.asarray(gradient[0]), [0.0, 0.0, -1.0], atol=1e-14)
    np.testing.assert_allclose(np.asarray(gradient[1:]), 0.0, atol=0.0)


def test_sphere_penetration_vertex_region():
    # the sheet's corner node 0 belongs to triangle 0 only; a sphere beyond the corner sees the vertex
    mesh, x, tri = _sheet()
    assert np.sum(np.any(tri == 0, axis=1)) == 1 and 0 in tri[0]
    centre = np.array([[-0.03, -0.02, 0.01], [0.2, 0.2, 0.5], [0.2, 0.2, -0.5]])  # 1 and 2 unlisted
    idx = _candidates(mesh.num_nodes, {0: [0]}, num_spheres=3)
    radius = jnp.asarray([0.05, 1.0, 1.0])
    penetration = np.asarray(
        penetration_of(mesh.reference_position, mesh.triangles, jnp.asarray(centre), radius, idx)
    )
    assert penetration[0] == pytest.approx(0.05 - np.linalg.norm(centre[0] - x[0]), rel=1e-14)
    assert np.all(np.isneginf(penetration[1:]))


def test_sphere_penetration_jit_and_vmap():
    _, _, _, _, args = _penetration_case()
    shifts = jnp.asarray([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01], [0.0, 0.0, -0.02]])
    nodes = args[0][None] + shifts[:, None, :]
    batched = jax.jit(jax.vmap(mm.sphere_penetration, in_axes=(0, None, None, None, None)))(nodes, *args[1:])
    for k in range(3):
        eager = np.asarray(mm.sphere_penetration(nodes[k], *args[1:]))
        np.testing.assert_allclose(np.asarray(penetration_of(nodes[k], *args[1:])), eager, rtol=1e-14)
        np.testing.assert_allclose(np.asarray(batched[k]), eager, rtol=1e-14)
    np.testing.assert_allclose(np.asarray(batched[1, 5]), 0.03, rtol=1e-13)  # sheet 1 cm up: R − 2 cm


# ------------------------------------------------------------------------------------------- stretches


def _rotation(angle_z, angle_x):
    cz, sz, cx, sx = np.cos(angle_z), np.sin(angle_z), np.cos(angle_x), np.sin(angle_x)
    about_z = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return jnp.asarray(about_x @ about_z)


def test_triangle_stretches_biaxial_rotation_shear():
    mesh = flat_mesh(0.3, 0.25, 0.05)
    x0 = mesh.reference_position
    biaxial = x0 * jnp.asarray([1.2, 0.9, 1.0])[None]
    major, minor = stretches_of(biaxial, mesh)
    np.testing.assert_allclose(np.asarray(major), 1.2, atol=1e-12)
    np.testing.assert_allclose(np.asarray(minor), 0.9, atol=1e-12)
    rotation = _rotation(0.7, -1.1)
    for position, expected in ((x0 @ rotation.T, (1.0, 1.0)), (biaxial @ rotation.T, (1.2, 0.9))):
        major, minor = stretches_of(position + jnp.asarray([0.1, -0.2, 0.3])[None], mesh)
        np.testing.assert_allclose(np.asarray(major), expected[0], atol=1e-12)
        np.testing.assert_allclose(np.asarray(minor), expected[1], atol=1e-12)
    # simple shear x += γ y: λ₁ = γ/2 + √(1 + γ²/4), λ₂ = 1/λ₁
    gamma = 0.3
    sheared = x0 + gamma * x0[:, 1:2] * jnp.asarray([1.0, 0.0, 0.0])[None]
    major, minor = stretches_of(sheared, mesh)
    expected = gamma / 2.0 + np.sqrt(1.0 + gamma**2 / 4.0)
    np.testing.assert_allclose(np.asarray(major), expected, atol=1e-12)
    np.testing.assert_allclose(np.asarray(minor), 1.0 / expected, atol=1e-12)
    # gradients are finite at the equibiaxial rest state (repeated eigenvalue)
    gradient = jax.jit(jax.grad(lambda x: jnp.sum(mm.triangle_stretches(x, mesh)[0])))(x0)
    assert np.all(np.isfinite(np.asarray(gradient)))


def test_triangle_stretches_jit_and_vmap():
    mesh = flat_mesh(0.3, 0.25, 0.05)  # a randomly perturbed sheet
    x0 = mesh.reference_position
    rng = np.random.default_rng(0)
    positions = x0[None] + jnp.asarray(rng.normal(scale=5e-3, size=(3, *x0.shape)))
    eager = [mm.triangle_stretches(p, mesh) for p in positions]
    jitted = stretches_of(positions[0], mesh)
    batched = jax.jit(jax.vmap(mm.triangle_stretches, in_axes=(0, None)))(positions, mesh)
    for k in range(2):
        np.testing.assert_allclose(np.asarray(jitted[k]), np.asarray(eager[0][k]), rtol=1e-14)
        for b in range(3):
            np.testing.assert_allclose(np.asarray(batched[k][b]), np.asarray(eager[b][k]), rtol=1e-14)


# ---------------------------------------------------------------------------------------------- radius


def test_mean_radius_of_the_rest_cylinder_and_radial_strain():
    radius, height = 0.1, 0.2
    mesh = cylinder_mesh(radius, height, 0.01)
    n = mesh.bottom_ring.shape[0]
    x0 = mesh.reference_position
    # rings: regular n-gons, A = (n/2) R² sin(2π/n). Successive rings are turned by π/n, so each layer is
    # a prismatoid with a mid-section 2n-gon of circumradius R cos(π/2n): A_mid = n R² cos²(π/2n) sin(π/n),
    # V = H (A + 2 A_mid)/3, r = √(V/(πH)).
    ring_area = 0.5 * n * radius**2 * np.sin(2.0 * np.pi / n)
    mid_area = n * radius**2 * np.cos(np.pi / (2 * n)) ** 2 * np.sin(np.pi / n)
    r0 = float(jax.jit(mm.mean_radius)(x0, mesh))
    assert r0 == pytest.approx(np.sqrt((ring_area + 2.0 * mid_area) / (3.0 * np.pi)), rel=1e-13)
    # the ring polygon alone, R √(n sin(2π/n)/(2π)), misses the zigzag's bulge by ≈ (π/n)²/12 in r
    polygon_radius = radius * np.sqrt(n * np.sin(2.0 * np.pi / n) / (2.0 * np.pi))
    assert r0 / polygon_radius - 1.0 == pytest.approx((np.pi / n) ** 2 / 12.0, rel=0.01)
    # uniform radial scaling by 1 + s: ε_r = −s; axial scaling leaves r unchanged
    s = 0.037
    assert float(radial_strain_of(x0 * jnp.asarray([1 + s, 1 + s, 1.0])[None], mesh)) == pytest.approx(
        -s, abs=1e-14
    )
    assert float(radial_strain_of(x0 * jnp.asarray([1.0, 1.0, 0.8])[None], mesh, r0)) == pytest.approx(
        0.0, abs=1e-14
    )


# ----------------------------------------------------------------------------------------- indentation


def test_indentation_field():
    radius = 0.1
    mesh = cylinder_mesh(radius, 0.2, 0.01)
    n = mesh.bottom_ring.shape[0]
    rows = mesh.num_nodes // n
    x0 = mesh.reference_position
    normal = jax.jit(mm.rest_outward_normal)(mesh)
    np.testing.assert_allclose(
        np.asarray(normal[:, :2]), np.asarray(x0[:, :2]) / radius, atol=1e-14
    )  # radial
    field = indentation_of
    # uniform radial expansion: u_n = s R everywhere, no indentation
    expanded = x0 * jnp.asarray([1.05, 1.05, 1.0])[None]
    np.testing.assert_allclose(
        np.asarray(jax.jit(mm.normal_displacement)(expanded, mesh)), 0.05 * radius, rtol=1e-12
    )
    np.testing.assert_allclose(np.asarray(field(expanded, mesh, 3)), 0.0, atol=1e-15)
    # one node pushed in by δ: indentation δ there, 0 elsewhere
    delta, node = 2e-3, 10 * n + 30
    pushed = x0.at[node].add(-delta * normal[node])
    indentation = np.asarray(field(pushed, mesh, 3))
    assert indentation[node] == pytest.approx(delta, rel=1e-12)
    assert np.max(np.abs(np.delete(indentation, node))) < 1e-15
    # one node lifted by δ at column 0: its window (±3 rows, ±3 columns, wrapping to columns n−3…n−1)
    # is δ deep, everything else 0
    lifted_node = 12 * n
    lifted = np.asarray(field(x0.at[lifted_node].add(delta * normal[lifted_node]), mesh, 3)).reshape(rows, n)
    expected = np.zeros((rows, n))
    expected[9:16, [0, 1, 2, 3, n - 3, n - 2, n - 1]] = delta
    expected[12, 0] = 0.0
    np.testing.assert_allclose(lifted, expected, atol=1e-15)
    # a radial sinusoid u_n = a cos(7θ) (n = 63: 9 columns per lobe): peaks (even rows, columns 0, 9, …)
    # are outermost, troughs (odd rows, column 4.5 ≙ index 4) sit 2a deep for a window reaching a peak
    assert n == 63
    a = 1e-3
    angle = np.arctan2(np.asarray(x0[:, 1]), np.asarray(x0[:, 0]))
    wavy = x0 + jnp.asarray(a * np.cos(7.0 * angle))[:, None] * normal
    indentation = np.asarray(field(wavy, mesh, 5)).reshape(rows, n)
    np.testing.assert_allclose(indentation[2:-2:2, ::9], 0.0, atol=1e-15)
    np.testing.assert_allclose(indentation[1:-1:2, 4::9], 2.0 * a, rtol=1e-12)


# ----------------------------------------------------------------------------------------------- platens


def test_platen_reaction_closed_cylinder_under_internal_pressure():
    radius, pressure = 0.1, 1e4
    mesh = cylinder_mesh(radius, 0.2, 0.01)
    n = mesh.bottom_ring.shape[0]
    x0 = mesh.reference_position
    # internal pressure p (cell_pressure = −p) at the rest shape: no stretching or bending force
    force = membrane_forces(x0, mesh, 1e6, 1e-3, -pressure)
    bottom, top = platen_reaction(force, mesh)
    # end load p A on each platen, pushing the top up and the bottom down. For the faceted mesh A is the
    # mean section of the end layer, (A_ring + 2 A_mid)/3 (cap share + the tilted band triangles' share)
    ring_area = 0.5 * n * radius**2 * np.sin(2.0 * np.pi / n)
    mid_area = n * radius**2 * np.cos(np.pi / (2 * n)) ** 2 * np.sin(np.pi / n)
    end_load = pressure * (ring_area + 2.0 * mid_area) / 3.0
    np.testing.assert_allclose(np.asarray(top), [0.0, 0.0, end_load], rtol=1e-12, atol=1e-12 * end_load)
    np.testing.assert_allclose(np.asarray(bottom), [0.0, 0.0, -end_load], rtol=1e-12, atol=1e-12 * end_load)
    # thin-shell end load p π R², to the polygon-vs-circle area: (A_ring + 2 A_mid)/3 ≈ π R² (1 − (π/n)²/2),
    # 1.2e-3 below the circle here, and (π/n)²/6 ≈ 4e-4 above the ring polygon A_ring ≈ π R² (1 − 2(π/n)²/3)
    assert top[2] / (pressure * np.pi * radius**2) - 1.0 == pytest.approx(-((np.pi / n) ** 2) / 2.0, rel=0.01)
    assert abs(float(top[2]) / (pressure * ring_area) - 1.0) < (np.pi / n) ** 2 / 6.0 * 1.01
    # a cell pressure (outside) pushes the top platen down
    _, top_cell = platen_reaction(membrane_forces(x0, mesh, 1e6, 1e-3, pressure), mesh)
    assert float(top_cell[2]) == pytest.approx(-end_load, rel=1e-12)


# ------------------------------------------------------------------------------ which internal stress


def test_radial_projected_area_of_a_cylinder_and_of_an_indented_band(precision):
    """A_r = Σ ∂V/∂x_i · r̂_i against two hand values and the cell pressure's radial resultant.

    - Nodes all at radius R: scaling x and y by (1 + ε) scales V by (1 + ε)², so Σ ∂V/∂x_i · r̂_i R = 2V
      and A_r = 2V/R exactly (a faceted cylinder: 2 × polygon area / R × H, → 2π R H as it refines);
    - the nodal pressure forces are −p ∂V/∂x, so their inward radial resultant is p A_r to round-off, on
      the cylinder and on a band indented by a wave (the surface §4.3's right cylinder does not see);
    - pressing the odd rows in by up to 2a lowers A_r (the surface's mean radius falls), by less than 2a/R.
    Under jit and vmap (two radii).
    """
    radius, height, pressure = 0.1, 0.2, 1e4
    dtype = jnp.result_type(float)
    mesh = cylinder_mesh(radius, height, 0.01, dtype=dtype)
    x0 = mesh.reference_position
    ring = x0[mesh.bottom_ring]
    area = jax.jit(records.radial_projected_area)(x0, mesh, ring)
    volume = float(enclosed_volume(x0, mesh))
    tol = 10 * tolerance(precision)
    assert float(area) == pytest.approx(2.0 * volume / radius, rel=tol)
    n = mesh.bottom_ring.shape[0]
    assert float(area) == pytest.approx(n * radius * np.sin(2.0 * np.pi / n) * height, rel=1e-3)
    assert abs(float(area) / (2.0 * np.pi * radius * height) - 1.0) < 2.0 * (np.pi / n) ** 2 / 3.0

    def pressure_resultant(position):
        force = -jax.grad(energies.pressure_energy)(position, mesh, pressure)
        return -jnp.sum(records.radial_components(force, position, ring))

    angle = np.arctan2(np.asarray(x0[:, 1]), np.asarray(x0[:, 0]))
    rows = np.arange(x0.shape[0]) // n
    wave = np.where((rows % 2 == 1), 3e-3 * (1.0 + np.cos(7.0 * angle)), 0.0)
    inward = -np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
    indented = x0 + jnp.asarray(wave[:, None] * inward, dtype)
    for position in (x0, indented):
        projected = records.radial_projected_area(position, mesh, ring)
        assert float(pressure_resultant(position)) == pytest.approx(pressure * float(projected), rel=tol)
    indented_area = float(records.radial_projected_area(indented, mesh, ring))
    assert indented_area < float(area)
    assert indented_area > float(area) * (1.0 - 2 * 3e-3 / radius)
    # vmap over two radii: A_r = 2V/R for each
    scales = jnp.asarray([1.0, 1.5], dtype)
    stacked = x0[None] * jnp.stack([scales, scales, jnp.ones_like(scales)], axis=1)[:, None, :]
    areas = jax.vmap(records.radial_projected_area, in_axes=(0, None, 0))(
        stacked, mesh, stacked[:, mesh.bottom_ring]
    )
    np.testing.assert_allclose(np.asarray(areas), float(area) * np.asarray(scales), rtol=tol)


def _ring_of_four(dtype, node_push=3.0, platen_push=5.0, thickness=4e-3):
    """A hand-built static case: four spheres of radius R in a ring (centres at a = R√2, neighbours touching),
    between two platens at z = ±R, each pressed inward by one membrane node at radius a + R + t_m/2.

    Each sphere is in equilibrium: the node's inward f is balanced by its two neighbours' contacts at ±45°,
    N = f/√2 each; each platen pushes each sphere with F along z. Returns the forces as
    :func:`membrane_love_weber_stress` reads them and the geometry.
    """
    from membrax.spheres.integrate import Forces, make_particles

    radius = 0.0125
    a = radius * np.sqrt(2.0)
    angles = np.arange(4) * np.pi / 2.0
    outward = np.stack([np.cos(angles), np.sin(angles), np.zeros(4)], axis=1)
    centres = a * outward
    pairs = [(0, 1), (1, 2), (2, 3), (0, 3)]
    normal = node_push / np.sqrt(2.0)
    branch = np.array([centres[j] - centres[i] for i, j in pairs])  # x_j − x_i, length 2R
    pair_force = normal * branch / np.linalg.norm(branch, axis=1)[:, None]  # on j from i: compression
    wall_force = np.zeros((4, 2, 3))
    wall_force[:, 0, 2], wall_force[:, 1, 2] = platen_push, -platen_push  # bottom pushes up, top down
    wall_arm = np.zeros((4, 2, 3))
    wall_arm[:, 0, 2], wall_arm[:, 1, 2] = -radius, radius
    reach = radius + 0.5 * thickness
    slot_force = (node_push * outward)[:, None, :]  # of each sphere on its node, (n_nodes = 4, K = 1, 3)
    slot_branch = (reach * outward)[:, None, :]
    arr = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    forces = Forces(
        force=arr(np.zeros((4, 3))),
        torque=arr(np.zeros((4, 3))),
        pair_spring=arr(np.zeros((4, 3))),
        wall_spring=arr(np.zeros((4, 2, 3))),
        pair_force=arr(pair_force),
        pair_branch=arr(branch),
        pair_normal_force=arr(np.full(4, normal)),
        wall_force=arr(wall_force),
        wall_arm=arr(wall_arm),
        wall_normal_force=arr(np.full((4, 2), platen_push)),
        wall_total_force=arr(np.array([[4 * platen_push, 4 * platen_push]])),
        wall_contacts=jnp.asarray([[4, 4]], jnp.int32),
    )
    particles = make_particles(arr(np.full(4, radius)), 2650.0)
    geometry = dict(radius=radius, a=a, reach=reach, centres=arr(centres), outward=outward)
    return forces, arr(slot_force), arr(slot_branch), particles, geometry


def test_love_weber_and_section_4_3_stresses_of_a_hand_built_static_ring(precision):
    """The §4.3, received and Love–Weber stresses of :func:`_ring_of_four` against hand values.

    Hand values (f the node push, F each platen's push on each sphere, R, a = R√2, r_c = a + R + t_m/2 the
    nodes' radius, H = 2R, V a chosen volume, A the platen area):
    - Love–Weber: σ_zz V = 4 spheres × 2 platens × F R; σ_xx V = pairs 4 N (2R)(1/2) + nodes 2 f (R + t_m/2)
      = 2 f r_c, the boundary sum Σ f_r r_c / 2 (equilibrium), so σ_r = 2 f r_c / V;
    - §4.3: the membrane's inward radial force on the spheres is 4f, σ3 = 4f / (2√(πA) H);
    - so σ3_LW / σ3_§4.3 = r_c √(πA) H / V: with V = π r_c² H (the volume inside the nodes) it is √(A/π)/r_c,
      R_A/r̄_c: Love–Weber over the nodes' own volume and §4.3 over a cylinder of the platen's area differ by
      the ratio of the two radii alone.
    """
    dtype = jnp.result_type(float)
    push, platen = 3.0, 5.0
    forces, slot_force, slot_branch, particles, g = _ring_of_four(dtype, push, platen)
    reach_radius = g["a"] + g["reach"]
    height = 2.0 * g["radius"]
    volume = np.pi * reach_radius**2 * height
    pair_member = jnp.zeros(4, jnp.int32)
    stress = jax.jit(records.membrane_love_weber_stress)(
        forces, slot_force, slot_branch, particles, pair_member, jnp.asarray([volume], dtype)
    )
    axial, radial = (float(x[0]) for x in principal_axisymmetric(stress))
    tol = 10 * tolerance(precision)
    assert axial == pytest.approx(8.0 * platen * g["radius"] / volume, rel=tol)
    assert radial == pytest.approx(2.0 * push * reach_radius / volume, rel=tol)
    assert float(stress[0, 0, 1]) == pytest.approx(0.0, abs=tol * radial)
    # §4.3: the membrane's force on the spheres is −f r̂ at each; the ring of nodes fixes the axis at 0
    sphere_force = -push * jnp.asarray(g["outward"], dtype)
    ring = jnp.asarray(reach_radius * g["outward"], dtype)
    radial_force = float(records.membrane_radial_force(sphere_force, g["centres"], ring))
    assert radial_force == pytest.approx(4.0 * push, rel=tol)
    platen_area = np.pi * (g["a"] + g["radius"]) ** 2
    area, _, internal_axial, internal_radial = records.right_cylinder_stresses(
        4.0 * platen, 4.0 * platen, radial_force, height, volume, height, volume, platen_area
    )
    assert float(area) == pytest.approx(platen_area, rel=tol)
    assert float(internal_axial) == pytest.approx(4.0 * platen / platen_area, rel=tol)
    section = 4.0 * push / (2.0 * np.sqrt(np.pi * platen_area) * height)
    assert float(internal_radial) == pytest.approx(section, rel=tol)
    assert radial / float(internal_radial) == pytest.approx(
        np.sqrt(platen_area / np.pi) / reach_radius, rel=tol
    )
    # vmap over two load levels: both stresses are linear in the forces
    scale = jnp.asarray([1.0, 2.0], dtype)
    scaled = jax.vmap(
        lambda s: records.membrane_love_weber_stress(
            forces.set(pair_force=s * forces.pair_force, wall_force=s * forces.wall_force),
            s * slot_force,
            slot_branch,
            particles,
            pair_member,
            jnp.asarray([volume], dtype),
        )
    )(scale)
    np.testing.assert_allclose(
        np.asarray(scaled[1]), 2.0 * np.asarray(scaled[0]), rtol=tol, atol=tol * radial
    )
