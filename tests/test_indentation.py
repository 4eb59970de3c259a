"""Membrane indentation into a square array of spheres (membrax.indentation).

The issue's test: a sheet pressed by pressure onto a fixed array of spheres indents deeper with pressure
and less with thickness. Asserted: the pressure potential's forces (a hand check, exact to round-off),
monotonicity in p and t_m, a sub-linear positive exponent d ln α / d ln p, and that the penalty contact
does not blur the geometry. Molenkamp & Luger's α/D and exponent 1/3 are printed beside the simulated
values, not asserted (the set-up is a square array, not their triangular grid, and their constant spans
0.15–0.4).
"""

import jax
import jax.numpy as jnp
import numpy as np

from membrax import indentation, membrane, theory

DIAMETER = 0.025
MODULUS = 1.4e6


def _perturbed_sheet(seed):
    """A flat 40 × 30 mm sheet: interior nodes moved in x, y, z; outline nodes moved in z only."""
    mesh = membrane.flat_mesh(0.04, 0.03, 0.005)
    rng = np.random.default_rng(seed)
    shift = 1e-3 * rng.standard_normal(mesh.reference_position.shape)
    shift[indentation.boundary_nodes(mesh), :2] = 0.0
    return mesh, mesh.reference_position + jnp.asarray(shift)


def test_pressure_potential_gives_p_times_projected_area_and_consistent_nodal_loads():
    """Hand check of V = Σ A_xy (z̄ − z_ref): total force (0, 0, −p A), interior loads −p Σ A n / 3.

    With the outline moved only vertically, the projected area of the sheet is that of the flat patch
    (the sum of the rest areas), so the pressure's resultant is exactly −p A ẑ: positive p pushes down.
    On interior nodes the force equals the consistent load of the cone volume (1/6) Σ x₁·(x₂ × x₃)
    (:func:`membrax.membrane.band_volume`) and does not depend on the reference plane.
    """
    mesh, position = _perturbed_sheet(0)
    pressure = 70e3
    area = float(jnp.sum(mesh.reference_area))
    force = -jax.grad(indentation.sheet_pressure_energy)(position, mesh, pressure)
    total = np.asarray(jnp.sum(force, axis=0))
    np.testing.assert_allclose(total, [0.0, 0.0, -pressure * area], rtol=0.0, atol=1e-10 * pressure * area)

    interior = np.setdiff1d(np.arange(mesh.num_nodes), indentation.boundary_nodes(mesh))
    cone = -pressure * jax.grad(membrane.band_volume)(position, mesh)
    shifted = -jax.grad(indentation.sheet_pressure_energy)(position, mesh, pressure, -0.3)
    scale = pressure * area / interior.size
    np.testing.assert_allclose(np.asarray(force[interior]), np.asarray(cone[interior]), atol=1e-10 * scale)
    np.testing.assert_allclose(np.asarray(force[interior]), np.asarray(shifted[interior]), atol=1e-10 * scale)


def test_boundary_nodes_of_flat_mesh_are_its_outline():
    mesh = membrane.flat_mesh(0.04, 0.03, 0.005)
    position = np.asarray(mesh.reference_position)
    outline = indentation.boundary_nodes(mesh)
    rows = position.reshape(-1, mesh.bottom_ring.shape[0], 3)
    expected = {*np.asarray(mesh.bottom_ring).tolist(), *np.asarray(mesh.top_ring).tolist()}
    columns = rows.shape[1]
    expected |= {r * columns for r in range(rows.shape[0])} | {
        r * columns + columns - 1 for r in range(rows.shape[0])
    }
    assert set(outline.tolist()) == expected


def test_indentation_grows_with_pressure_and_falls_with_thickness():
    """3 × 3 cells of D = 25 mm spheres, edge D/6, outline pinned; α in the central void.

    E_m = 1400 kPa, t_m = 2.5 and 5 mm, p = 10, 40, 100 kPa (each pressure starts from the previous
    solution), frictionless penalty k_n = 1e6 N/m.
    """
    radius = 0.5 * DIAMETER
    pressures = np.array([10e3, 40e3, 100e3])
    thicknesses = (2.5e-3, 5e-3)
    void_ratio = 6.0 / np.pi - 1.0  # simple cubic: the square array's void ratio
    depth = np.zeros((len(thicknesses), pressures.size))
    print("\n t_m/mm  p/kPa  alpha/D (sim)  alpha/D (M&L)")
    for i, thickness in enumerate(thicknesses):
        mesh, spheres, low, high = indentation.sheet_on_square_array(3, DIAMETER, DIAMETER / 6, thickness)
        previous = None
        for j, pressure in enumerate(pressures):
            solution = indentation.solve_sheet_on_spheres(
                mesh,
                spheres,
                np.full(spheres.shape[0], radius),
                float(pressure),
                MODULUS,
                thickness,
                normal_stiffness=1e6,
                initial_position=previous,
            )
            previous = solution.position
            assert solution.success
            depth[i, j] = indentation.indentation_depth(
                solution.position, low, high, radius + 0.5 * thickness
            )
            # the penalty's overlap is a small error on the indentation
            assert solution.max_overlap < 0.01 * depth[i, j]
            ratio = float(
                theory.molenkamp_luger_indentation_ratio(void_ratio, DIAMETER, thickness, pressure, MODULUS)
            )
            print(
                f"{thickness * 1e3:7.1f} {pressure / 1e3:6.0f} {depth[i, j] / DIAMETER:14.4f} {ratio:14.4f}"
            )

    assert np.all(depth > 0.0)
    assert np.all(np.diff(depth, axis=1) > 0.0), "α must grow with p"
    assert np.all(depth[1] < depth[0]), "α must fall with t_m"
    for i, thickness in enumerate(thicknesses):
        exponent = np.polyfit(np.log(pressures), np.log(depth[i]), 1)[0]
        print(f"t_m = {thickness * 1e3:g} mm: d ln(alpha)/d ln(p) = {exponent:.3f} (Molenkamp & Luger: 1/3)")
        # sub-linear: the membrane stiffens as it stretches (and it cannot pass through the spheres)
        assert 0.0 < exponent < 1.0
    # the deepest indentation stays inside the void: above the sphere centres' plane
    assert np.all(depth < radius + 0.5 * max(thicknesses))
