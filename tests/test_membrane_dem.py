"""The coupled DEM + membrane step: clamped inflation against thin-shell theory, and a consolidated specimen
checked against equilibrium, Newton's third law, the no-penetration requirement and jit/grad."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import clamped_cylinder_parts

from membrax.defaults import LATEX_DENSITY
from membrax.membrane import coupled as membrane_dem
from membrax.membrane import energies, stability
from membrax.membrane.candidates import fitted_candidate_capacities
from membrax.membrane.contact import MembraneContactParams
from membrax.membrane.mesh import cylinder_mesh, free_node_mask
from membrax.spheres import fcc
from membrax.spheres.contact import ContactParams
from membrax.spheres.integrate import DampingParams, DEMParams, make_particles, sphere_dem
from membrax.spheres.neighbors import pair_neighbor_fn
from membrax.triaxial.membrane_cell import membrane_test


def _clamped_cylinder(radius, height, edge, modulus, thickness, cell_pressure, damping):
    """A membrane cylinder clamped to two fixed platens, two small spheres inside that touch nothing."""
    mesh, spheres, particles, frame, walls = clamped_cylinder_parts(radius, height, edge)
    params = membrane_dem.CoupledParams(
        dem=DEMParams(contact=ContactParams.paper(), damping=damping),
        membrane=membrane_dem.MembraneParams(
            modulus=jnp.asarray(modulus),
            thickness=jnp.asarray(thickness),
            cell_pressure=jnp.asarray(cell_pressure),
            contact=MembraneContactParams.default(),
            bending_factor=jnp.asarray(1.0),
            contact_offset_factor=jnp.asarray(1.0),
        ),
    )
    dt = 0.5 * stability.membrane_critical_time_step(mesh, params.membrane, contacts_per_node=0)["mesh"]
    dem_init, _ = sphere_dem(particles, frame, dt)
    init_fn, step_fn = membrane_dem.membrane_dem(particles, frame, mesh, dt, platen_area=np.pi * radius**2)
    state = init_fn(dem_init(spheres, walls, frame.allocate(spheres)), params, capacity=2, skin=0.01)
    return mesh, params, state, step_fn


def test_clamped_cylinder_under_internal_pressure_matches_thin_shell_theory():
    """Explicit dynamics with damping to rest: a long cylinder of radius R, both end rings clamped to fixed
    platens, internal pressure p (cell pressure −p).

    Long cylinder at fixed length (ε_z = 0): σ_θ = pR/t, ε_θ = (1 − ν²) pR/(E t) = 0.75 pR/(E t) for ν = ½
    (incompressible neo-Hookean at small strain), σ_z = ν σ_θ, so the membrane pulls each platen inward
    with N = σ_z t 2πR = p π R². The clamps add a bending boundary layer at each end (linear shell theory:
    w = w∞ (1 − e^{−βz}(cos βz + sin βz)), β⁴ = 3(1 − ν²)/(R t)², 1/β = 18 mm here), where the hoop strain
    drops to zero; with the length fixed, ∫ ε_z dz = 0 over the height H then gives
    σ_z = ν σ_θ (H − 2/β)/(H − 2ν²/β) (0.954 ν σ_θ here), and ε_θ∞ = (σ_θ − ν σ_z)/E in the middle.
    Both the mid-height hoop strain and the platen reactions (cap pressure removed) are asserted against
    this shell solution within 2 %, and the hoop strain against the plain long-cylinder value too.
    """
    radius, height, modulus, thickness = 0.1, 0.6, 1.4e6, 0.005
    pressure = 1e-3 * modulus * thickness / radius  # pR/(Et) = 1e-3
    mesh, params, state, step_fn = _clamped_cylinder(
        radius, height, 2 * np.pi * radius / 32, modulus, thickness, -pressure, DampingParams.local(0.3)
    )
    run = jax.jit(lambda s: jax.lax.fori_loop(0, 1500, lambda _, x: step_fn(x, params), s))
    for _ in range(2):
        state = run(state)
    assert int(state.error) == 0
    n_theta = mesh.bottom_ring.shape[0]
    rings = np.asarray(state.membrane.position).reshape(-1, n_theta, 3)
    rest = np.asarray(mesh.reference_position).reshape(-1, n_theta, 3)
    middle = rings.shape[0] // 2
    strain = np.mean(np.hypot(rings[middle, :, 0], rings[middle, :, 1])) / np.mean(
        np.hypot(rest[middle, :, 0], rest[middle, :, 1])
    )
    hoop_stress = pressure * radius / thickness
    np.testing.assert_allclose(strain - 1.0, 0.75 * hoop_stress / modulus, rtol=0.02)
    poisson = 0.5
    beta = (3.0 * (1.0 - poisson**2)) ** 0.25 / np.sqrt(radius * thickness)
    axial_stress = poisson * hoop_stress * (height - 2.0 / beta) / (height - 2.0 * poisson**2 / beta)
    np.testing.assert_allclose(strain - 1.0, (hoop_stress - poisson * axial_stress) / modulus, rtol=0.02)
    end_load = axial_stress * thickness * 2.0 * np.pi * radius
    reaction = np.asarray(state.membrane.platen_reaction)
    np.testing.assert_allclose(reaction[1, 2], -end_load, rtol=0.02)
    np.testing.assert_allclose(reaction[0, 2], end_load, rtol=0.02)
    # The membrane is at rest: what the clamps hold balances (no sphere is touched).
    np.testing.assert_allclose(np.asarray(state.membrane.sphere_force), 0.0, atol=0.0)


@pytest.mark.slow
def test_gradient_and_vmap_of_coupled_steps_match_finite_differences_and_a_loop():
    """d(mean node radius after 100 steps)/d(E_m, p) by jax.grad equals central differences (viscous damping,
    smooth), and a vmap over the cell pressure equals a Python loop."""
    radius, height, modulus, thickness = 0.1, 0.3, 1.4e6, 0.005
    pressure = 1e-3 * modulus * thickness / radius
    _, params, state, step_fn = _clamped_cylinder(
        radius, height, 2 * np.pi * radius / 12, modulus, thickness, -pressure, DampingParams.viscous(200.0)
    )

    def mean_radius(modulus_, cell_pressure):
        p = params.set(membrane=params.membrane.set(modulus=modulus_, cell_pressure=cell_pressure))
        final = jax.lax.fori_loop(0, 100, lambda _, s: step_fn(s, p), state)
        xy = final.membrane.position[:, :2]
        return jnp.mean(jnp.sqrt(xy[:, 0] ** 2 + xy[:, 1] ** 2))

    value_and_grad = jax.jit(jax.value_and_grad(mean_radius, argnums=(0, 1)))
    _, (d_modulus, d_pressure) = value_and_grad(jnp.asarray(modulus), jnp.asarray(-pressure))

    def f(modulus_, cell_pressure):  # the values of the compiled value-and-gradient (one compilation)
        return value_and_grad(jnp.asarray(modulus_), jnp.asarray(cell_pressure))[0]

    step_e, step_p = 1e-4 * modulus, 1e-4 * pressure
    fd_modulus = (f(modulus + step_e, -pressure) - f(modulus - step_e, -pressure)) / (2 * step_e)
    fd_pressure = (f(modulus, -pressure + step_p) - f(modulus, -pressure - step_p)) / (2 * step_p)
    assert float(d_pressure) < 0.0  # more internal pressure (more negative p) inflates
    np.testing.assert_allclose(float(d_modulus), float(fd_modulus), rtol=1e-5)
    np.testing.assert_allclose(float(d_pressure), float(fd_pressure), rtol=1e-5)
    pressures = jnp.asarray([-pressure, -0.5 * pressure])
    batched = jax.vmap(lambda p: mean_radius(jnp.asarray(modulus), p))(pressures)
    np.testing.assert_allclose(np.asarray(batched), [float(f(modulus, p)) for p in pressures], rtol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize(("contact_model", "edges_per_diameter"), [("nodes", 5.0), ("faces", 3.0)])
def test_consolidated_specimen_is_in_equilibrium_and_spheres_stay_behind_the_membrane(
    contact_model, edges_per_diameter
):
    """A 4 × 4 × 5-layer FCC specimen in a 5 mm membrane, consolidated at 10 kPa (f64), the spheres meeting
    the membrane's nodes (mesh edge D/5) or its faces, edges and nodes (edge D/3, cheaper).

    - Newton's third law and rest: the membrane's reactions on both platens plus its forces on the spheres
      sum to zero (the cell pressure sums to zero over the closed surface, the clamps and the spheres hold
      the rest), within 1 % of p × platen area;
    - the spheres are in vertical equilibrium: bottom platen force − top platen force + the membrane's
      vertical force on them = 0, within 1 % of p × platen area;
    - no sphere passes through the membrane between nodes: the largest penetration of a sphere into the
      triangle surface (R − distance from the centre) stays below t_m/2 (the issue's requirement);
    - the candidate table starts with one slot per node, too few where a node sees two spheres: the driver
      grows it on the overflow bit and reruns, so the final table holds every node's candidates.
    """
    specimen = fcc.fcc_specimen(0.025, 4, 5)
    test = membrane_test(
        specimen,
        cell_pressure=1e4,
        membrane_thickness=5e-3,
        candidate_capacity=1,
        contact_model=contact_model,
        edges_per_diameter=edges_per_diameter,
    )
    state, records = test.consolidate(max_steps=3000, chunk_steps=1000, record_every=100, tolerance=0.01)
    assert int(state.error) == 0
    candidates = state.membrane.candidates
    assert test.runner.reallocations >= 1
    assert 2 <= int(candidates.max_count) <= candidates.capacity
    load = test.cell_pressure * test.platen_area
    sphere_force = np.asarray(state.membrane.sphere_force).sum(axis=0)
    reaction = np.asarray(state.membrane.platen_reaction).sum(axis=0)
    np.testing.assert_allclose(reaction + sphere_force, 0.0, atol=0.01 * load)
    platen_force = np.asarray(records.wall_force[-1, 0])  # (bottom, top) normal forces of the spheres
    assert abs(platen_force[0] - platen_force[1] + sphere_force[2]) < 0.01 * load
    # The servo holds the ram (spheres + the membrane's pull on the platen) at p A, not the sphere force.
    assert abs(float(records.ram_force[-1, 0]) / load - 1.0) < 0.01
    penetration = float(test.max_penetration(state))
    assert penetration < 0.5 * float(test.params.membrane.thickness)


def test_a_mesh_whose_rings_share_a_node_is_refused():
    # The rings are set with unique_indices in the step: a repeated node would make that set undefined.
    radius, height = 0.05, 0.1
    mesh = cylinder_mesh(radius, height, 0.02)
    mesh = mesh.set(top_ring=mesh.top_ring.at[0].set(mesh.bottom_ring[0]))
    particles = make_particles(jnp.full(2, 0.1 * radius), 2650.0)
    frame = pair_neighbor_fn(np.full(3, -0.1), np.full(3, 0.2), 0.01, 0.02, 0)
    with pytest.raises(ValueError, match="rings repeat a node"):
        membrane_dem.membrane_dem(particles, frame, mesh, 1e-6, platen_area=np.pi * radius**2)


def test_the_membrane_critical_time_step_is_the_dense_eigenvalue_and_the_same_on_every_call():
    """Δt_mesh = 2/√λ_max(M^-1/2 K M^-1/2), K the membrane's stiffness at rest: Lanczos (tol 1e-3) against
    numpy's dense eigenvalues of the same matrix (built column by column from the Hessian–vector product),
    within 1e-3; and two calls give the same bits (a fixed Lanczos start vector: a run's Δt is repeatable)."""
    radius, height, modulus, thickness = 0.05, 0.08, 1.4e6, 0.005
    mesh, params, _, _ = _clamped_cylinder(
        radius, height, 2 * np.pi * radius / 12, modulus, thickness, 1e4, DampingParams.local(0.3)
    )
    first = stability.membrane_critical_time_step(mesh, params.membrane, contacts_per_node=0)
    again = stability.membrane_critical_time_step(mesh, params.membrane, contacts_per_node=0)
    assert first == again
    mass = np.asarray(energies.lumped_mass(mesh, params.membrane.thickness, LATEX_DENSITY))
    free = np.repeat(np.asarray(free_node_mask(mesh)), 3)
    scale = np.repeat(1.0 / np.sqrt(mass), 3) * free
    stiffness = (
        params.membrane.modulus,
        params.membrane.thickness,
        params.membrane.cell_pressure,
        params.membrane.bending_factor,
        params.membrane.locking_jm,
    )
    basis = jnp.asarray((np.eye(3 * mesh.num_nodes) * scale).reshape(-1, mesh.num_nodes, 3))
    products = jax.vmap(
        lambda vector: stability._stiffness_product(
            vector, mesh.reference_position, mesh, *stiffness, model="neo_hookean"
        )
    )(basis)
    dense = (np.asarray(products).reshape(basis.shape[0], -1) * scale).T  # column j: M^-1/2 K M^-1/2 e_j
    largest = np.linalg.eigvalsh(0.5 * (dense + dense.T))[-1]
    assert first["mesh"] == pytest.approx(2.0 / np.sqrt(largest), rel=1e-3)


@pytest.mark.parametrize("contact_model", ["nodes", "faces"])
def test_a_wider_candidate_table_changes_no_bit(contact_model):
    """A node table's capacity K only pads its rows: 300 consolidating steps (float64, the 4 × 4 × 5
    specimen, no overflow) with K = 12, and with K = 12 cut back after 150 steps to the largest count + 2
    (:func:`membrax.membrane.candidates.fitted_candidate_capacities`, as a resumed batch is), end on the same
    bits, so that growing one capacity of the table (or not growing another) cannot change a run.
    The padded slots add exact zeros to every sum and a sphere's slots keep their order (flat ids
    node · K + k increase with the node for any K)."""
    from membrax.spheres import fcc

    def run(capacity, fit=False):
        test = membrane_test(
            fcc.fcc_specimen(0.025, 4, 5),
            cell_pressure=1e4,
            membrane_thickness=5e-3,
            candidate_capacity=capacity,
            contact_model=contact_model,
            edges_per_diameter=2.0,
        )
        steps = jax.jit(
            lambda s, n: jax.lax.fori_loop(0, n, lambda _, x: test.runner.step_fn(x, test.params), s),
            static_argnums=1,
        )
        state = test.set_platens(test.initial_state, True, 0.0, test.cell_pressure)
        if fit:
            state = steps(state, 150)
            capacities = fitted_candidate_capacities(state.membrane.candidates)
            assert capacities.capacity < capacity  # it was cut
            thickness = test.params.membrane.contact_thickness
            state = membrane_dem.grow_candidates(state, test.particles, capacities, thickness, test.mesh)
            return jax.device_get(steps(state, 150)), test.dt
        return jax.device_get(steps(state, 300)), test.dt

    with jax.enable_x64(True):
        (wide, dt_wide), (fitted, dt_fitted) = run(12), run(12, fit=True)
    assert dt_wide == dt_fitted
    assert int(wide.dem.error) == int(fitted.dem.error) == 0
    assert int(fitted.membrane.candidates.max_count) >= 2  # nodes do see more than one sphere
    assert fitted.membrane.candidates.capacity < 12
    assert float(np.abs(wide.membrane.velocity).max()) > 0.0  # it moved
    assert float(np.abs(wide.membrane.sphere_force).max()) > 0.0  # and the membrane pressed on spheres
    for name in ("position", "velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(wide.dem, name), getattr(fitted.dem, name))
    for name in ("position", "velocity", "node_force", "sphere_force"):
        np.testing.assert_array_equal(getattr(wide.membrane, name), getattr(fitted.membrane, name))
