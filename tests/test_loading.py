"""Start of shearing, load paths, areas and options of the membrane test.

Each test checks a closed form, a hand calculation or a symmetry: the platen ramp's velocity and travel,
the step counts of a ramped stage, symmetric loading, the seeded imperfection, where nodes touch spheres,
the hoop strain of a uniformly stretched membrane, and the areas counted from the start of shearing.
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from membrax.driver import two_rate_plan
from membrax.membrane import measure as membrane_measure
from membrax.membrane.mesh import cylinder_mesh
from membrax.membrane.records import right_cylinder_stresses
from membrax.run_records import rebase_to_shear_start
from membrax.spheres import fcc
from membrax.spheres.walls import (
    BOTTOM,
    TOP,
    advance_walls,
    change_speed,
    ramp_acceleration,
    ramped_velocity,
    set_control,
    triaxial_walls,
)
from membrax.triaxial.membrane_cell import membrane_test


def _ramp(walls, dt, steps):
    def step(w, _):
        w = advance_walls(w, dt)
        w = w.set(velocity=ramped_velocity(w, dt))
        return w, (w.velocity, w.position)

    return jax.lax.scan(step, walls, None, length=steps)[1]


def test_a_ramped_platen_reaches_its_speed_linearly_and_travels_half_as_far_meanwhile():
    """v_n = min(n a Δt, v) exactly; over the ramp time t_r = v/a the platen travels v t_r / 2 (a
    triangle's area), afterwards v per unit time; the step change (a = inf) is v from the first step."""
    dt, speed, ramp_steps = 1e-5, -2e-3, 400
    acceleration = abs(speed) / (ramp_steps * dt)
    walls = set_control(triaxial_walls(np.zeros((0, 2)), np.zeros(0), 0.3), False, speed, 0.0, acceleration)
    np.testing.assert_array_equal(np.asarray(walls.velocity), 0.0)
    velocity, position = jax.jit(_ramp, static_argnums=2)(walls, dt, 2 * ramp_steps)
    n = np.arange(1, 2 * ramp_steps + 1)
    expected = np.sign(speed) * np.minimum(n * acceleration * dt, abs(speed))
    np.testing.assert_allclose(np.asarray(velocity)[:, 0, TOP], expected, rtol=1e-12, atol=1e-18)
    # position after step n uses the velocity of step n − 1 (leapfrog): Σ_{k<n} v_k Δt
    travelled = np.asarray(position)[:, 0, TOP] - 0.3
    ramp_travel = float(np.sum(expected[: ramp_steps - 1]) * dt)
    assert ramp_travel == pytest.approx(0.5 * speed * ramp_steps * dt, rel=5e-3)
    assert travelled[-1] == pytest.approx(float(np.sum(expected[:-1]) * dt), rel=1e-12)
    instant = set_control(walls, False, speed, 0.0)
    assert float(instant.velocity[0, TOP]) == speed and float(instant.acceleration[0, TOP]) == math.inf
    # vmap over members' speeds equals a loop
    speeds = jnp.asarray([-1e-3, -2e-3])
    batched = jax.vmap(lambda v: _ramp(set_control(walls, False, v, 0.0, acceleration), dt, 50)[0])(speeds)
    for k, v in enumerate(speeds):
        single = _ramp(set_control(walls, False, v, 0.0, acceleration), dt, 50)[0]
        np.testing.assert_allclose(np.asarray(batched[k]), np.asarray(single), rtol=1e-15)


def test_a_ramp_delays_every_later_strain_by_the_ramp_strain():
    """Full speed at ε_ramp after t_r = 2 ε_ramp/ε̇: the strain then lags the unramped one by ε̇ t_r/2 =
    ε_ramp, so the fine phase takes ε_ramp × steps-per-strain more steps and the coarse phase the same."""
    assert two_rate_plan(1024.0, 0.5, 0.125) == (128, 384)
    assert two_rate_plan(1024.0, 0.5, 0.125, ramp_strain=0.0625) == (192, 384)


def test_a_rate_change_covers_its_strain_at_the_mean_rate():
    """The platen at ε̇₁ H changes to ε̇₂ H = 4 ε̇₁ H linearly in t = 2 ε_t/(ε̇₁ + ε̇₂), so meanwhile it
    travels ε_t H (the mean speed's), then ε̇₂ H per unit time; the plan counts the same steps."""
    dt, height, rate, change_strain = 1e-5, 0.3, 2.0, 0.01  # ε̇₁ Δt = 2e-5 per step
    walls = set_control(triaxial_walls(np.zeros((0, 2)), np.zeros(0), height), False, -rate * height, 0.0)
    faster = change_speed(walls, 4.0, rate, change_strain)
    steps = round(2.0 * change_strain / (5.0 * rate) / dt)  # 200 steps of change
    assert float(faster.target_velocity[0, TOP]) == pytest.approx(-4.0 * rate * height, rel=1e-12)
    velocity, position = jax.jit(_ramp, static_argnums=2)(faster, dt, 2 * steps)
    n = np.arange(1, 2 * steps + 1)
    expected = -rate * height * np.minimum(1.0 + 3.0 * n / steps, 4.0)
    np.testing.assert_allclose(np.asarray(velocity)[:, 0, TOP], expected, rtol=1e-12)
    travel = height - float(position[steps, 0, TOP])  # after the change's steps (leapfrog: one step late)
    assert travel == pytest.approx(change_strain * height, rel=2.0 / steps)
    unchanged = change_speed(walls, 1.0, rate, change_strain)
    np.testing.assert_array_equal(np.asarray(unchanged.acceleration), np.asarray(walls.acceleration))
    step_change = change_speed(walls, 4.0, rate, 0.0)
    assert float(step_change.acceleration[0, TOP]) == math.inf
    # The plan: (ε_coarse − ε_t)/(ε̇₂ Δt) + 2 ε_t/((ε̇₁ + ε̇₂) Δt) steps after the fine phase.
    assert two_rate_plan(1024.0, 0.5, 0.125, 0.0625, coarse_steps_per_strain=256.0) == (192, 106)
    assert two_rate_plan(1024.0, 0.5, 0.125, 0.0625, coarse_steps_per_strain=1024.0) == (192, 384)


@pytest.fixture(scope="module")
def small_test():
    specimen = fcc.fcc_specimen(0.025, 4, 5)
    return membrane_test(specimen, cell_pressure=1e4, membrane_thickness=5e-3, edges_per_diameter=2.5)


def test_symmetric_shearing_moves_both_platens_at_half_the_rate_and_ramps_to_the_strain(small_test):
    test = small_test
    state = test.initial_state
    height = test.initial_height
    rate = test.shear_rate(1e-3)
    sheared = test.start_shear(state, 1e-3, ramp_strain=1e-3, symmetric=True)
    walls = sheared.dem.walls
    np.testing.assert_allclose(np.asarray(walls.target_velocity)[0], [-0.5 * rate * height] * 2, rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(walls.velocity), 0.0)
    # full closing speed ε̇ H reached after t_r = 2 ε_ramp / ε̇
    ramp_time = 2e-3 / rate
    total = float(walls.acceleration[0, BOTTOM] + walls.acceleration[0, TOP]) * ramp_time
    assert total == pytest.approx(rate * height, rel=1e-12)
    top_only = test.start_shear(state, 1e-3, ramp_strain=0.0, symmetric=False).dem.walls
    np.testing.assert_allclose(np.asarray(top_only.velocity)[0], [0.0, -rate * height], rtol=1e-12)
    # the wave-transit ratio: t_r c / H with c = d √(k/m)
    mass = float(test.particles.mass[0])
    speed = 0.025 * math.sqrt(1e7 / mass)
    assert test.ramp_transit_ratio(1e-3, 1e-3) == pytest.approx(ramp_time * speed / height, rel=1e-12)


def test_the_seeded_imperfection_is_reproducible_and_only_shrinks_spheres():
    specimen = fcc.fcc_specimen(0.025, 4, 5)
    one = fcc.with_imperfection(specimen, 1e-3, seed=7)
    again = fcc.with_imperfection(specimen, 1e-3, seed=7)
    other = fcc.with_imperfection(specimen, 1e-3, seed=8)
    radius, nominal = np.asarray(one.radius), np.asarray(specimen.radius)
    np.testing.assert_array_equal(radius, np.asarray(again.radius))
    assert np.any(radius != np.asarray(other.radius))
    reduction = (nominal - radius) / 0.025
    assert reduction.min() >= 0.0 and reduction.max() <= 1e-3
    # uniform on [0, f D): mean f D / 2 within 4 standard errors (σ = f/√12 per sphere)
    assert abs(reduction.mean() - 5e-4) < 4 * 1e-3 / math.sqrt(12 * reduction.size)
    np.testing.assert_array_equal(np.asarray(one.position), np.asarray(specimen.position))
    np.testing.assert_array_equal(np.asarray(fcc.with_imperfection(specimen, 0.0).radius), nominal)
    with pytest.raises(ValueError, match="fraction"):
        fcc.with_imperfection(specimen, -1e-3)
    # Its contacts are open, so Δt is the touching lattice's: the same as the perfect specimen's.
    perfect = membrane_test(specimen, cell_pressure=1e4, membrane_thickness=5e-3)
    imperfect = membrane_test(one, cell_pressure=1e4, membrane_thickness=5e-3)
    assert imperfect.dt == pytest.approx(perfect.dt, rel=1e-12)


@pytest.mark.parametrize("factor", [0.0, 0.5, 1.0])
def test_nodes_touch_spheres_at_the_chosen_offset(factor):
    """The mesh is built f t_m/2 outside the outer spheres: on a flat face of the octagon the rest nodes
    lie at R + f t_m/2 from the plane of the outer sphere centres, where the contact's overlap is zero."""
    specimen = fcc.fcc_specimen(0.025, 4, 5)
    thickness = 5e-3
    test = membrane_test(specimen, 1e4, 5e-3, edges_per_diameter=2.5, contact_offset_factor=factor)
    assert float(test.params.membrane.contact_thickness) == pytest.approx(factor * thickness, rel=1e-15)
    position = np.asarray(test.mesh.reference_position)
    centres = np.asarray(specimen.position)
    face = centres[:, 0].max()  # the +x flat face's sphere centres
    on_face = (position[:, 0] > 0.0) & (np.abs(position[:, 1]) < 0.5 * (centres[:, 1].max() - 0.0125))
    gap = position[on_face, 0] - face
    np.testing.assert_allclose(gap, 0.0125 + 0.5 * factor * thickness, rtol=1e-9)


def test_hoop_strain_of_a_uniformly_stretched_membrane_is_the_stretch():
    """ε_θ = λ − 1 for every node scaled radially by λ, whatever the mesh (a ring's length scales by λ)."""
    mesh = cylinder_mesh(0.1, 0.3, 0.02)
    for stretch in (1.0, 1.01, 0.97):
        position = mesh.reference_position * jnp.asarray([[stretch, stretch, 1.0]])
        assert float(membrane_measure.hoop_strain(position, mesh)) == pytest.approx(stretch - 1.0, abs=1e-14)
    grad = jax.grad(
        lambda s: membrane_measure.hoop_strain(
            mesh.reference_position * jnp.stack([s, s, jnp.ones_like(s)])[None], mesh
        )
    )
    assert float(grad(jnp.asarray(1.0))) == pytest.approx(1.0, rel=1e-12)


def test_areas_count_from_the_start_of_shearing():
    """A = A₀ (1 − ε_v)/(1 − ε_a) with strains from the reference state: at the reference itself the
    external σ1 is ram/A₀ (the servo's σc), internal σ3 = F_r / (2 √(π A₀) H₀); and a right cylinder
    squeezed by ε_a at constant volume has A = A₀/(1 − ε_a)."""
    area0, height0, volume0 = 0.05, 0.4, 0.05 * 0.4 * 0.95
    records = {
        "height": np.array([height0, 0.9 * height0]),
        "volume": np.array([volume0, volume0]),
        "axial_strain": np.array([0.07, 0.16]),
        "volumetric_strain": np.array([0.05, 0.05]),
        "ram_force": np.array([500.0, 2000.0]),
        "received_axial_force": np.array([600.0, 2100.0]),
        "membrane_radial_force": np.array([900.0, 1000.0]),
        "clamp_radial_force": np.array([100.0, 100.0]),
    }
    out = rebase_to_shear_start(records, {"height": height0, "volume": volume0, "platen_area": area0})
    np.testing.assert_allclose(out["platen_area"], [area0, area0 / 0.9], rtol=1e-14)
    np.testing.assert_allclose(out["external_axial_stress"][0], 500.0 / area0, rtol=1e-14)
    np.testing.assert_allclose(out["internal_axial_stress"][1], 2100.0 * 0.9 / area0, rtol=1e-14)
    lateral = 2.0 * math.sqrt(math.pi * area0) * height0
    np.testing.assert_allclose(out["internal_radial_stress"][0], 1000.0 / lateral, rtol=1e-14)
    np.testing.assert_allclose(out["axial_strain"], [0.0, 0.1], atol=1e-15)
    np.testing.assert_array_equal(out["consolidation_axial_strain"], 0.07)
    np.testing.assert_array_equal(out["consolidation_volumetric_strain"], 0.05)


def test_right_cylinder_stresses_work_under_jit_and_grad():
    def external(ram, height):
        return right_cylinder_stresses(ram, ram, ram, height, 1.0, 1.0, 1.0, 1.0)[1]

    # A = A₀ / (1 − ε_a) at constant volume: σ = F (1 − ε_a)/A₀ = F H/H₀; dσ/dH = F/H₀
    value = jax.jit(external)(jnp.asarray(3.0), jnp.asarray(0.9))
    assert float(value) == pytest.approx(2.7, rel=1e-14)
    assert float(jax.grad(external, argnums=1)(jnp.asarray(3.0), jnp.asarray(0.9))) == pytest.approx(3.0)


def _consolidated_start(test, records):
    """The shear's reference state: the last consolidation record's height and volume, the platen area."""
    return {
        "height": float(records.height[-1, 0]),
        "volume": float(records.volume[-1, 0]),
        "platen_area": test.platen_area,
    }


def _rebased(records, start):
    """A stage's records as numpy arrays, strains and stresses from the shear's start ``start``."""
    return rebase_to_shear_start(
        {f.name: np.asarray(getattr(records, f.name)) for f in dataclasses.fields(records)}, start
    )


def _peak_friction_angles(test, state, start, inertial_number):
    """(external, internal) peak φ' of a short ramped shear from ``state``, degrees."""
    _, records = test.shear(
        state,
        target_axial_strain=0.002,
        inertial_number=inertial_number,
        record_every_fine=10,
        fine_until_strain=0.002,
        chunk_steps=5000,
        ramp_strain=1e-2,
    )
    rebased = _rebased(records, start)

    def phi(major, minor):
        return np.degrees(np.arcsin((major - minor) / (major + minor)))

    external = phi(rebased["external_axial_stress"].ravel(), test.cell_pressure)
    internal = phi(rebased["internal_axial_stress"].ravel(), rebased["internal_radial_stress"].ravel())
    return float(np.nanmax(external)), float(np.nanmax(internal))


@pytest.mark.slow
def test_the_ramped_peak_is_a_material_number_not_a_rate_effect():
    """Peak φ' at I = 1e-3 and at I/2 agree within 0.5° (external and internal) with the default ramp:
    the lattice's peak, its elastic limit at ~0.01 % strain, is approached quasi-statically (4 × 4 × 5
    specimen, 10 kPa, 5 mm, float64).

    Why 0.5°: round-off alone moves these peaks. Three builds of the same contact law that differ only in
    rounding (before and after the spring-rotation cap of spheres/contact.py, and with the cap disabled)
    gave differences fast − slow of 0.09°/0.04°, 0.12°/0.00° and 0.34°/0.25° (external/internal), and
    moved each peak by up to 0.45°: the bound is that scatter, not a rate effect."""
    specimen = fcc.fcc_specimen(0.025, 4, 5)
    test = membrane_test(specimen, cell_pressure=1e4, membrane_thickness=5e-3, edges_per_diameter=2.5)
    state, records = test.consolidate(max_steps=6000, chunk_steps=1000, record_every=100, tolerance=0.01)
    start = _consolidated_start(test, records)
    fast = _peak_friction_angles(test, state, start, 1e-3)
    slow = _peak_friction_angles(test, state, start, 5e-4)
    assert abs(fast[0] - slow[0]) < 0.5 and abs(fast[1] - slow[1]) < 0.5, (fast, slow)


@pytest.mark.slow
def test_the_membranes_radial_stress_grows_with_the_hoop_strain_below_henkel_and_gilberts_bound():
    """During shearing the membrane's extra radial stress Δσ_r (internal σ3 from the start of shearing)
    grows with the mid-height hoop strain ε_θ and stays at or below Henkel & Gilbert's 2 E_m t_m Δε_θ / D₀
    (`membrane-corrections.md`, hoop tension): that formula puts the mid-height strain, the barrel's
    largest, on the whole height of a membrane free at its ends. 4 × 4 × 6 specimen, 10 kPa, 5 mm, float64;
    the issue-16 note gives the measured ratio (0.5–0.9 here, ~0.5 beyond 4 % at demo size)."""
    specimen = fcc.fcc_specimen(0.025, 4, 6)
    test = membrane_test(specimen, cell_pressure=1e4, membrane_thickness=5e-3, edges_per_diameter=3.0)
    state, records = test.consolidate(max_steps=20000, chunk_steps=1000, record_every=100, tolerance=0.01)
    start = _consolidated_start(test, records)
    _, shear = test.shear(
        state,
        target_axial_strain=0.08,
        inertial_number=5e-3,
        record_every_fine=100,
        fine_until_strain=0.001,
        record_every_coarse=500,
        ramp_strain=1e-3,
    )
    rebased = _rebased(shear, start)
    axial = rebased["axial_strain"].ravel()
    radial_excess = rebased["internal_radial_stress"].ravel() - rebased["internal_radial_stress"].ravel()[0]
    hoop = rebased["hoop_strain"].ravel() - rebased["hoop_strain"].ravel()[0]
    diameter = 2.0 * math.sqrt(test.platen_area / math.pi)
    henkel_gilbert = 2.0 * 1.4e6 * 5e-3 * hoop / diameter
    picks = [int(np.argmin(np.abs(axial - strain))) for strain in (0.02, 0.04, 0.06, 0.08)]
    ratio = radial_excess[picks] / henkel_gilbert[picks]
    assert np.all(np.diff(radial_excess[picks]) > 0.0) and np.all(np.diff(hoop[picks]) > 0.0), ratio
    assert np.all(ratio > 0.0) and np.all(ratio <= 1.0), ratio


def test_the_ramp_acceleration_reaches_full_speed_at_the_ramp_strain():
    """a = |v| ε̇/(2 ε_r): from rest the platen travels v²/(2a) = |v| ε_r/ε̇ before full speed, i.e. the
    axial strain ε_r of a specimen of height H = |v|/ε̇ (by hand); no ramp and still walls give inf."""
    rate, height, ramp = 0.08, 0.45, 0.01
    velocity = np.array([[-0.5 * rate * height, -0.5 * rate * height, 0.0]])
    acceleration = ramp_acceleration(velocity, rate, ramp)
    travel = velocity[0, :2] ** 2 / (2.0 * acceleration[0, :2])
    np.testing.assert_allclose(2.0 * travel / height, ramp, rtol=1e-15)  # both platens: the total strain
    assert np.isinf(acceleration[0, 2])
    assert np.all(np.isinf(ramp_acceleration(velocity, rate, 0.0)))


def test_a_ramped_rigid_wall_test_sets_the_platen_acceleration_of_its_ramp():
    """The rigid-wall cell ramps like the membrane cell: top platen at ε̇ H with a = ε̇² H/(2 ε_r), the
    lateral walls servo-held (infinite acceleration: no ramp), by hand."""
    from membrax.triaxial.rigid import rigid_wall_test

    test = rigid_wall_test(fcc.fcc_specimen(0.025, 3, 4), cell_pressure=1e4)
    state = test.start_shear(test.initial_state, inertial_number=1e-3, ramp_strain=0.01)
    rate = test.shear_rate(1e-3)
    height = float(state.walls.position[0, TOP] + state.walls.position[0, BOTTOM])
    walls = state.walls
    assert float(walls.acceleration[0, TOP]) == pytest.approx(rate**2 * height / 0.02, rel=1e-6)
    assert np.all(np.isinf(np.asarray(walls.acceleration[0, 2:])))
    fine, _ = test.shear_plan(0.02, 1e-3, 0.01, ramp_strain=0.01)
    # the ramp delays every later strain by ε_r/ε̇: (ε_fine + ε_r)/(ε̇ Δt) steps (two_rate_plan)
    assert fine == math.ceil((0.01 + 0.01) / (rate * test.dt))
