"""The membrane's stretching laws against their closed forms: the Gent law (a strain-stiffening rubber) beside
the neo-Hookean and St Venant–Kirchhoff laws, its compiled kernels, its lock rule and its bulge theory.

Closed forms (incompressible, plane stress, λ₃ = 1/(λ₁λ₂); Gent 1996, Rubber Chem. Technol. 69, 59–61):
W = −(μ J_m/2) ln(1 − (I₁ − 3)/J_m) per unit reference volume, μ = E_m/3, and the principal Cauchy stresses
σᵢ = 2 (∂W/∂I₁)(λᵢ² − λ₃²) = μ (λᵢ² − λ₃²)/(1 − (I₁ − 3)/J_m).
"""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ACCUMULATED, SMALL_MEMBRANE_TEST, central_difference, clamped_cylinder_parts, tolerance

from membrax import assemble, native, theory
from membrax.config import with_overrides
from membrax.defaults import GENT_LOCK_FRACTION, LATEX_DENSITY
from membrax.driver import ChunkRunner
from membrax.errors import ErrorCode, SimulationError, describe
from membrax.membrane import coupled, energies, face_contact, stability
from membrax.membrane.mesh import MembraneMesh, cylinder_mesh, flat_mesh, free_node_mask, green_strain
from membrax.spheres.contact import ContactParams
from membrax.spheres.integrate import DampingParams, DEMParams, sphere_dem

MODULUS, THICKNESS = 1.4e6, 2e-3
SHEAR = MODULUS / 3.0


def _patch(dtype=jnp.float64) -> MembraneMesh:
    """A flat patch in the xy-plane: under a homogeneous deformation every triangle has the same strain, so
    the energy per unit reference volume is the law's W at that strain."""
    return flat_mesh(0.3, 0.2, 0.05, dtype=dtype)


def _deformed(mesh, gradient):
    """Node positions under the in-plane deformation gradient ``gradient`` (2 × 2), z = 0."""
    full = jnp.eye(3, dtype=mesh.reference_position.dtype).at[:2, :2].set(gradient)
    return mesh.reference_position @ full.T


def _cauchy_stress(model, stretches, locking_jm, dtype=jnp.float64):
    """σ₁₁, σ₂₂ of the patch at F = diag(λ₁, λ₂) from jax.grad of its energy: P = ∂W/∂F/(t₀ A₀) and
    σ = P Fᵀ (J = 1, incompressible)."""
    mesh = _patch(dtype)
    volume = THICKNESS * float(jnp.sum(mesh.reference_area))

    def energy(gradient):
        return energies.stretching_energy(
            _deformed(mesh, gradient), mesh, MODULUS, THICKNESS, model=model, locking_jm=locking_jm
        )

    gradient = jnp.diag(jnp.asarray(stretches, dtype))
    nominal = jax.grad(energy)(gradient) / volume
    return np.diag(np.asarray(nominal @ gradient.T, dtype=np.float64))


def _gent_stress(stretch_1, stretch_2, locking_jm):
    """The closed form σᵢ = μ (λᵢ² − λ₃²)/(1 − (I₁ − 3)/J_m), λ₃ = 1/(λ₁λ₂)."""
    thickness_sq = 1.0 / (stretch_1 * stretch_2) ** 2
    excess = stretch_1**2 + stretch_2**2 + thickness_sq - 3.0
    factor = SHEAR / (1.0 - excess / locking_jm)
    return np.array([factor * (stretch_1**2 - thickness_sq), factor * (stretch_2**2 - thickness_sq)])


@pytest.mark.parametrize("locking_jm", [8.0, 97.2])  # λ = 2 at J_m = 8: s = 0.63
@pytest.mark.parametrize("stretch", [1.05, 1.5, 2.0])
def test_equibiaxial_gent_tension_matches_the_closed_form(stretch, locking_jm):
    """Equibiaxial λ: σ = μ (λ² − λ⁻⁴)/(1 − (2λ² + λ⁻⁴ − 3)/J_m); the current thickness is t₀/λ², so the
    tension per unit current length is T = σ t₀/λ² = μ t₀ (1 − λ⁻⁶)/(1 − (I₁ − 3)/J_m). Checked from
    jax.grad of a flat patch's energy two ways: the stress tensor, and T = (dW/dλ)/(dA/dλ) = (dW/dλ)/(2λA₀)
    (the work of the tension on the area change). Also the theory module's closed form."""
    sigma = _cauchy_stress("gent", (stretch, stretch), locking_jm)
    expected = _gent_stress(stretch, stretch, locking_jm)
    np.testing.assert_allclose(sigma, expected, rtol=1e-12)
    mesh = _patch()
    area = float(jnp.sum(mesh.reference_area))
    work = jax.grad(
        lambda s: energies.stretching_energy(
            _deformed(mesh, s * jnp.eye(2)), mesh, MODULUS, THICKNESS, model="gent", locking_jm=locking_jm
        )
    )(stretch)
    excess = 2.0 * stretch**2 + stretch**-4 - 3.0
    tension = SHEAR * THICKNESS * (1.0 - stretch**-6) / (1.0 - excess / locking_jm)
    np.testing.assert_allclose(float(work) / (2.0 * stretch * area), tension, rtol=1e-12)
    np.testing.assert_allclose(float(theory.gent_equibiaxial_stress(SHEAR, stretch, locking_jm)), expected[0])


@pytest.mark.parametrize("stretch", [1.2, 2.0, 3.0])
def test_uniaxial_gent_stress_matches_the_closed_form_and_the_sides_are_free(stretch):
    """Uniaxial tension of an incompressible sheet: λ₂ = λ₃ = λ^(−1/2), so σ₂₂ = 0 (free sides) and
    σ₁₁ = μ (λ² − 1/λ)/(1 − (λ² + 2/λ − 3)/J_m)."""
    locking_jm = 20.0
    sigma = _cauchy_stress("gent", (stretch, stretch**-0.5), locking_jm)
    excess = stretch**2 + 2.0 / stretch - 3.0
    np.testing.assert_allclose(
        sigma[0], SHEAR * (stretch**2 - 1.0 / stretch) / (1.0 - excess / locking_jm), rtol=1e-12
    )
    assert abs(sigma[1]) < 1e-12 * sigma[0]


def test_gent_tends_to_neo_hookean_as_the_lock_recedes():
    """At fixed strain, W_Gent/W_neo-Hookean − 1 = −ln(1 − s)/s − 1 = s/2 + s²/3 + …, s = (I₁ − 3)/J_m: the
    relative difference (I₁ − 3)/(2 J_m) to first order; the stresses differ by the factor 1/(1 − s)."""
    mesh = _patch()
    position = _deformed(mesh, jnp.asarray([[1.4, 0.1], [0.0, 1.1]]))
    neo_hookean = float(energies.stretching_energy(position, mesh, MODULUS, THICKNESS))
    excess = neo_hookean / (SHEAR / 2.0 * THICKNESS * float(jnp.sum(mesh.reference_area)))  # I₁ − 3
    for locking_jm in (1e2, 1e4, 1e6):
        gent = float(
            energies.stretching_energy(position, mesh, MODULUS, THICKNESS, "gent", locking_jm=locking_jm)
        )
        ratio = excess / locking_jm
        assert gent / neo_hookean - 1.0 == pytest.approx(-math.log1p(-ratio) / ratio - 1.0, rel=1e-7)
        assert gent / neo_hookean - 1.0 == pytest.approx(ratio / 2.0, rel=ratio)
    stress = _cauchy_stress("gent", (1.3, 1.1), 1e8)
    np.testing.assert_allclose(stress, _cauchy_stress("neo_hookean", (1.3, 1.1), 1e8), rtol=1e-7)


def test_the_three_laws_share_the_small_strain_plane_stress_tangent():
    """At zero strain the Hessian of the energy per unit volume in the displacement gradient H is the plane
    stress tangent of E_m and ν = ½ for all three laws (SVK with ν = ½): ∂²W/∂H₁₁² = E/(1 − ν²) = 4E/3,
    ∂²W/∂H₁₁∂H₂₂ = νE/(1 − ν²) = 2E/3, ∂²W/∂H₁₂² = ∂²W/∂H₁₂∂H₂₁ = G = E/3 (W = G(H₁₂ + H₂₁)²/2)."""
    mesh = _patch()
    volume = THICKNESS * float(jnp.sum(mesh.reference_area))
    expected = (MODULUS / 0.75) * np.array(
        [[1.0, 0.0, 0.0, 0.5], [0.0, 0.25, 0.25, 0.0], [0.0, 0.25, 0.25, 0.0], [0.5, 0.0, 0.0, 1.0]]
    )  # rows and columns H₁₁, H₁₂, H₂₁, H₂₂
    for model in ("neo_hookean", "gent", "svk"):

        def energy(flat, model=model):
            gradient = jnp.eye(2) + flat.reshape(2, 2)
            return energies.stretching_energy(
                _deformed(mesh, gradient), mesh, MODULUS, THICKNESS, model, 0.5, locking_jm=97.2
            )

        tangent = (
            np.asarray(jax.jacrev(jax.grad(energy))(jnp.zeros(4))) / volume
        )  # the gathers are reverse-only
        np.testing.assert_allclose(tangent, expected, rtol=1e-12, atol=1e-12 * MODULUS)


def test_the_gent_lock_is_continued_finitely_and_checked():
    """Past s = (I₁ − 3)/J_m = f (0.9) the energy is its quadratic extension in s: the stress factor
    φ'(s) = 1/(1 − f) + (s − f)/(1 − f)² stays finite and continuous at f (10 on both sides), the energy
    finite at and past the lock (s = 1, 2), and :func:`energies.locking_ratio` gives s, which the coupled
    step turns into ``ErrorCode.MEMBRANE_LOCKED`` past f, with a message naming the fix."""
    mesh = _patch()
    stretch = 1.5
    excess = 2.0 * stretch**2 + stretch**-4 - 3.0

    def tension(ratio):
        return _cauchy_stress("gent", (stretch, stretch), excess / ratio)[0]

    neo_hookean = SHEAR * (stretch**2 - stretch**-4)
    for ratio, factor in ((0.5, 2.0), (0.9 - 1e-9, 10.0), (0.9 + 1e-9, 10.0), (1.0, 20.0), (2.0, 120.0)):
        assert tension(ratio) == pytest.approx(factor * neo_hookean, rel=1e-6)
    position = _deformed(mesh, stretch * jnp.eye(2))
    for ratio in (1.0, 2.0):
        energy = energies.stretching_energy(
            position, mesh, MODULUS, THICKNESS, "gent", locking_jm=excess / ratio
        )
        assert np.isfinite(float(energy))
    assert float(energies.locking_ratio(position, mesh, 10.0)) == pytest.approx(excess / 10.0, rel=1e-12)
    assert int(stability.locked_bit(position, mesh, excess / (GENT_LOCK_FRACTION - 1e-3))) == 0
    locked = int(stability.locked_bit(position, mesh, excess / (GENT_LOCK_FRACTION + 1e-3)))
    assert locked == ErrorCode.MEMBRANE_LOCKED
    assert "membrane_locking_jm" in describe(locked)[0]


def _deformed_cylinder(dtype=jnp.float64):
    mesh = cylinder_mesh(0.1, 0.2, 0.02)
    rng = np.random.default_rng(0)
    position = mesh.reference_position * jnp.asarray([1.3, 1.3, 0.95])[None, :] + jnp.asarray(
        rng.normal(0.0, 2e-3, mesh.reference_position.shape)
    )
    cast = jax.tree.map(lambda a: a.astype(dtype) if a.dtype == jnp.float64 else a, mesh)
    return cast, position.astype(dtype)


def _relative_error(result, reference):
    result, reference = np.asarray(result, np.float64), np.asarray(reference, np.float64)
    return np.max(np.abs(result - reference)) / np.max(np.abs(reference))


needs_kernels = pytest.mark.skipif(not native.available(), reason="no compiled kernels: JAX is the path")


@needs_kernels
@pytest.mark.parametrize("locking_jm", [97.2, 2.0, 0.5])  # the largest s: 0.018, 0.87, 3.5 (continued)
def test_gent_kernel_forces_and_cotangents_equal_the_jax_definition_in_float64(locking_jm):
    """The compiled forces are −∇ of the JAX energy (1e-12 of the largest entry), below and past the lock
    fraction, and the compiled reverse-mode rule gives ``jax.vjp`` of the JAX definition for the positions
    and every scalar, J_m's cotangent among them (1e-11: it is a small sum of cancelling terms)."""
    mesh, position = _deformed_cylinder()
    closest = float(energies.locking_ratio(position, mesh, locking_jm))  # 0.018, 0.87, 3.5
    assert (closest > GENT_LOCK_FRACTION) == (locking_jm < 1.0)
    scalars = (1.4e6, 0.004, 2e4, 0.45, 0.7, locking_jm)
    compiled = jax.jit(lambda x, *s: energies.nodal_forces(x, mesh, *s[:4], "gent", *s[4:]))
    reference = energies.reference_nodal_forces(position, mesh, *scalars[:5], "gent", locking_jm)
    assert _relative_error(compiled(position, *scalars), reference) < tolerance(jnp.float64)
    cotangent = jnp.asarray(np.random.default_rng(1).normal(size=position.shape))
    got = jax.vjp(lambda x, *s: energies._COMPILED_NODAL_FORCES["gent"](x, mesh, *s), position, *scalars)[1](
        cotangent
    )
    want = jax.vjp(
        lambda x, *s: energies.reference_nodal_forces(x, mesh, *s[:5], "gent", s[5]), position, *scalars
    )[1](cotangent)
    for index, (g, w) in enumerate(zip(got, want, strict=True)):
        assert _relative_error(g, w) < (1e-11 if index == 6 else tolerance(jnp.float64)), index


@needs_kernels
def test_gent_kernel_in_float32_is_as_accurate_as_jax():
    """In float32 the kernel and XLA err by the same amount against the float64 forces (float32 round-off
    of a few operations per triangle, summed at the nodes)."""
    mesh64, position64 = _deformed_cylinder()
    mesh32, position32 = _deformed_cylinder(jnp.float32)
    exact = energies.reference_nodal_forces(position64, mesh64, 1.4e6, 0.004, 2e4, 0.5, 1.0, "gent", 2.0)
    scalars = tuple(jnp.float32(v) for v in (1.4e6, 0.004, 2e4, 0.5))
    compiled = energies.nodal_forces(position32, mesh32, *scalars, "gent", jnp.float32(1.0), jnp.float32(2.0))
    reference = energies.reference_nodal_forces(
        position32, mesh32, *scalars, jnp.float32(1.0), "gent", jnp.float32(2.0)
    )
    assert compiled.dtype == jnp.float32
    error_kernel, error_jax = _relative_error(compiled, exact), _relative_error(reference, exact)
    assert error_kernel < 10 * tolerance(jnp.float32)
    assert error_kernel < 3.0 * error_jax


def test_jit_vmap_and_grad_over_the_modulus_and_the_lock():
    """vmap of the (compiled, on the CPU) Gent forces over E_m equals a loop; the forces are linear in E_m;
    d(ū·F)/dE_m = ū·F/E_m, and d(ū·F)/dJ_m by jax.grad equals a central difference."""
    mesh, position = _deformed_cylinder()
    direction = jnp.asarray(np.random.default_rng(2).normal(size=position.shape))

    def work(modulus, locking_jm):
        forces = energies.nodal_forces(position, mesh, modulus, 0.004, 0.0, 0.5, "gent", 0.0, locking_jm)
        return jnp.sum(direction * forces)

    moduli = jnp.asarray([0.7e6, 1.4e6, 2.8e6])
    batched = jax.jit(
        jax.vmap(lambda e: energies.nodal_forces(position, mesh, e, 0.004, 0.0, 0.5, "gent", 0.0, 2.0))
    )(moduli)
    for k in range(3):
        single = energies.nodal_forces(position, mesh, moduli[k], 0.004, 0.0, 0.5, "gent", 0.0, 2.0)
        assert _relative_error(batched[k], single) < tolerance(jnp.float64)
        assert _relative_error(batched[k], batched[0] * moduli[k] / moduli[0]) < tolerance(jnp.float64)
    d_modulus, d_locking = jax.jit(jax.grad(work, argnums=(0, 1)))(1.4e6, 2.0)
    assert float(d_modulus) == pytest.approx(float(work(1.4e6, 2.0)) / 1.4e6, rel=1e-12)
    assert float(d_locking) == pytest.approx(central_difference(work, (1.4e6, 2.0), 1), rel=1e-6)
    assert float(d_locking) != 0.0


def test_gent_bulge_pressure_tends_to_neo_hookean_and_has_the_limit_points_stated():
    """Theory: the Gent cap's pressure is the neo-Hookean one over 1 − (I₁ − 3)/J_m (relative difference
    (I₁ − 3)/J_m to first order, checked for J_m = 1e3 … 1e7), the same p = dW/dV by finite differences of
    the cap's energy W = t₀ π a² (−μ J_m/2) ln(1 − s), V = π h (3a² + h²)/6; its limit point 1.8827 μ t₀/a at
    J_m = 97.2 (84.8 kPa for 1 mm of 700 kPa over 25 mm spheres' windows, against the neo-Hookean 82.7),
    tending to 1.8353 as J_m → ∞, and none below J_m = 32.62 (a monotonic rise to the lock)."""
    modulus, thickness, aperture = 700.0, 1.0, 0.5 * theory.SQUARE_WINDOW_RATIO * 25.0
    height = 1.1 * aperture
    neo_hookean = float(theory.membrane_bulge_pressure(modulus, thickness, aperture, height))
    squared = 1.0 + (height / aperture) ** 2
    excess = 2.0 * squared + squared**-2 - 3.0
    for locking_jm in (1e3, 1e5, 1e7):
        gent = float(theory.gent_bulge_pressure(modulus, thickness, aperture, height, locking_jm))
        assert gent / neo_hookean - 1.0 == pytest.approx(excess / locking_jm, rel=2.0 * excess / locking_jm)

    def cap_energy(h, locking_jm=97.2):
        lam_sq = 1.0 + (h / aperture) ** 2
        ratio = (2.0 * lam_sq + lam_sq**-2 - 3.0) / locking_jm
        return thickness * math.pi * aperture**2 * (-(modulus / 3.0) * locking_jm / 2.0) * math.log1p(-ratio)

    def cap_volume(h):
        return math.pi * h * (3.0 * aperture**2 + h * h) / 6.0

    step = 1e-6 * aperture
    by_differences = (cap_energy(height + step) - cap_energy(height - step)) / (
        cap_volume(height + step) - cap_volume(height - step)
    )
    gent = float(theory.gent_bulge_pressure(modulus, thickness, aperture, height, 97.2))
    assert gent == pytest.approx(by_differences, rel=1e-8)
    assert float(theory.gent_bulge_pressure(modulus, thickness, aperture, 10.0 * aperture, 97.2)) == math.inf

    ratio, coefficient = theory.gent_bulge_limit(97.2)
    assert (ratio, coefficient) == pytest.approx((1.3141, 1.8827), abs=1e-4)
    assert theory.gent_membrane_limit_pressure(modulus, thickness, aperture, 97.2) == pytest.approx(
        84.845, rel=1e-4
    )
    assert theory.gent_bulge_limit(1e9)[1] == pytest.approx(theory.BULGE_LIMIT_COEFFICIENT, rel=1e-7)
    # The limit point is a maximum of p(h): p falls on both sides of it.
    for side in (-1e-3, 1e-3):
        beside = float(
            theory.gent_bulge_pressure(modulus, thickness, aperture, (ratio + side) * aperture, 97.2)
        )
        assert beside < coefficient * (modulus / 3.0) * thickness / aperture
    critical = theory.GENT_MONOTONIC_LOCKING_JM
    assert math.isinf(theory.gent_bulge_limit(0.9999 * critical)[1])
    assert math.isfinite(theory.gent_bulge_limit(1.0001 * critical)[1])
    assert math.isinf(theory.gent_membrane_limit_pressure(modulus, thickness, aperture, 30.0))
    # Below the critical J_m the pressure rises monotonically all the way to the lock.
    heights = np.linspace(0.01, 0.999 * theory.penetration._cap_lock_height(30.0), 2000) * aperture
    pressures = np.asarray(theory.gent_bulge_pressure(modulus, thickness, aperture, heights, 30.0))
    assert np.all(np.diff(pressures) > 0.0)


@pytest.mark.slow
def test_a_gent_membrane_cell_with_a_remote_lock_runs_as_the_neo_hookean_one():
    """The law wired end to end (configuration → assemble → cell → compiled step → driver): the small
    membrane test consolidated 600 steps with membrane_law = "gent" and J_m = 1e10 (stresses within
    (I₁ − 3)/J_m ~ 1e-13 of the neo-Hookean ones) equals the neo-Hookean run to float64 round-off carried
    through the steps; with J_m = 1e-3 the same step (J_m is traced) stiffens the membrane and the driver
    stops on the lock bit with a SimulationError that names it and the largest (I₁ − 3)/J_m reached."""
    states = {}
    for law in ("neo-hookean", "gent"):
        config = with_overrides(SMALL_MEMBRANE_TEST, membrane_law=law, membrane_locking_jm=1e10)
        with assemble.precision_scope(config):
            test = assemble.build_test(config)
            state, records = test.consolidate(
                max_steps=600, chunk_steps=300, record_every=100, tolerance=1e-12
            )
            states[law] = (test, state, records)
    _, neo_state, _ = states["neo-hookean"]
    gent_test, gent_state, _ = states["gent"]
    assert int(gent_state.error) == 0
    # The states, to the float64 round-off carried through 600 steps (the servo's ram force amplifies it
    # more: it differs by 1.2e-8 of itself, as a 1e-13 change of E_m in the neo-Hookean run moves it by 3e-8).
    for got, want in (
        (gent_state.membrane.position, neo_state.membrane.position),
        (gent_state.dem.position, neo_state.dem.position),
    ):
        assert _relative_error(got, want) < tolerance(jnp.float64, ACCUMULATED)
    params = gent_test.params
    locked = dataclasses.replace(
        gent_test, params=params.set(membrane=params.membrane.set(locking_jm=jnp.asarray(1e-3)))
    )
    # The message names the lock and the stretch reached at the run's (traced) J_m.
    named = r"Gent lock.*largest \(I1 - 3\)/J_m reached \d+\.\d{3} at J_m = 0\.001"
    with assemble.precision_scope(SMALL_MEMBRANE_TEST), pytest.raises(SimulationError, match=named):
        locked.consolidate(max_steps=600, chunk_steps=300, record_every=100, tolerance=1e-12)


# ------------------------------------------------------------------------ stability near the lock

#: Gent's equibiaxial tangent ratio k_t/k_0 at J_m = 97.2, from the closed form (energies.gent_tangent_ratio).
GENT_TANGENT_RATIOS = {0.1: 0.2421345401, 0.5: 1.0411462776, 0.7: 3.2623709688, 0.9: 32.694725455}


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
@pytest.mark.parametrize("ratio", sorted(GENT_TANGENT_RATIOS))
def test_gent_tangent_ratio_is_the_finite_difference_stiffness_of_the_energy(ratio, dtype):
    """k_t/k_0 = [16 φ''(s)(λ − λ⁻⁵)²/J_m + φ'(s)(4 + 20λ⁻⁶)]/24 equals d²W/dλ² of a flat patch stretched
    equibiaxially to λ(s) over its value at rest, by central differences of jax.grad of the energy
    (h = 1e-6 λ in float64, 1e-4 λ in float32); λ(s) solves 2λ² + λ⁻⁴ − 3 = s J_m. Tolerances: 1e-8 in
    float64 (round-off ~ε/h, truncation ~h²), 2e-3 in float32 (round-off); at s = 0.9 the continued energy
    meets Gent's with W of class C² only (its third derivative jumps), so there the difference is first
    order in h: 2e-5 in float64 (8.8e-6 measured), the same 2e-3 in float32 (8.4e-4)."""
    locking_jm = 97.2
    mesh = _patch(dtype)
    stretch = float(
        energies.gent_equibiaxial_stretch(jnp.asarray(ratio, dtype), jnp.asarray(locking_jm, dtype))
    )
    assert 2.0 * stretch**2 + stretch**-4 - 3.0 == pytest.approx(ratio * locking_jm, rel=tolerance(dtype))

    slope = jax.jit(
        jax.grad(
            lambda lam: energies.stretching_energy(
                _deformed(mesh, lam * jnp.eye(2, dtype=dtype)),
                mesh,
                MODULUS,
                THICKNESS,
                "gent",
                0.5,
                locking_jm,
            )
        )
    )

    def curvature(lam):
        step = (1e-6 if dtype == jnp.float64 else 1e-4) * lam
        return (
            float(slope(jnp.asarray(lam + step, dtype))) - float(slope(jnp.asarray(lam - step, dtype)))
        ) / (2.0 * step)

    volume = THICKNESS * float(jnp.sum(mesh.reference_area))
    at_rest = curvature(1.0)
    difference = (1e-8 if ratio < GENT_LOCK_FRACTION else 2e-5) if dtype == jnp.float64 else 2e-3
    assert at_rest / volume == pytest.approx(12.0 * SHEAR, rel=difference)  # k_0 = 12 μ per unit volume
    closed = float(energies.gent_tangent_ratio(jnp.asarray(ratio, dtype), jnp.asarray(locking_jm, dtype)))
    assert closed == pytest.approx(GENT_TANGENT_RATIOS[ratio], rel=1e-9 if dtype == jnp.float64 else 1e-5)
    assert curvature(stretch) / at_rest == pytest.approx(closed, rel=difference)


def _membrane_tangent(gradient, locking_jm=97.2):
    """The largest eigenvalue of ∂²W/∂F² per unit volume, F the 3 × 2 deformation gradient of a flat patch
    (out-of-plane rows included: the stress's geometric stiffness), by reverse over reverse mode."""
    mesh = _patch()
    rest = mesh.reference_position[:, :2]

    def energy(flat):
        return energies.stretching_energy(
            rest @ flat.reshape(3, 2).T, mesh, MODULUS, THICKNESS, "gent", 0.5, locking_jm
        )

    hessian = jax.jacrev(jax.grad(energy))(jnp.asarray(gradient, jnp.float64).ravel())
    return float(np.linalg.eigvalsh(np.asarray(hessian)).max())


def test_the_equibiaxial_tangent_ratio_bounds_the_elasticity_tensor_of_tension_states():
    """k_t/k_0 is the ratio of the largest eigenvalue of ∂²W/∂F² at the equibiaxial stretch λ(s) to that at
    rest (1e-9), and no plane tension state with the same s (λ₂ from λ₁^(−1/2), uniaxial, to λ₁) has a
    larger one at s = 0.7 and 0.9, where the tangent exceeds 1 (checked on eight states each). At s = 0.9
    the patch's triangles straddle f = 0.9 by round-off: the continued energy's two pieces give the same
    derivatives there (they did not when chosen by ``jnp.minimum`` and ``jnp.maximum``: 29.07, not 32.69)."""
    locking_jm = 97.2
    at_rest = _membrane_tangent(np.eye(3, 2))
    for ratio in (0.1, 0.5, 0.7, 0.9):
        stretch = float(energies.gent_equibiaxial_stretch(ratio, locking_jm))
        tangent = _membrane_tangent(np.eye(3, 2) * stretch)
        assert tangent / at_rest == pytest.approx(
            float(energies.gent_tangent_ratio(ratio, locking_jm)), rel=1e-9
        )
    for ratio in (0.7, 0.9):
        bound = float(energies.gent_tangent_ratio(ratio, locking_jm))
        equibiaxial = float(energies.gent_equibiaxial_stretch(ratio, locking_jm))
        uniaxial = math.sqrt(ratio * locking_jm + 3.0)  # λ² + 2/λ − 3 = s J_m, to 1 %: solved below
        for fraction in np.linspace(0.0, 0.95, 8):
            # λ₂ = λ₁^(−1/2 + 3f/2): f = 0 uniaxial, f = 1 equibiaxial; λ₁ solves I₁ − 3 = s J_m.
            exponent = -0.5 + 1.5 * fraction
            low, high = 1.0, max(uniaxial, equibiaxial) * 1.5
            for _ in range(200):
                middle = 0.5 * (low + high)
                excess = middle**2 + middle ** (2 * exponent) + middle ** (-2 - 2 * exponent) - 3.0
                low, high = (middle, high) if excess < ratio * locking_jm else (low, middle)
            state = np.zeros((3, 2))
            state[0, 0], state[1, 1] = low, low**exponent
            assert _membrane_tangent(state) / at_rest <= bound * (1.0 + 1e-9)


def test_the_stable_stretch_solves_the_tangent_limit_of_the_time_step():
    """r_max = (Δt_mesh/Δt)² − (Δt_mesh/Δt_contact)² (ω²_mesh k_t/k_0 + ω²_contact ≤ (2/Δt)²): with
    Δt = ½ Δt_combined, r_max = 4 + 3 (Δt_mesh/Δt_contact)², 4 without contacts; s_stable solves
    k_t(s)/k_0 = r_max on the stiffening branch (1e-9), 0.727 at r_max = 4, J_m = 97.2 (the explicit step
    with dt_safety 0.5 is stable to s ≈ 0.73), and an infinite limit gives an infinite s_stable."""
    combined = 2.0 / math.sqrt((2.0 / 3e-5) ** 2 + (2.0 / 6e-5) ** 2)
    critical = {"mesh": 3e-5, "contact": 6e-5, "combined": combined}
    limit = stability.membrane_tangent_limit(0.5 * combined, critical)
    assert limit == pytest.approx(4.0 + 3.0 * 0.25, rel=1e-12)
    assert stability.membrane_tangent_limit(1.5e-5, {"mesh": 3e-5, "contact": math.inf}) == pytest.approx(4.0)
    for tangent_limit in (4.0, limit, 40.0):
        stable = energies.stable_locking_ratio(tangent_limit, 97.2)
        assert float(energies.gent_tangent_ratio(stable, 97.2)) == pytest.approx(tangent_limit, rel=1e-9)
        assert stable > 0.3  # the stiffening branch, past the ratio's minimum (0.2 near s = 0.16)
    assert energies.stable_locking_ratio(4.0, 97.2) == pytest.approx(0.72700114, rel=1e-7)
    assert math.isinf(energies.stable_locking_ratio(math.inf, 97.2))


def _held_patch_dynamics():
    """A flat patch, its boundary held, its interior free: the dense M⁻¹K of the free nodes and a leapfrog."""
    mesh = flat_mesh(0.3, 0.2, 0.05)
    free = np.asarray(face_contact.interior_nodes(mesh))
    mass = np.asarray(energies.lumped_mass(mesh, THICKNESS, LATEX_DENSITY))
    rows = np.repeat(free, 3)
    scale = 1.0 / np.sqrt(np.repeat(mass, 3)[rows])

    def energy(position, locking_jm):
        return energies.stretching_energy(position, mesh, MODULUS, THICKNESS, "gent", 0.5, locking_jm)

    def omega_squared(position, locking_jm=97.2):
        hessian = jax.jacrev(jax.grad(lambda x: energy(x.reshape(-1, 3), locking_jm)))(position.ravel())
        block = np.asarray(hessian)[np.ix_(rows, rows)] * scale[:, None] * scale[None, :]
        return float(np.linalg.eigvalsh(block).max())

    @functools.partial(jax.jit, static_argnums=2)
    def leapfrog(position, dt, steps, locking_jm=97.2):
        inverse_mass = jnp.where(jnp.asarray(free)[:, None], 1.0 / jnp.asarray(mass)[:, None], 0.0)

        def step(_, carry):
            x, v = carry
            v = v - dt * inverse_mass * jax.grad(energy)(x, locking_jm)
            return x + dt * v, v

        return jax.lax.fori_loop(0, steps, step, (position, jnp.zeros_like(position)))[0]

    return mesh, free, omega_squared, leapfrog


def test_a_patch_stretched_past_the_stable_stretch_blows_up_and_is_flagged_and_below_it_stays_finite():
    """The rule on a small mesh: a flat Gent patch held at an equibiaxial stretch λ(s) on its boundary, its
    interior nodes free (undamped leapfrog, the lumped latex masses), Δt = ½ · 2/ω₀ (ω₀² the largest
    eigenvalue of M⁻¹K at rest, dense), so r_max = 4 and s_stable = 0.727 (J_m = 97.2).

    - ω²(s)/ω₀² ≤ k_t(s)/k_0 (the closed form bounds the mesh's own frequency, within 25 %) at s = 0.6,
      0.7, 0.85 (at s = 0.5, where both are 1.04, the mesh's is 0.13 % above: no stretch below s ≈ 0.55
      stiffens the patch beyond its rest value by more than that). The patch itself turns unstable
      between s = 0.727 and 0.75 (its ω²(s)/ω₀² is 3.46 and 4.12 there): the rule is conservative;
    - at s = s_stable − 0.05 a 1e-6 perturbation stays below 10× itself over 3000 steps and the check
      (:func:`stability.gent_bits`) is clear; at s = 0.85 (k_t/k_0 = 15) it grows past 1e3× (or to inf)
      within 300 steps, and the check sets ``MEMBRANE_STIFFENED`` (not ``MEMBRANE_LOCKED``: 0.85 < 0.9),
      whose message names the membrane and the fix."""
    mesh, free, omega_squared, leapfrog = _held_patch_dynamics()
    at_rest = omega_squared(mesh.reference_position)
    dt = 0.5 * 2.0 / math.sqrt(at_rest)
    limit = stability.membrane_tangent_limit(dt, {"mesh": 2.0 / math.sqrt(at_rest), "contact": math.inf})
    assert limit == pytest.approx(4.0, rel=1e-12)
    stable = energies.stable_locking_ratio(limit, 97.2)
    assert stable == pytest.approx(0.72700114, rel=1e-7)
    noise = 1e-6 * 0.05 * np.random.default_rng(0).standard_normal(mesh.reference_position.shape)
    noise = noise * free[:, None]

    def held(ratio):
        stretch = float(energies.gent_equibiaxial_stretch(ratio, 97.2))
        return mesh.reference_position * jnp.asarray([[stretch, stretch, 1.0]])

    for ratio in (0.6, 0.7, 0.85):  # measured 0.94, 0.88, 0.80 of the bound
        growth = omega_squared(held(ratio)) / at_rest / float(energies.gent_tangent_ratio(ratio, 97.2))
        assert 0.75 < growth <= 1.0
    below, past = held(stable - 0.05), held(0.85)
    end = leapfrog(below + noise, dt, 3000)
    assert np.max(np.abs(np.asarray(end - below))) < 10.0 * np.max(np.abs(noise))
    assert int(stability.gent_bits(below, mesh, 97.2, limit)) == 0
    end = np.asarray(leapfrog(past + noise, dt, 300))
    assert not np.all(np.isfinite(end)) or np.max(np.abs(end - np.asarray(past))) > 1e3 * np.max(
        np.abs(noise)
    )
    flagged = int(stability.gent_bits(past, mesh, 97.2, limit))
    assert flagged == ErrorCode.MEMBRANE_STIFFENED
    assert "membrane stiffened" in describe(flagged)[0] and "dt_safety" in describe(flagged)[0]


def test_the_stiffening_check_under_jit_and_vmap_over_the_lock():
    """:func:`stability.gent_bits` jitted and vmapped over J_m on one stretched patch (s = e/J_m, e its
    largest I₁ − 3) equals the loop and the rule: clear below s_stable, ``MEMBRANE_STIFFENED`` between
    s_stable and 0.9, both bits past 0.9; the threshold follows J_m (traced) through the closed form."""
    mesh = _patch()
    position = _deformed(mesh, 2.0 * jnp.eye(2))
    excess = float(jnp.max(energies._first_invariant_excess(green_strain(position, mesh))))
    limit = 4.0
    ratios = np.asarray([0.3, 0.8, 0.95])
    stable = [energies.stable_locking_ratio(limit, excess / r) for r in ratios]
    expected = [
        (ErrorCode.MEMBRANE_STIFFENED if r > s else 0) | (ErrorCode.MEMBRANE_LOCKED if r > 0.9 else 0)
        for r, s in zip(ratios, stable, strict=True)
    ]
    assert expected[0] == 0 and expected[1] == ErrorCode.MEMBRANE_STIFFENED
    batched = jax.jit(jax.vmap(lambda jm: stability.gent_bits(position, mesh, jm, limit)))(excess / ratios)
    assert [int(b) for b in batched] == [int(e) for e in expected]
    assert [int(stability.gent_bits(position, mesh, excess / r, limit)) for r in ratios] == [
        int(e) for e in expected
    ]
    assert int(stability.gent_bits(position, mesh, excess / 0.8, math.inf)) == 0  # no limit: nothing checked


def test_a_coupled_gent_membrane_past_the_stable_stretch_stops_with_the_named_error():
    """The check in the coupled step: a clamped Gent cylinder (two spheres inside that touch nothing), its
    free nodes set out radially by 1.5 (hoop stretch), J_m chosen so that the largest triangle's
    s = (I₁ − 3)/J_m is 0.3 (below s_stable) or 0.85 (above it, below the lock's 0.9), Δt = ½ Δt_crit,mesh
    (r_max = 4). vmapped over J_m (traced) the jitted step sets ``MEMBRANE_STIFFENED`` at the first check
    for 0.85 alone; through the chunk driver the 0.85 run stops with a SimulationError naming the membrane
    and the fix, the 0.3 run takes its 40 steps finite and clear."""
    radius, height = 0.1, 0.2
    mesh, spheres, particles, frame, walls = clamped_cylinder_parts(
        radius, height, 2 * np.pi * radius / 12, box=3.0
    )
    params = coupled.CoupledParams(
        dem=DEMParams(contact=ContactParams.paper(), damping=DampingParams.local(0.3)),
        membrane=coupled.MembraneParams.create(thickness=THICKNESS, cell_pressure=0.0, modulus=MODULUS),
    )
    critical = stability.membrane_critical_time_step(
        mesh, params.membrane, contacts_per_node=0, stretching_model="gent"
    )
    dt = 0.5 * critical["mesh"]
    limit = stability.membrane_tangent_limit(dt, critical)
    assert limit == pytest.approx(4.0, rel=1e-12)
    dem_init, _ = sphere_dem(particles, frame, dt)
    init_fn, step_fn = coupled.membrane_dem(
        particles, frame, mesh, dt, np.pi * radius**2, stretching_model="gent", tangent_limit=limit
    )
    state = init_fn(dem_init(spheres, walls, frame.allocate(spheres)), params, capacity=2, skin=0.01)
    free = jnp.asarray(free_node_mask(mesh))[:, None]
    stretched = jnp.where(
        free, state.membrane.position * jnp.asarray([[1.5, 1.5, 1.0]]), state.membrane.position
    )
    state = state.set(membrane=state.membrane.set(position=stretched))
    excess = float(energies.locking_ratio(stretched, mesh, 1.0))  # the largest I₁ − 3
    targets = np.asarray([0.3, 0.85])
    locking = excess / targets
    stable = [energies.stable_locking_ratio(limit, jm) for jm in locking]
    assert targets[0] < stable[0] and stable[1] < targets[1] < GENT_LOCK_FRACTION

    def with_lock(jm):
        return params.set(membrane=params.membrane.set(locking_jm=jm))

    def run(jm, steps):
        return jax.lax.fori_loop(0, steps, lambda _, s: step_fn(s, with_lock(jm)), state)

    errors = jax.jit(jax.vmap(lambda jm: run(jm, 1).error))(jnp.asarray(locking))
    assert [int(e) for e in errors] == [0, int(ErrorCode.MEMBRANE_STIFFENED)]
    runner = ChunkRunner(
        step_fn,
        frame,
        lambda s, p: s.membrane.position[0],
        particles.num_particles,
        dem_of=lambda s: s.dem,
        with_dem=lambda s, dem: s.set(dem=dem),
    )
    end, _ = runner.run(state, with_lock(jnp.asarray(locking[0])), 40, chunk_steps=20, record_every=10)
    assert int(end.error) == 0 and np.all(np.isfinite(np.asarray(end.membrane.position)))
    with pytest.raises(SimulationError, match=r"membrane stiffened.*dt_safety"):
        runner.run(state, with_lock(jnp.asarray(locking[1])), 40, chunk_steps=20, record_every=10)


def test_the_runaway_guard_names_a_gent_membranes_stable_stretch():
    """The kinetic-energy runaway message adds, for a Gent membrane test, its s_stable (0.727 at r_max = 4,
    J_m = 97.2, from the closed form) and the fix; other tests (no s_stable) get nothing added."""
    from types import SimpleNamespace

    from membrax import runner

    gent = SimpleNamespace(stable_locking_ratio=energies.stable_locking_ratio(4.0, 97.2))
    hint = runner._membrane_hint(gent)
    assert "(I1 - 3)/J_m = 0.727" in hint and "membrane_locking_jm" in hint
    assert runner._membrane_hint(SimpleNamespace()) == ""
    assert runner._membrane_hint(SimpleNamespace(stable_locking_ratio=math.inf)) == ""
