"""membrax.theory against the reference's worked values (§6, §7, §12), finite differences and transforms.

Reference: shared/reference/membrane-corrections.md. Units as there: kPa, m, kN/m.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_close, central_difference

from membrax import theory

# ------------------------------------------------------------------------------------------------------
# Worked values
# ------------------------------------------------------------------------------------------------------


def test_fcc_geometry_matches_unit_cell_count():
    # Hand calculation: the FCC conventional cell of side a = √2 D holds 4 spheres of volume π D³/6.
    diameter = 1.0
    cell_side = math.sqrt(2.0) * diameter
    solid_fraction = 4 * (math.pi * diameter**3 / 6) / cell_side**3
    assert theory.FCC_SOLID_FRACTION == pytest.approx(solid_fraction, rel=1e-14)
    assert theory.FCC_VOID_RATIO == pytest.approx(0.3505, abs=5e-5)
    assert theory.FCC_POROSITY == pytest.approx(1 - 0.74048, abs=5e-6)


# §6: FCC peak φ' against φμ. Columns: φμ, R (tan α = 2), φ' (tan α = 2), φ' (α = 63.5°).
# Two last-digit errata in the reference, corrected here from the closed form (hand check:
# φμ = 10°: R = 2 tan 55° = 2.856296, sin φ' = 1.856296/3.856296 → 28.7748°, printed 28.78;
# φμ = 30°, α = 63.5°: R = tan 63.5° tan 75° = 7.4854 → 49.8447°, printed 49.85).
ROWE_ERRATA = {(10, "exact"): (28.78, 28.77), (30, "paper"): (49.85, 49.84)}
# φμ (degrees) → (R, φ' exact, φ' paper).
ROWE_TABLE = {
    0: (2.000, 19.47, 19.55),
    5: (2.384, 24.14, 24.21),
    10: (2.856, 28.77, 28.85),
    15: (3.464, 33.50, 33.57),
    20: (4.289, 38.45, 38.52),
    25: (5.495, 43.79, 43.85),
    30: (7.464, 49.79, 49.84),
    35: (11.343, 56.93, 56.97),
}


def _printed(value, decimals):
    """Tolerance of a value printed with ``decimals`` decimals (half the last digit), at least 1e-4 rel."""
    return max(0.5 * 10.0**-decimals, 1e-4 * abs(value))


@pytest.mark.parametrize(
    ("friction_deg", "ratio", "phi_exact", "phi_paper"), [(k, *v) for k, v in ROWE_TABLE.items()]
)
def test_rowe_fcc_table(friction_deg, ratio, phi_exact, phi_paper):
    friction = math.radians(friction_deg)
    assert float(theory.rowe_stress_ratio(friction, theory.FCC)) == pytest.approx(
        ratio, abs=_printed(ratio, 3)
    )
    assert float(theory.rowe_peak_friction_angle_deg(friction_deg, theory.FCC)) == pytest.approx(
        phi_exact, abs=_printed(phi_exact, 2)
    )
    assert float(theory.rowe_peak_friction_angle_deg(friction_deg, theory.FCC_PAPER)) == pytest.approx(
        phi_paper, abs=_printed(phi_paper, 2)
    )


def test_rowe_table_errata_are_rounding_slips():
    # The printed values differ from the closed form by just over half a unit in the last digit.
    for (friction_deg, convention), (printed, corrected) in ROWE_ERRATA.items():
        packing = theory.FCC if convention == "exact" else theory.FCC_PAPER
        value = float(theory.rowe_peak_friction_angle_deg(friction_deg, packing))
        assert round(value, 2) == corrected
        assert 0.005 < abs(value - printed) < 0.006


def test_rowe_paper_value_and_both_conventions():
    # §12.6 and the paper's §5.1: 43.85° at φμ = 25° needs α = 63.5°; tan α = 2 gives 43.794°.
    assert_close(theory.rowe_stress_ratio(math.radians(25), theory.FCC), 5.4950, rtol=1e-4)
    assert_close(theory.rowe_stress_ratio(math.radians(25), theory.FCC_PAPER), 5.5106, rtol=1e-4)
    assert_close(theory.rowe_peak_friction_angle_deg(25.0, theory.FCC), 43.794, rtol=1e-4)
    assert_close(theory.rowe_peak_friction_angle_deg(25.0, theory.FCC_PAPER), 43.853, rtol=1e-4)
    assert round(float(theory.rowe_peak_friction_angle_deg(25.0, theory.FCC_PAPER)), 2) == 43.85
    assert theory.ROWE_PACKINGS["fcc"] is theory.FCC
    assert theory.ROWE_PACKINGS["fcc_paper"] is theory.FCC_PAPER


def test_rowe_other_packings_from_contact_statics():
    # §6 [D]: tan α and β of the other regular packings; with φμ = 0 the ratio is tan α tan β.
    assert_close(theory.TETRAHEDRAL.tan_alpha, 2 * math.sqrt(2), rtol=1e-12)
    assert_close(math.degrees(theory.TETRAHEDRAL.beta), 54.7356, rtol=1e-5)
    assert_close(theory.rowe_stress_ratio(0.0, theory.RODS_SQUARE), 1.0, rtol=1e-12)
    assert_close(theory.rowe_stress_ratio(0.0, theory.RODS_HEXAGONAL), 3.0, rtol=1e-12)


# §7: φ_crit = 36°, e_min = 0.71, e_max = 1.00, e = 0.78. Columns: p', I_R, Bolton, clipped, Eq. 1,
# low-pressure rule I_R = 5 I_D − 1.
BOLTON_TABLE = [
    (10, 4.8394, 50.52, 48.00, 52.52, 44.38),
    (40, 3.7877, 47.36, 47.36, 49.36, 44.38),
    (100, 3.0926, 45.28, 45.28, 47.28, 44.38),
    (200, 2.5668, 43.70, 43.70, 45.70, 43.70),
]


@pytest.mark.parametrize(("pressure", "index", "bolton", "clipped", "eq1", "low_rule"), BOLTON_TABLE)
def test_bolton_table(pressure, index, bolton, clipped, eq1, low_rule):
    density = theory.relative_density(0.78, 0.71, 1.00)
    assert_close(density, 0.758621, rtol=1e-5)
    assert_close(theory.relative_dilatancy_index(density, pressure), index, rtol=1e-4)
    assert float(theory.bolton_peak_friction_angle_deg(36.0, density, pressure)) == pytest.approx(
        bolton, abs=_printed(bolton, 2)
    )
    assert float(theory.bolton_peak_friction_angle_deg(36.0, density, pressure, clip=True)) == pytest.approx(
        clipped, abs=_printed(clipped, 2)
    )
    assert float(theory.paper_eq1_peak_friction_angle_deg(36.0, density, pressure)) == pytest.approx(
        eq1, abs=_printed(eq1, 2)
    )
    assert float(
        theory.bolton_peak_friction_angle_deg(36.0, density, pressure, low_pressure_rule=True)
    ) == pytest.approx(low_rule, abs=_printed(low_rule, 2))


def test_paper_eq1_is_bolton_plus_two_degrees():
    pressures = jnp.array([5.0, 10.0, 40.0, 100.0, 300.0])
    densities = jnp.array([0.2, 0.5, 0.758621, 0.9, 1.0])
    difference = theory.paper_eq1_peak_friction_angle_deg(36.0, densities, pressures) - (
        theory.bolton_peak_friction_angle_deg(36.0, densities, pressures)
    )
    assert_close(difference, 2.0, rtol=0, atol=1e-12)


def test_bolton_plane_strain_and_dilatancy():
    # §7: plane strain φ'max − φ'crit = 5 I_R, (−dεv/dε1)max = 0.3 I_R; §12.7: p' = 100 kPa → 45.278°.
    density = theory.relative_density(0.78, 0.71, 1.00)
    index = theory.relative_dilatancy_index(density, 100.0)
    assert_close(theory.bolton_peak_friction_angle_deg(36.0, density, 100.0), 45.278, rtol=1e-4)
    assert_close(
        theory.bolton_peak_friction_angle_deg(36.0, density, 100.0, plane_strain=True),
        36 + 5 * 3.0926,
        rtol=1e-4,
    )
    assert_close(theory.bolton_max_dilatancy_rate(index), 0.3 * 3.0926, rtol=1e-4)


def test_astm_and_henkel_gilbert_shell():
    # §12.1
    assert_close(theory.astm_shell_correction(1400.0, 0.002, 0.150, 0.05).axial_stress, 3.7333, rtol=1e-4)
    assert_close(
        theory.henkel_gilbert_shell_correction(1400.0, 0.002, 0.150, 0.05).axial_stress, 3.6388, rtol=1e-4
    )
    for (diameter, thickness), expected in {
        (0.300, 0.002): 1.8667,
        (0.038, 0.0002): 1.4737,
        (0.100, 0.0003): 0.8400,
    }.items():
        assert_close(
            theory.astm_shell_correction(1400.0, thickness, diameter, 0.05).axial_stress, expected, rtol=1e-4
        )
    # The ASTM form carries no radial increment.
    assert float(theory.astm_shell_correction(1400.0, 0.002, 0.150, 0.05).radial_stress) == 0.0


def test_henkel_gilbert_general_form_is_pi_d_m_eps_over_area():
    # §1(a): Δσa = π D M εa / A with the right-cylinder D and A; check against the area correction.
    modulus, thickness, diameter0, axial, volumetric = 1400.0, 0.002, 0.15, 0.08, -0.04
    area = theory.area_correction(math.pi * diameter0**2 / 4, axial, volumetric)
    diameter = math.sqrt(4 * float(area) / math.pi)
    expected = math.pi * diameter * modulus * thickness * axial / float(area)
    got = theory.henkel_gilbert_shell_correction(
        modulus, thickness, diameter0, axial, volumetric
    ).axial_stress
    assert_close(got, expected, rtol=1e-12)


def test_hoop_tension():
    # §12.2: D = 0.153897, ε_θ = 0.025978, Δσr = 0.9453; small-strain 0.9333.
    correction = theory.hoop_tension_correction(1400.0, 0.002, 0.150, 0.05)
    assert_close(correction.radial_stress, 0.9453, rtol=1e-4)
    assert float(correction.axial_stress) == 0.0
    assert_close(
        theory.hoop_tension_correction(1400.0, 0.002, 0.150, 0.05, small_strain=True).radial_stress,
        0.9333,
        rtol=1e-4,
    )
    # Radial contraction: a buckled hoop carries no compression.
    assert float(theory.hoop_tension_correction(1400.0, 0.002, 0.150, 0.0, 0.05).radial_stress) == 0.0


@pytest.mark.parametrize(
    ("volumetric", "axial_inc", "radial_inc"),
    [
        (0.0, 3.7333, 0.0),
        (-0.03, 2.9867, 0.7467),
        (0.02, 4.2311, -0.4978),
    ],
)
def test_right_cylinder_shell_table(volumetric, axial_inc, radial_inc):
    # §12.3: Δq = 4 E t εa / D whatever εv when ν = 0.5.
    correction = theory.right_cylinder_shell_correction(1400.0, 0.002, 0.150, 0.05, volumetric)
    assert_close(correction.axial_stress, axial_inc, rtol=1e-4)
    assert_close(correction.radial_stress, radial_inc, rtol=1e-4, atol=1e-12)
    assert_close(correction.axial_stress + correction.radial_stress, 3.7333, rtol=1e-4)
    clipped = theory.right_cylinder_shell_correction(
        1400.0, 0.002, 0.150, 0.05, volumetric, clip_hoop_compression=True
    )
    assert float(clipped.radial_stress) == pytest.approx(max(radial_inc, 0.0), abs=1e-4)


def test_right_cylinder_shell_general_poisson_ratio():
    # §3 closed form Δq = E t/(D(1−ν²)) [(4−2ν) εa + (4ν−2) εθ] for any ν.
    modulus, thickness, diameter, axial, volumetric, nu = 1400.0, 0.002, 0.15, 0.04, -0.02, 0.3
    hoop = (volumetric - axial) / 2
    expected = modulus * thickness / (diameter * (1 - nu**2)) * ((4 - 2 * nu) * axial + (4 * nu - 2) * hoop)
    correction = theory.right_cylinder_shell_correction(
        modulus, thickness, diameter, axial, volumetric, poisson_ratio=nu
    )
    assert_close(correction.axial_stress + correction.radial_stress, expected, rtol=1e-12)


def test_ballast_worked_example_apply_correction():
    # §12.4: σcell = 10, q = 65.5, εa = 0.05, εv = −0.05, D = 0.3, t = 0.002.
    correction = theory.right_cylinder_shell_correction(1400.0, 0.002, 0.300, 0.05, -0.05)
    assert_close(correction.axial_stress, 1.2444, rtol=1e-4)
    assert_close(correction.radial_stress, 0.6222, rtol=1e-4)
    sigma_1, sigma_3 = 10.0 + 65.5, 10.0
    assert_close(theory.stress_ratio(sigma_1, sigma_3), 7.55, rtol=1e-4)
    assert_close(theory.mobilised_friction_angle_deg(sigma_1, sigma_3), 50.00, rtol=1e-4)
    corrected = theory.apply_membrane_correction(sigma_1, sigma_3, correction)
    assert_close(corrected.sigma_1, 74.2556, rtol=1e-4)
    assert_close(corrected.sigma_3, 10.6222, rtol=1e-4)
    assert_close(theory.stress_ratio(*corrected), 6.9906, rtol=1e-4)
    assert round(float(theory.mobilised_friction_angle_deg(*corrected)), 2) == 48.56  # printed to 0.01°


def test_filter_paper():
    # §12.5: K = 0.19 kN/m, half the perimeter of a 38 mm specimen covered.
    args = (0.19, 0.059690, 1.134115e-3)
    assert_close(theory.filter_paper_correction(*args, 0.05).axial_stress, 10.000, rtol=1e-4)
    assert_close(theory.filter_paper_correction(*args, 0.01).axial_stress, 5.000, rtol=1e-4)


def test_area_correction_and_radial_strain():
    # §12.8
    for (axial, volumetric), ratio in {
        (0.05, 0.0): 1.05263,
        (0.05, -0.03): 1.08421,
        (0.10, -0.06): 1.17778,
    }.items():
        assert_close(theory.area_correction(1.0, axial, volumetric), ratio, rtol=1e-5)
        # Radial strain is consistent with the area: (1 − εr)² = A/A0.
        assert_close((1 - theory.radial_strain(axial, volumetric)) ** 2, ratio, rtol=1e-5)
    # Small-strain form agrees to first order: difference O(ε²).
    for axial, volumetric in [(1e-4, -2e-4), (1e-3, 5e-4)]:
        exact = float(theory.radial_strain(axial, volumetric))
        small = float(theory.radial_strain_small(axial, volumetric))
        assert abs(exact - small) < 2 * max(axial, abs(volumetric)) ** 2


def test_stress_measures_consistent():
    sigma_1, sigma_3 = 55.0, 10.0
    q = theory.deviator_stress(sigma_1, sigma_3)
    p = theory.mean_stress(sigma_1, sigma_3)
    assert float(q) == 45.0 and float(p) == 25.0
    phi = theory.mobilised_friction_angle(sigma_1, sigma_3)
    assert_close(theory.friction_angle_from_q_over_p(q / p), phi, rtol=1e-12)
    assert_close(theory.friction_angle_from_stress_ratio(sigma_1 / sigma_3), phi, rtol=1e-12)
    assert_close(theory.stress_ratio_from_friction_angle(phi), sigma_1 / sigma_3, rtol=1e-12)


def test_molenkamp_luger():
    # Hand calculation for 10 kPa, 2.5 mm, D = 25 mm, FCC e: 0.275 · 1.3505^(4/9) · 10^(1/3) · (10/1400)^(1/3)
    e = theory.FCC_VOID_RATIO
    expected = 0.275 * (1 + e) ** (4 / 9) * (25 / 2.5) ** (1 / 3) * (10 / 1400) ** (1 / 3)
    assert_close(theory.molenkamp_luger_indentation_ratio(e, 25.0, 2.5, 10.0, 1400.0), expected, rtol=1e-12)
    assert_close(expected, 0.1304, rtol=1e-3)
    # Scaling: α/D ∝ σ'^(1/3) and ∝ t^(−1/3); thickest membrane has the lowest ratio (paper §5.2, Fig. 9).
    ratio_8 = theory.molenkamp_luger_indentation_ratio(e, 25.0, 2.5, 80.0, 1400.0)
    assert_close(ratio_8 / expected, 2.0, rtol=1e-12)
    validity = theory.molenkamp_luger_validity(e, 25.0, 2.5, 100.0, 1400.0)
    assert bool(validity.thin_membrane) and bool(validity.large_deflection) and bool(validity.valid)
    assert not bool(theory.molenkamp_luger_validity(e, 25.0, 2.5, 10.0, 1400.0).valid)
    assert not bool(theory.molenkamp_luger_validity(e, 25.0, 6.0, 100.0, 1400.0).thin_membrane)


def test_baldi_nova_scaling():
    # §12.9: X = 0.5228, v_m = 0.01046 m, ε_vm = 0.139 for D = 0.3 m.
    penetration = theory.baldi_nova_penetration(0.040, 10.0, 1400.0, 0.002)
    assert_close(penetration / 0.020, 0.5228, rtol=1e-4)
    assert_close(penetration, 0.01046, rtol=1e-3)
    assert_close(theory.baldi_nova_volumetric_strain(penetration, 0.300), 0.139, rtol=3e-3)


def test_leps_log_linear():
    # One log cycle below p_a adds Δφ'.
    assert_close(theory.leps_friction_angle_deg(45.0, 7.0, 10.13), 52.0, rtol=1e-12)


def test_bulge_pressure_is_the_derivative_of_the_caps_energy_over_its_volume():
    # Hand calculation: a cap of height h over a hole of radius a, uniform stretch λ² = 1 + (h/a)², stores
    # W = (μ t π a²/2)(2λ² + λ⁻⁴ − 3) and encloses V = π h (3a² + h²)/6; p = dW/dV by central differences.
    modulus, thickness, aperture = 700.0, 1.0, 5.18  # kPa, mm, mm

    def energy(height):
        squared = 1.0 + (height / aperture) ** 2
        return modulus / 3.0 * thickness * math.pi * aperture**2 / 2.0 * (2.0 * squared + squared**-2 - 3.0)

    def volume(height):
        return math.pi * height * (3.0 * aperture**2 + height**2) / 6.0

    for height in (0.5, 2.0, 6.52, 12.0):
        step = 1e-5
        expected = (energy(height + step) - energy(height - step)) / (
            volume(height + step) - volume(height - step)
        )
        got = float(theory.membrane_bulge_pressure(modulus, thickness, aperture, height))
        assert got == pytest.approx(expected, rel=1e-7), height
    # Shallow bulge: p → 12 μ t h³/a⁴.
    shallow = 1e-3 * aperture
    assert float(theory.membrane_bulge_pressure(modulus, thickness, aperture, shallow)) == pytest.approx(
        12.0 * modulus / 3.0 * thickness * shallow**3 / aperture**4, rel=1e-5
    )


def test_limit_pressure_is_the_bulge_curves_maximum():
    heights = np.linspace(0.01, 4.0, 40001)
    curve = np.asarray(theory.membrane_bulge_pressure(3.0, 1.0, 1.0, jnp.asarray(heights)))
    assert float(theory.membrane_limit_pressure(3.0, 1.0, 1.0)) == pytest.approx(curve.max(), rel=1e-8)
    assert theory.BULGE_LIMIT_HEIGHT_RATIO == pytest.approx(heights[curve.argmax()], abs=2e-4)
    # The corners of the calibration grid over 25 mm spheres' square windows, a = (√2 − 1) 12.5 mm.
    window = theory.SQUARE_WINDOW_RATIO * 12.5
    assert window == pytest.approx(math.hypot(12.5, 12.5) - 12.5, rel=1e-14)
    assert float(theory.membrane_limit_pressure(700.0, 1.0, window)) == pytest.approx(82.71, abs=0.01)
    assert float(theory.membrane_limit_pressure(1400.0, 1.0, window)) == pytest.approx(165.42, abs=0.01)


# ------------------------------------------------------------------------------------------------------
# Gradients, vmap, jit, dtype
# ------------------------------------------------------------------------------------------------------

# (name, scalar function of floats, a point inside the valid domain)
SMOOTH_FUNCTIONS = [
    ("stress_ratio", theory.stress_ratio, (55.0, 10.0)),
    ("mean_stress", theory.mean_stress, (55.0, 10.0)),
    ("mobilised_friction_angle", theory.mobilised_friction_angle, (55.0, 10.0)),
    ("friction_angle_from_stress_ratio", theory.friction_angle_from_stress_ratio, (4.0,)),
    ("stress_ratio_from_friction_angle", theory.stress_ratio_from_friction_angle, (0.7,)),
    ("friction_angle_from_q_over_p", theory.friction_angle_from_q_over_p, (1.2,)),
    ("area_correction", theory.area_correction, (0.05, 0.07, -0.03)),
    ("radial_strain", theory.radial_strain, (0.07, -0.03)),
    ("rowe_stress_ratio", lambda f: theory.rowe_stress_ratio(f, theory.FCC), (0.44,)),
    (
        "rowe_peak_friction_angle_deg",
        lambda f: theory.rowe_peak_friction_angle_deg(f, theory.FCC_PAPER),
        (25.0,),
    ),
    ("relative_density", theory.relative_density, (0.78, 0.71, 1.0)),
    ("bolton_peak_friction_angle_deg", theory.bolton_peak_friction_angle_deg, (36.0, 0.6, 40.0)),
    ("paper_eq1_peak_friction_angle_deg", theory.paper_eq1_peak_friction_angle_deg, (36.0, 0.6, 40.0)),
    ("leps_friction_angle_deg", theory.leps_friction_angle_deg, (50.0, 7.0, 30.0)),
    (
        "molenkamp_luger_indentation_ratio",
        theory.molenkamp_luger_indentation_ratio,
        (0.35, 25.0, 3.3, 40.0, 1400.0),
    ),
    ("baldi_nova_penetration", theory.baldi_nova_penetration, (0.04, 10.0, 1400.0, 0.002)),
    ("astm_shell", lambda *a: theory.astm_shell_correction(*a).axial_stress, (1400.0, 0.002, 0.15, 0.05)),
    (
        "henkel_gilbert_shell",
        lambda *a: theory.henkel_gilbert_shell_correction(*a).axial_stress,
        (1400.0, 0.002, 0.15, 0.05, -0.02),
    ),
    (
        "hoop_tension",
        lambda *a: theory.hoop_tension_correction(*a).radial_stress,
        (1400.0, 0.002, 0.15, 0.05, -0.02),
    ),
    (
        "right_cylinder_axial",
        lambda *a: theory.right_cylinder_shell_correction(*a).axial_stress,
        (1400.0, 0.002, 0.15, 0.05, -0.02),
    ),
    (
        "right_cylinder_radial_exact",
        lambda *a: theory.right_cylinder_shell_correction(*a, small_strain=False).radial_stress,
        (1400.0, 0.002, 0.15, 0.05, -0.02),
    ),
    ("filter_paper", lambda *a: theory.filter_paper_correction(*a).axial_stress, (0.19, 0.06, 1.1e-3, 0.01)),
    ("membrane_bulge_pressure", theory.membrane_bulge_pressure, (700.0, 1.0, 5.18, 4.0)),
    ("membrane_limit_pressure", theory.membrane_limit_pressure, (700.0, 1.0, 5.18)),
]


@pytest.mark.parametrize(
    ("name", "function", "point"), SMOOTH_FUNCTIONS, ids=[f[0] for f in SMOOTH_FUNCTIONS]
)
def test_gradient_matches_central_differences(name, function, point):
    gradient = jax.grad(function, argnums=tuple(range(len(point))))(*point)
    for index, partial in enumerate(gradient):
        expected = central_difference(function, point, index)
        np.testing.assert_allclose(
            float(partial), expected, rtol=1e-6, atol=1e-9, err_msg=f"{name}: d/d arg {index}"
        )


@pytest.mark.parametrize(
    ("name", "function", "point"), SMOOTH_FUNCTIONS, ids=[f[0] for f in SMOOTH_FUNCTIONS]
)
def test_vmap_and_jit_equal_python_loop(name, function, point):
    # Perturb every argument over a batch of 5, staying inside the valid domain.
    scales = np.linspace(0.9, 1.1, 5)
    batch = [jnp.asarray(p * scales) for p in point]
    looped = np.array([float(function(*[float(b[i]) for b in batch])) for i in range(5)])
    np.testing.assert_allclose(np.asarray(jax.vmap(function)(*batch)), looped, rtol=1e-13, err_msg=name)
    np.testing.assert_allclose(
        np.asarray(jax.jit(jax.vmap(function))(*batch)), looped, rtol=1e-13, err_msg=name
    )
    # Broadcasting over arrays gives the same as vmap.
    np.testing.assert_allclose(np.asarray(function(*batch)), looped, rtol=1e-13, err_msg=name)


@pytest.mark.parametrize(
    ("name", "function", "point"), SMOOTH_FUNCTIONS, ids=[f[0] for f in SMOOTH_FUNCTIONS]
)
@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_dtype_preserved(name, function, point, dtype):
    args = [jnp.asarray(p, dtype=dtype) for p in point]
    assert function(*args).dtype == dtype, name


# ------------------------------------------------------------------------------------------------------
# Bad inputs
# ------------------------------------------------------------------------------------------------------

BAD_INPUTS = [
    (lambda: theory.astm_shell_correction(-1400.0, 0.002, 0.15, 0.05), "membrane_modulus"),
    (lambda: theory.astm_shell_correction(1400.0, 0.0, 0.15, 0.05), "membrane_thickness"),
    (lambda: theory.astm_shell_correction(1400.0, 0.002, -0.15, 0.05), "specimen_diameter"),
    (lambda: theory.astm_shell_correction(1400.0, 0.002, 0.15, 1.0), "axial_strain"),
    (lambda: theory.astm_shell_correction(1400.0, float("nan"), 0.15, 0.05), "membrane_thickness"),
    (lambda: theory.henkel_gilbert_shell_correction(1400.0, 0.002, 0.15, 0.05, 1.2), "volumetric_strain"),
    (
        lambda: theory.right_cylinder_shell_correction(1400.0, 0.002, 0.15, 0.05, 0.0, poisson_ratio=0.7),
        "poisson_ratio",
    ),
    (lambda: theory.hoop_tension_correction(1400.0, 0.002, 0.0, 0.05), "initial_diameter"),
    (lambda: theory.area_correction(1.0, jnp.array([0.1, 1.5]), 0.0), "axial_strain"),
    (lambda: theory.radial_strain(float("nan"), 0.0), "axial_strain"),
    (lambda: theory.mobilised_friction_angle(10.0, -1.0), "sigma_3"),
    (lambda: theory.molenkamp_luger_indentation_ratio(0.35, 25.0, 2.5, 10.0, 0.0), "membrane_modulus"),
    (lambda: theory.molenkamp_luger_indentation_ratio(0.35, -25.0, 2.5, 10.0, 1400.0), "grain_diameter"),
    (lambda: theory.relative_density(0.78, 1.0, 0.71), "void_ratio_max - void_ratio_min"),
    (lambda: theory.bolton_peak_friction_angle_deg(36.0, 0.7, 0.0), "mean_effective_stress_kpa"),
    (lambda: theory.bolton_peak_friction_angle_deg(36.0, 1.7, 50.0), "relative_density"),
    (lambda: theory.rowe_peak_friction_angle_deg(95.0), "interparticle_friction_angle_deg"),
    (lambda: theory.rowe_stress_ratio(1.0), "interparticle_friction_angle"),
    (lambda: theory.membrane_limit_pressure(700.0, 1.0, 0.0), "aperture_radius"),
    (lambda: theory.membrane_bulge_pressure(700.0, 1.0, 5.0, -1.0), "bulge_height"),
]


@pytest.mark.parametrize(
    ("call", "argument"), BAD_INPUTS, ids=[b[1] + str(i) for i, b in enumerate(BAD_INPUTS)]
)
def test_bad_input_raises_naming_argument_and_range(call, argument):
    with pytest.raises(ValueError, match="range") as error:
        call()
    assert str(error.value).startswith(argument + " ")


def test_no_checks_inside_jit():
    # Documented: traced values are not checked; a negative thickness passes through jit as arithmetic.
    value = jax.jit(lambda t: theory.astm_shell_correction(1400.0, t, 0.15, 0.05).axial_stress)(-0.002)
    assert_close(value, -3.7333, rtol=1e-4)
