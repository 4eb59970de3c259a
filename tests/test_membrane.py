"""Membrane mesh and energies (membrax.membrane.mesh): each test checks a number against theory."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_difference, tolerance
from scipy.optimize import minimize

from membrax.membrane import energies, stability
from membrax.membrane.mesh import (
    cylinder_mesh,
    enclosed_volume,
    flat_mesh,
    offset_polygon,
    prism_mesh,
    rounded_offset_path,
)


def _stretched(mesh, stretch_x, stretch_y):
    """Reference positions under the homogeneous deformation diag(λ1, λ2, 1)."""
    return mesh.reference_position * jnp.asarray([stretch_x, stretch_y, 1.0])[None, :]


def _rotation(angle_z, angle_x):
    cz, sz, cx, sx = np.cos(angle_z), np.sin(angle_z), np.cos(angle_x), np.sin(angle_x)
    about_z = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return jnp.asarray(about_x @ about_z)


def _prismatoid_volume(position, mesh):
    """Exact volume of a stack of layers whose vertices lie on two planes: Σ h/6 (A_low + 4 A_mid + A_up).

    A_mid is the area of the polygon through the midpoints of the layer's zigzag edges, in order.
    """
    x = np.asarray(position)
    per_ring = mesh.bottom_ring.shape[0]
    rings = x.reshape(-1, per_ring, 3)

    def area(polygon):
        return 0.5 * np.sum(
            polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1]
        )

    total = 0.0
    for j in range(rings.shape[0] - 1):
        low, up = rings[j], rings[j + 1]
        if j % 2 == 0:  # upper ring turned by +½ step: zigzag L0 U0 L1 U1 ...
            zigzag = np.stack([low, up], axis=1).reshape(-1, 3)
        else:  # lower ring turned by +½ step: zigzag U0 L0 U1 L1 ...
            zigzag = np.stack([up, low], axis=1).reshape(-1, 3)
        middle = 0.5 * (zigzag + np.roll(zigzag, -1, axis=0))
        height = up[0, 2] - low[0, 2]
        total += height / 6.0 * (area(low) + 4.0 * area(middle) + area(up))
    return total


# ------------------------------------------------------------------------------------------------ mesh


def test_paper_size_mesh_count_and_orientation():
    # paper specimen: D ≈ 0.25 m (membrane mid-surface radius 0.1265 m), H = 0.449 m, edge 5 mm
    mesh = cylinder_mesh(0.1265, 0.449, 0.005)
    assert mesh.bottom_ring.shape == (159,)
    assert mesh.num_triangles == 33072  # 2 · 159 · 104 bands
    small = cylinder_mesh(1.0, 2.0, 0.3)
    x = np.asarray(small.reference_position)
    tri = np.asarray(small.triangles)
    normal = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    centre = x[tri].mean(axis=1)
    assert np.all(normal[:, 0] * centre[:, 0] + normal[:, 1] * centre[:, 1] > 0.0)  # outward
    edge_lengths = np.linalg.norm(x[tri] - x[np.roll(tri, 1, axis=1)], axis=2)
    assert edge_lengths.max() / edge_lengths.min() < 1.1  # near equilateral
    assert (
        np.ptp(x[np.asarray(small.bottom_ring), 2]) == 0.0 and x[np.asarray(small.top_ring), 2].min() == 2.0
    )


# ------------------------------------------------------------------------------------------------ stretching


@pytest.mark.parametrize(("stretch_x", "stretch_y"), [(1.3, 1.3), (1.5, 1.0), (1.2, 0.9)])
def test_patch_neo_hookean_energy_matches_law(stretch_x, stretch_y):
    mesh = flat_mesh(0.3, 0.2, 0.05)
    modulus, thickness = 1.4e6, 2e-3
    area = float(jnp.sum(mesh.reference_area))
    law = (modulus / 6.0) * (stretch_x**2 + stretch_y**2 + 1.0 / (stretch_x * stretch_y) ** 2 - 3.0)
    position = _stretched(mesh, stretch_x, stretch_y) @ _rotation(0.4, 0.7).T  # rotation-invariant
    energy = energies.stretching_energy(position, mesh, modulus, thickness)
    np.testing.assert_allclose(float(energy), law * thickness * area, rtol=1e-8)


def test_patch_svk_energy_matches_law():
    mesh = flat_mesh(0.3, 0.2, 0.05)
    modulus, thickness, nu, stretch_x, stretch_y = 1.4e6, 2e-3, 0.3, 1.05, 0.98
    e11, e22 = (stretch_x**2 - 1.0) / 2.0, (stretch_y**2 - 1.0) / 2.0
    shear, lame = modulus / (2.0 * (1.0 + nu)), modulus * nu / (1.0 - nu**2)
    law = shear * (e11**2 + e22**2) + 0.5 * lame * (e11 + e22) ** 2
    energy = energies.stretching_energy(
        _stretched(mesh, stretch_x, stretch_y), mesh, modulus, thickness, model="svk", poisson_ratio=nu
    )
    np.testing.assert_allclose(
        float(energy), law * thickness * float(jnp.sum(mesh.reference_area)), rtol=1e-8
    )


def test_patch_rigid_motion_gives_no_force(precision):
    mesh = flat_mesh(0.3, 0.2, 0.05)
    modulus, thickness = 1.4e6, 2e-3
    force_scale = modulus * thickness * 0.05 * 0.1  # E t a × 10 % strain
    moved = mesh.reference_position @ _rotation(0.9, -0.6).T + jnp.asarray([0.3, -1.0, 2.0])[None, :]
    grad = jax.grad(energies.stretching_energy)(moved, mesh, modulus, thickness)
    assert grad.dtype == precision
    # Round-off of positions near 2 m over a 5 cm edge: 40 ulp of strain, so the table's tolerance × 40.
    assert float(jnp.max(jnp.abs(grad))) < 40 * tolerance(precision) * force_scale
    # a stretched patch: interior nodes carry no net force (uniform stress), the boundary ones do
    grad = jax.grad(energies.stretching_energy)(_stretched(mesh, 1.1, 1.0), mesh, modulus, thickness)
    assert float(jnp.max(jnp.abs(grad))) > 1e-2 * force_scale


# ------------------------------------------------------------------------------------------------ pressure


def test_closed_cylinder_inflation_matches_thin_shell_theory():
    """Internal pressure on a long cylinder whose end rings slide radially but are held axially.

    Membrane theory: σ_θ = pR/t. With the end rings held axially the length is fixed, ε_z = 0, so
    σ_z = ν σ_θ and ε_θ = (1 − ν²) pR/(E t); for ν = ½ (incompressible neo-Hookean at small strain) this is
    0.75 pR/(E t), the same as for a free closed-end vessel (σ_z = pR/(2t), ε_θ = (1 − ν/2) pR/(E t)) because
    ν = ½ makes the closed-end axial strain vanish. The state is uniform: no bending boundary layer, so the
    mid-height ring is compared at 2 %.
    """
    radius, height, modulus, thickness, pressure = 1.0, 6.0, 100.0, 0.01, -1e-3  # pR/(Et) = 1e-3
    mesh = cylinder_mesh(radius, height, 2.0 * np.pi * radius / 48)
    n = mesh.num_nodes
    free = np.ones((n, 3), dtype=bool)
    free[np.asarray(mesh.bottom_ring), 2] = False
    free[np.asarray(mesh.top_ring), 2] = False
    free_index = jnp.asarray(np.flatnonzero(free.ravel()))
    start = mesh.reference_position.ravel()

    def energy(displacement):  # displacement in units of R, energy in units of E t R²
        position = start.at[free_index].add(radius * displacement).reshape(n, 3)
        return energies.total_energy(position, mesh, modulus, thickness, pressure) / (modulus * thickness)

    value_and_grad = jax.jit(jax.value_and_grad(energy))

    def objective(u):
        value, grad = value_and_grad(jnp.asarray(u))
        return float(value), np.asarray(grad)

    result = minimize(
        objective,
        np.zeros(free_index.size),
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": 2000, "ftol": 1e-16},
    )
    position = np.asarray(start.at[free_index].add(radius * jnp.asarray(result.x)).reshape(n, 3))
    rings = position.reshape(-1, mesh.bottom_ring.shape[0], 3)
    middle = rings[rings.shape[0] // 2]
    centre = middle.mean(axis=0)
    mean_radius = np.mean(np.hypot(middle[:, 0] - centre[0], middle[:, 1] - centre[1]))
    theory = 0.75 * (-pressure) * radius / (modulus * thickness)
    np.testing.assert_allclose((mean_radius - radius) / radius, theory, rtol=0.02)


def test_neo_hookean_band_has_the_inflation_limit_point_and_svk_has_none(precision):
    """Why a thin, soft membrane balloons into a surface void (docs/model.md, the inflation limit).

    A closed band scaled uniformly by λ (every triangle stretched equibiaxially in its plane) stores
    W = μ t A₀ (2λ² + λ⁻⁴ − 3)/2 and encloses V = λ³ V₀, so the pressure it holds, p = dW/dV (from the
    energy's gradient here), is (2/3)(μ t A₀/V₀)(λ⁻¹ − λ⁻⁷) for the neo-Hookean law: it peaks at λ = 7^(1/6)
    and falls beyond, the limit point of inflated rubber (Adkins & Rivlin 1952). The St Venant–Kirchhoff law,
    W = t A₀ (μ + λ*)(λ² − 1)²/2 per unit area in equibiaxial stretch, only stiffens: no limit point.
    """
    dtype = precision
    modulus, thickness = 7e5, 1e-3
    mesh = cylinder_mesh(0.125, 0.25, 0.02, dtype=dtype)
    rest = mesh.reference_position
    area = float(jnp.sum(mesh.reference_area))
    volume = float(enclosed_volume(rest, mesh))

    def held_pressure(stretch, model):
        def energy(s):
            return energies.stretching_energy(s * rest, mesh, modulus, thickness, model=model)

        return jax.grad(energy)(stretch) / jax.grad(lambda s: enclosed_volume(s * rest, mesh))(stretch)

    stretches = jnp.linspace(1.02, 2.5, 149, dtype=dtype)
    neo_hookean = np.asarray(jax.vmap(lambda s: held_pressure(s, "neo_hookean"))(stretches))
    svk = np.asarray(jax.vmap(lambda s: held_pressure(s, "svk"))(stretches))
    lam = np.asarray(stretches, dtype=np.float64)
    expected = 2.0 / 3.0 * (modulus / 3.0) * thickness * area / volume * (1.0 / lam - lam**-7)
    np.testing.assert_allclose(neo_hookean, expected, rtol=50 * tolerance(dtype))
    peak = lam[np.argmax(neo_hookean)]
    assert abs(peak - 7.0 ** (1.0 / 6.0)) <= 0.01  # the grid's step
    assert neo_hookean[-1] < 0.8 * neo_hookean.max()
    assert np.all(np.diff(svk) > 0.0)


def test_pressure_forces_close_and_cap_carries_p_times_area(precision):
    mesh = cylinder_mesh(0.1, 0.3, 0.03)
    key = jax.random.PRNGKey(0)
    position = mesh.reference_position + 0.003 * jax.random.normal(key, mesh.reference_position.shape)
    pressure = 50e3
    force = -jax.grad(energies.pressure_energy)(position, mesh, pressure)
    scale = pressure * 0.1 * 0.3
    assert force.dtype == precision
    rtol = tolerance(precision)
    np.testing.assert_allclose(np.asarray(jnp.sum(force, axis=0)), 0.0, atol=rtol * scale)
    torque = jnp.sum(jnp.cross(position, force), axis=0)
    np.testing.assert_allclose(np.asarray(torque), 0.0, atol=rtol * scale * 0.3)

    # explicit assembly: each face f gives −p A_f n_f / 3 to its vertices; the cap fan's centroid share
    # goes equally to the ring nodes
    x = np.asarray(position)
    expected = np.zeros_like(x)
    tri = np.asarray(mesh.triangles)
    face = -pressure * np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]) / 6.0  # −p A n / 3
    for k in range(3):
        np.add.at(expected, tri[:, k], face)
    cap_totals = []
    for ring, upward in ((np.asarray(mesh.bottom_ring), False), (np.asarray(mesh.top_ring), True)):
        here, after = ring, np.roll(ring, -1)
        first, second = (here, after) if upward else (after, here)
        centre = x[ring].mean(axis=0)
        cap_face = -pressure * np.cross(x[first] - centre, x[second] - centre) / 6.0
        np.add.at(expected, first, cap_face)
        np.add.at(expected, second, cap_face)
        expected[ring] += cap_face.sum(axis=0) / ring.size
        cap_totals.append(3.0 * cap_face.sum(axis=0))
        # the cap force is p × (the ring polygon's projected area), along the inward normal
        polygon = x[ring]
        shoelace = 0.5 * np.sum(
            polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1]
        )
        np.testing.assert_allclose(
            cap_totals[-1][2], pressure * shoelace * (-1.0 if upward else 1.0), rtol=rtol
        )
    np.testing.assert_allclose(np.asarray(force), expected, rtol=0.0, atol=rtol * scale)


# ------------------------------------------------------------------------------------------------ volume


def test_enclosed_volume_exact_for_polyhedron_and_converges_to_cylinder():
    radius, height = 0.125, 0.4
    mesh = cylinder_mesh(radius, height, 0.02, z_bottom=0.05)
    n = mesh.bottom_ring.shape[0]
    half = np.pi / n
    # each layer is an antiprism of regular n-gons: V = H n R² sin(π/n)(1 + 2 cos(π/n))/3
    exact = height * n * radius**2 * np.sin(half) * (1.0 + 2.0 * np.cos(half)) / 3.0
    volume = float(enclosed_volume(mesh.reference_position, mesh))
    np.testing.assert_allclose(volume, exact, rtol=1e-12)
    np.testing.assert_allclose(volume, _prismatoid_volume(mesh.reference_position, mesh), rtol=1e-12)
    # origin-independent (closed surface)
    shifted = mesh.reference_position + jnp.asarray([1.0, -2.0, 3.0])[None, :]
    np.testing.assert_allclose(float(enclosed_volume(shifted, mesh)), exact, rtol=1e-12)
    errors = []
    for edge in (0.04, 0.02, 0.01):
        fine = cylinder_mesh(radius, height, edge)
        errors.append(
            abs(float(enclosed_volume(fine.reference_position, fine)) / (np.pi * radius**2 * height) - 1)
        )
    assert errors[0] > errors[1] > errors[2] and errors[2] < 2e-3
    np.testing.assert_allclose(errors[1] / errors[2], 4.0, rtol=0.05)  # second order in the edge length


def test_octagonal_prism_volume_is_exact():
    angles = (np.arange(8) + 0.5) * np.pi / 4
    outline = 0.12 * np.column_stack([np.cos(angles), np.sin(angles)])
    mesh = prism_mesh(outline, 0.001, 0.3, 0.02)
    volume = float(enclosed_volume(mesh.reference_position, mesh))
    np.testing.assert_allclose(volume, _prismatoid_volume(mesh.reference_position, mesh), rtol=1e-12)
    polygon = offset_polygon(outline, 0.001)
    # the offset octagon's apothem is the outline's plus the offset
    np.testing.assert_allclose(
        np.linalg.norm(polygon[0] + polygon[1]) / 2.0, 0.12 * np.cos(np.pi / 8) + 0.001
    )
    # nodes lie on the offset octagon, which the mesh approaches from inside
    prism = (
        0.3
        * 0.5
        * np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    )
    assert 0.995 * prism < volume < prism


def test_rounded_offset_path_is_the_minkowski_sum_of_the_core_with_a_disc():
    """Steiner: the perimeter of a convex polygon ⊕ disc(ρ) is P_core + 2πρ, every point lies at distance
    ρ from the core polygon, and the mesh's enclosed area approaches A_core + ρ P_core + πρ²."""
    angles = (np.arange(8) + 0.5) * np.pi / 4
    outline = 0.12 * np.column_stack([np.cos(angles), np.sin(angles)])
    offset, corner_radius = 0.0025, 0.0125
    point_at, perimeter = rounded_offset_path(outline, offset, corner_radius)
    core = offset_polygon(outline, -corner_radius)
    core_side = np.linalg.norm(np.roll(core, -1, axis=0) - core, axis=1)
    rho = offset + corner_radius
    np.testing.assert_allclose(perimeter, core_side.sum() + 2 * np.pi * rho, rtol=1e-12)
    points = point_at(np.linspace(0.0, 1.0, 4001, endpoint=False))
    # Distance to the (convex) core polygon: the largest signed distance to its edge lines, or to a vertex.
    edge = np.roll(core, -1, axis=0) - core
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / core_side[:, None]
    to_lines = np.einsum("pkj,kj->pk", points[:, None, :] - core[None], normal)
    k = np.argmax(to_lines, axis=1)
    along = np.einsum("pj,pj->p", points - core[k], edge[k]) / core_side[k] ** 2
    on_side = (along >= 0) & (along <= 1)
    to_vertices = np.min(np.linalg.norm(points[:, None, :] - core[None], axis=2), axis=1)
    distance = np.where(on_side, to_lines[np.arange(len(points)), k], to_vertices)
    np.testing.assert_allclose(distance, rho, rtol=1e-9)
    # Consecutive samples are equally spaced in arc length.
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    np.testing.assert_allclose(steps, perimeter / 4001, rtol=1e-3)
    mesh = prism_mesh(outline, offset, 0.3, 0.005, corner_radius=corner_radius)
    core_area = 0.5 * np.sum(core[:, 0] * np.roll(core[:, 1], -1) - np.roll(core[:, 0], -1) * core[:, 1])
    exact = 0.3 * (core_area + rho * core_side.sum() + np.pi * rho**2)
    volume = float(enclosed_volume(mesh.reference_position, mesh))
    assert 0.999 * exact < volume < exact  # inscribed: the chords cut the arcs


# ------------------------------------------------------------------------------------------------ bending


@pytest.mark.parametrize("roll_axis", [0, 1])
def test_bending_of_rolled_strip_matches_kirchhoff(roll_axis):
    mesh = flat_mesh(1.0, 1.0, 0.025)
    modulus, thickness, radius = 1.0, 0.01, 1.0
    x = np.asarray(mesh.reference_position).copy()
    arc = x[:, roll_axis].copy()
    x[:, roll_axis] = radius * np.sin(arc / radius)  # isometric: no stretching
    x[:, 2] = radius * (1.0 - np.cos(arc / radius))
    position = jnp.asarray(x)
    energy = float(energies.bending_energy(position, mesh, modulus, thickness))
    rigidity = float(energies.bending_rigidity(modulus, thickness))
    area = float(jnp.sum(mesh.reference_area))
    np.testing.assert_allclose(energy, 0.5 * rigidity * area / radius**2, rtol=0.05)
    # the 2 % shortfall is the strip's border (edges on it carry no hinge); against the area covered by
    # the interior edges' diamonds, Σ Ā_e/3, the calibration is within 1 %
    rest = mesh.reference_position
    rest_length_sq = jnp.sum((rest[mesh.edges[:, 1]] - rest[mesh.edges[:, 0]]) ** 2, axis=1)
    diamond_area = float(jnp.sum(3.0 * rest_length_sq / mesh.edge_weight)) / 3.0  # Σ Ā_e / 3
    np.testing.assert_allclose(energy, 0.5 * rigidity * diamond_area / radius**2, rtol=0.01)
    # rolling maps edges to chords, shorter by (a/R)²/24 ≈ 3e-5: a stretching energy negligible here
    assert float(energies.stretching_energy(position, mesh, modulus, thickness)) < 1e-3 * energy


def test_rest_shape_has_no_energy_and_no_force(precision):
    mesh = cylinder_mesh(0.125, 0.2, 0.02)
    grad = jax.jit(jax.grad(energies.total_energy))(mesh.reference_position, mesh, 1.4e6, 2e-3, 0.0)
    assert grad.dtype == precision
    rtol = tolerance(precision)  # a strain of round-off size: force ~ E t a × rtol, energy ~ E t A × rtol²
    assert float(jnp.max(jnp.abs(grad))) < rtol * 1.4e6 * 2e-3 * 0.02
    energy = float(energies.total_energy(mesh.reference_position, mesh, 1.4e6, 2e-3, 0.0))
    assert abs(energy) < rtol**2 * 1.4e6 * 2e-3 * (2 * np.pi * 0.125 * 0.2)


# ------------------------------------------------------------------------------------------------ autodiff


def test_parameter_gradients_match_central_differences():
    mesh = cylinder_mesh(0.1, 0.2, 0.03)
    key = jax.random.PRNGKey(1)
    position = mesh.reference_position + 0.004 * jax.random.normal(key, mesh.reference_position.shape)

    def energy(modulus, thickness, pressure):
        return energies.total_energy(position, mesh, modulus, thickness, pressure)

    params = (1.4e6, 2e-3, 30e3)
    grads = jax.grad(energy, argnums=(0, 1, 2))(*params)
    for k in range(3):
        np.testing.assert_allclose(float(grads[k]), central_difference(energy, params, k), rtol=1e-6)
    np.testing.assert_allclose(float(grads[2]), float(enclosed_volume(position, mesh)), rtol=1e-12)
    # The energy is linear in the bending factor, with slope the plate bending energy.
    by_factor = jax.grad(lambda factor: energies.total_energy(position, mesh, *params, bending_factor=factor))
    np.testing.assert_allclose(
        float(by_factor(0.3)), float(energies.bending_energy(position, mesh, *params[:2])), rtol=1e-12
    )

    # volume gradient w.r.t. positions along a random direction
    direction = jax.random.normal(jax.random.PRNGKey(2), position.shape)
    grad_volume = jax.grad(enclosed_volume)(position, mesh)
    step = 1e-6

    def volume_at(s):
        return float(enclosed_volume(position + s * direction, mesh))

    finite = (volume_at(step) - volume_at(-step)) / (2.0 * step)
    np.testing.assert_allclose(float(jnp.sum(grad_volume * direction)), finite, rtol=1e-6)


@pytest.mark.parametrize("model", ["neo_hookean", "svk", "gent"])
def test_nodal_forces_and_hessian_match_central_differences(model):
    # The closed-form derivatives of the triangles and hinges against the energy itself: the directional
    # derivative of U is −F·v, and the Hessian–vector product that membrane_critical_time_step iterates on
    # (stability._stiffness_product, reverse over reverse) is the directional derivative of −F.
    mesh = cylinder_mesh(0.1, 0.2, 0.03)
    key1, key2 = jax.random.split(jax.random.PRNGKey(3))
    position = mesh.reference_position * jnp.asarray([1.05, 1.05, 0.97])[None, :]
    position = position + 0.003 * jax.random.normal(key1, position.shape)
    direction = jax.random.normal(key2, position.shape)
    params = (1.4e6, 3e-3, 30e3)
    bending_factor = 1.0  # plate bending on, so the hinges' closed forms are checked too
    locking_jm = 0.5  # s = (I₁ − 3)/J_m: 0.27 in the median triangle, past the lock fraction in the top 10 %

    def energy(x):
        return energies.total_energy(
            x, mesh, *params, model=model, bending_factor=bending_factor, locking_jm=locking_jm
        )

    def energy_at(s):
        return float(energy(position + s * direction))

    step = 1e-6
    force = jax.jit(
        lambda x: energies.nodal_forces(
            x, mesh, *params, model=model, bending_factor=bending_factor, locking_jm=locking_jm
        )
    )
    finite = (energy_at(step) - energy_at(-step)) / (2.0 * step)
    np.testing.assert_allclose(-float(jnp.sum(force(position) * direction)), finite, rtol=1e-6)
    hvp = stability._stiffness_product(
        direction, position, mesh, *params, bending_factor, locking_jm, model=model
    )
    finite_hvp = -(force(position + step * direction) - force(position - step * direction)) / (2.0 * step)
    scale_ = float(jnp.max(jnp.abs(hvp)))
    np.testing.assert_allclose(np.asarray(hvp), np.asarray(finite_hvp), rtol=0, atol=1e-5 * scale_)

    # The derivative with respect to the rest frames D_m⁻¹ (a mesh quantity) is carried too.
    def energy_of_frames(inverse):
        return energies.stretching_energy(
            position, mesh.set(reference_inverse=inverse), *params[:2], model=model, locking_jm=locking_jm
        )

    frames_direction = jax.random.normal(jax.random.PRNGKey(4), mesh.reference_inverse.shape)
    grad_frames = jax.grad(energy_of_frames)(mesh.reference_inverse)
    finite_frames = (
        float(energy_of_frames(mesh.reference_inverse + step * frames_direction))
        - float(energy_of_frames(mesh.reference_inverse - step * frames_direction))
    ) / (2.0 * step)
    np.testing.assert_allclose(float(jnp.sum(grad_frames * frames_direction)), finite_frames, rtol=1e-6)


def test_jit_and_vmap_over_material_parameters_match_loop():
    mesh = cylinder_mesh(0.1, 0.2, 0.03)
    position = mesh.reference_position * jnp.asarray([1.02, 1.02, 0.99])[None, :]
    moduli = jnp.asarray([1.0e6, 1.4e6, 2.0e6])
    thicknesses = jnp.asarray([1e-3, 2e-3, 4e-3])

    def energy(modulus, thickness):
        return energies.total_energy(position, mesh, modulus, thickness, 20e3)

    batched = jax.jit(jax.vmap(energy))(moduli, thicknesses)
    forces = jax.vmap(lambda e, t: energies.nodal_forces(position, mesh, e, t, 20e3))(moduli, thicknesses)
    for k in range(3):
        np.testing.assert_allclose(float(batched[k]), float(energy(moduli[k], thicknesses[k])), rtol=1e-13)
        single = energies.nodal_forces(position, mesh, moduli[k], thicknesses[k], 20e3)
        np.testing.assert_allclose(np.asarray(forces[k]), np.asarray(single), rtol=1e-12, atol=1e-9)


def test_float64_in_float64_out_and_lumped_mass():
    mesh = cylinder_mesh(0.1, 0.2, 0.03)
    assert mesh.reference_position.dtype == jnp.float64
    modulus, thickness = jnp.float64(1.4e6), jnp.float64(2e-3)
    for value in (
        energies.stretching_energy(mesh.reference_position, mesh, modulus, thickness),
        energies.bending_energy(mesh.reference_position, mesh, modulus, thickness),
        enclosed_volume(mesh.reference_position, mesh),
        energies.nodal_forces(mesh.reference_position, mesh, modulus, thickness, jnp.float64(1e4)),
    ):
        assert value.dtype == jnp.float64
    mass = energies.lumped_mass(mesh, thickness, density=930.0)
    assert mass.dtype == jnp.float64 and mass.shape == (mesh.num_nodes,)
    np.testing.assert_allclose(
        float(jnp.sum(mass)), 930.0 * 2e-3 * float(jnp.sum(mesh.reference_area)), rtol=1e-13
    )


def test_unknown_model_is_rejected():
    mesh = flat_mesh(0.1, 0.1, 0.05)
    with pytest.raises(ValueError, match="model"):
        energies.stretching_energy(mesh.reference_position, mesh, 1.0, 1.0, model="mooney")
