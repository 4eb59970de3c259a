"""Closed-form theory: stress measures, stress–dilatancy and classical membrane corrections.

Contract: every function here is pure ``jax.numpy``; it works under ``jax.jit``, ``jax.vmap`` and
``jax.grad``, broadcasts over array arguments, and returns the dtype it was given (float64 in, float64 out).
Each physical law's docstring gives its equation and source; the tags [C] confirmed, [D] derived, [U]
unconfirmed are those of ``shared/reference/membrane-corrections.md`` (cited below as "the reference").

Units. Formulas that are homogeneous in stress (membrane corrections, stress ratios, Molenkamp & Luger)
take any consistent units, SI (Pa, m) recommended: a modulus in Pa gives a stress increment in Pa, in kPa
gives kPa. Only Bolton's relation is not homogeneous (``ln p'`` with p' in kPa), so its argument is named
``mean_effective_stress_kpa``. Angles are radians, except in functions and arguments ending ``_deg``.

Signs. Compression is positive for stresses and strains (geotechnical convention): a contracting specimen
has ``volumetric_strain > 0`` and a bulging one has a negative radial strain.

Checks. Called eagerly with concrete numbers, each function raises ``ValueError`` naming the argument and
its accepted range for NaN, non-positive moduli, thicknesses or diameters, strains >= 1, and the like.
Inside ``jit``/``vmap``/``grad`` the inputs are tracers and nothing is checked (see
:mod:`membrax.validation`): validate before tracing.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from membrax.validation import as_float, check_range

__all__ = [
    "FCC",
    "FCC_PAPER",
    "FCC_POROSITY",
    "FCC_SOLID_FRACTION",
    "FCC_VOID_RATIO",
    "RODS_HEXAGONAL",
    "RODS_SQUARE",
    "ROWE_PACKINGS",
    "TETRAHEDRAL",
    "CorrectedStresses",
    "MembraneCorrection",
    "BULGE_LIMIT_COEFFICIENT",
    "BULGE_LIMIT_HEIGHT_RATIO",
    "MolenkampLugerValidity",
    "RowePacking",
    "SQUARE_WINDOW_RATIO",
    "apply_membrane_correction",
    "area_correction",
    "astm_shell_correction",
    "baldi_nova_penetration",
    "baldi_nova_volumetric_strain",
    "bolton_max_dilatancy_rate",
    "bolton_peak_friction_angle_deg",
    "deviator_stress",
    "filter_paper_correction",
    "friction_angle_from_q_over_p",
    "friction_angle_from_stress_ratio",
    "henkel_gilbert_shell_correction",
    "hoop_tension_correction",
    "leps_friction_angle_deg",
    "mean_stress",
    "mobilised_friction_angle",
    "mobilised_friction_angle_deg",
    "molenkamp_luger_indentation_ratio",
    "membrane_bulge_pressure",
    "membrane_limit_pressure",
    "molenkamp_luger_validity",
    "paper_eq1_peak_friction_angle_deg",
    "radial_strain",
    "radial_strain_small",
    "relative_density",
    "relative_dilatancy_index",
    "right_cylinder_shell_correction",
    "rowe_peak_friction_angle",
    "rowe_peak_friction_angle_deg",
    "rowe_stress_ratio",
    "stress_ratio",
    "stress_ratio_from_friction_angle",
    "strain_rate_from_inertial_number",
]


_POSITIVE = {"lower": 0.0, "lower_open": True}
_STRAIN = {"upper": 1.0, "upper_open": True}
_STRAIN_HINT = "Strains are fractions (0.05 for 5 %), compression positive, and must stay below 1."
_ANGLE_DEG = {"lower": 0.0, "upper": 90.0, "upper_open": True}


# ---------------------------------------------------------------------------------------------------------
# FCC geometry
# ---------------------------------------------------------------------------------------------------------

#: Solid fraction of face-centred cubic packing of equal spheres, π/(3√2) = 0.74048 (Kepler density).
FCC_SOLID_FRACTION = math.pi / (3.0 * math.sqrt(2.0))
#: Porosity of FCC packing, 1 − π/(3√2) = 0.25952.
FCC_POROSITY = 1.0 - FCC_SOLID_FRACTION
#: Void ratio of FCC packing, n/(1 − n) = 0.35047.
FCC_VOID_RATIO = FCC_POROSITY / FCC_SOLID_FRACTION


# ---------------------------------------------------------------------------------------------------------
# Stress and strain measures (reference §9)
# ---------------------------------------------------------------------------------------------------------


def stress_ratio(sigma_1, sigma_3):
    """Principal stress ratio R = σ1/σ3 (dimensionless).

    Args:
      sigma_1: major principal (axial) effective stress, any stress unit (Pa, kPa).
      sigma_3: minor principal (radial) effective stress in the same unit, > 0.
    """
    check_range("sigma_3", sigma_3, **_POSITIVE)
    return as_float(sigma_1) / as_float(sigma_3)


def mean_stress(sigma_1, sigma_3):
    """Mean stress p = (σ1 + 2σ3)/3 for axisymmetric (triaxial) conditions, in the unit of σ1 and σ3."""
    return (as_float(sigma_1) + 2.0 * as_float(sigma_3)) / 3.0


def deviator_stress(sigma_1, sigma_3):
    """Deviator stress q = σ1 − σ3, in the unit of σ1 and σ3."""
    return as_float(sigma_1) - as_float(sigma_3)


def mobilised_friction_angle(sigma_1, sigma_3):
    """Mobilised friction angle φ' (radians) from the Mohr–Coulomb circle.

    sin φ' = (σ1 − σ3)/(σ1 + σ3)   [C, standard; reference §9]

    Args:
      sigma_1: major principal effective stress, > 0, any stress unit (Pa or kPa).
      sigma_3: minor principal effective stress, > 0, the same unit as ``sigma_1``.

    Returns:
      φ', radians (dimensionless ratio of the two stresses).
    """
    check_range("sigma_1", sigma_1, **_POSITIVE)
    check_range("sigma_3", sigma_3, **_POSITIVE)
    sigma_1 = as_float(sigma_1)
    sigma_3 = as_float(sigma_3)
    return jnp.arcsin((sigma_1 - sigma_3) / (sigma_1 + sigma_3))


def mobilised_friction_angle_deg(sigma_1, sigma_3):
    """:func:`mobilised_friction_angle` in degrees."""
    return jnp.rad2deg(mobilised_friction_angle(sigma_1, sigma_3))


def friction_angle_from_stress_ratio(ratio):
    """Friction angle (radians) from R = σ1/σ3: sin φ' = (R − 1)/(R + 1)   [C, reference §6]."""
    check_range("ratio", ratio, **_POSITIVE)
    ratio = as_float(ratio)
    return jnp.arcsin((ratio - 1.0) / (ratio + 1.0))


def stress_ratio_from_friction_angle(friction_angle):
    """Inverse of :func:`friction_angle_from_stress_ratio`: R = (1 + sin φ')/(1 − sin φ').

    Args:
      friction_angle: φ', radians, in [−π/2, π/2).

    Returns:
      R = σ1/σ3, dimensionless.
    """
    check_range("friction_angle", friction_angle, lower=-math.pi / 2, upper=math.pi / 2, upper_open=True)
    sine = jnp.sin(as_float(friction_angle))
    return (1.0 + sine) / (1.0 - sine)


def friction_angle_from_q_over_p(q_over_p):
    """Friction angle (radians) in triaxial compression from M = q/p: sin φ' = 3M/(6 + M)  [C, §9]."""
    check_range("q_over_p", q_over_p, lower=0.0, upper=3.0, upper_open=True)
    q_over_p = as_float(q_over_p)
    return jnp.arcsin(3.0 * q_over_p / (6.0 + q_over_p))


def strain_rate_from_inertial_number(inertial_number, particle_diameter, density, confining_stress):
    """Axial strain rate ε̇ = I / (d √(ρ/σ)) for an inertial number I, 1/s.

    The inertial number I = ε̇ d √(ρ/σ) compares the time a grain takes to rearrange under the confining
    stress σ with the loading time 1/ε̇ (GDR MiDi 2004, "On dense granular flows", Eur. Phys. J. E 14);
    I ≲ 1e-3 is quasi-static. Traceable: σ may be a JAX value (a rollout differentiated with respect to
    σc, :mod:`membrax.gradients`).

    Args:
      inertial_number: I, dimensionless.
      particle_diameter: d, m.
      density: ρ of the grains, kg/m³.
      confining_stress: σ, Pa.
    """
    sqrt = jnp.sqrt if isinstance(confining_stress, jax.Array) else math.sqrt
    return inertial_number / (particle_diameter * sqrt(density / confining_stress))


def area_correction(initial_area, axial_strain, volumetric_strain=0.0):
    """Right-cylinder area correction A = A0 (1 − εv)/(1 − εa)   [C, reference §9].

    Args:
      initial_area: A0, > 0 (any area unit; the result has the same unit).
      axial_strain: εa, compression positive, < 1.
      volumetric_strain: εv, contraction positive, < 1. Zero gives the undrained A0/(1 − εa).
    """
    check_range("initial_area", initial_area, **_POSITIVE)
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **_STRAIN, hint=_STRAIN_HINT)
    return as_float(initial_area) * (1.0 - as_float(volumetric_strain)) / (1.0 - as_float(axial_strain))


def radial_strain(axial_strain, volumetric_strain):
    """Exact right-cylinder radial strain εr = 1 − √((1 − εv)/(1 − εa))   [D, reference §9].

    Derivation: V = π r² H, so (r/r0)² = (V/V0)/(H/H0) = (1 − εv)/(1 − εa). Compression positive, so a
    bulging specimen has εr < 0.
    """
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **_STRAIN, hint=_STRAIN_HINT)
    return 1.0 - jnp.sqrt((1.0 - as_float(volumetric_strain)) / (1.0 - as_float(axial_strain)))


def radial_strain_small(axial_strain, volumetric_strain):
    """Small-strain radial strain εr ≈ (εv − εa)/2, from εv = εa + 2εr   [D, reference §9]."""
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **_STRAIN, hint=_STRAIN_HINT)
    return 0.5 * (as_float(volumetric_strain) - as_float(axial_strain))


# ---------------------------------------------------------------------------------------------------------
# Rowe (1962) stress–dilatancy for regular packings (reference §6)
# ---------------------------------------------------------------------------------------------------------


class RowePacking(NamedTuple):
    """Geometry of a regular packing in Rowe's relation R = tan α · tan(φμ + β).

    Attributes:
      tan_alpha: the geometric factor tan α (dimensionless).
      beta: angle between the sliding direction and σ1, radians.
    """

    tan_alpha: float
    beta: float


#: FCC with the cube axis along σ1 ([100], square-pyramid contacts): tan α = 2 exactly, β = 45°  [D].
FCC = RowePacking(tan_alpha=2.0, beta=math.pi / 4)
#: FCC with the paper's rounded α = 63.5° (β = 45°): gives the paper's 43.85° at φμ = 25°.
FCC_PAPER = RowePacking(tan_alpha=math.tan(math.radians(63.5)), beta=math.pi / 4)
#: Close-packed tetrahedral along [111]: tan α = 2√2, β = 54.74° = 90° − 35.26°  [D].
TETRAHEDRAL = RowePacking(tan_alpha=2.0 * math.sqrt(2.0), beta=math.pi / 2 - math.atan(1 / math.sqrt(2)))
#: Rods in square (diamond) array: tan α = 1, β = 45°  [D].
RODS_SQUARE = RowePacking(tan_alpha=1.0, beta=math.pi / 4)
#: Rods in hexagonal array: tan α = √3, β = 60°  [D].
RODS_HEXAGONAL = RowePacking(tan_alpha=math.sqrt(3.0), beta=math.pi / 3)
#: The packings above by name.
ROWE_PACKINGS = {
    "fcc": FCC,
    "fcc_paper": FCC_PAPER,
    "tetrahedral": TETRAHEDRAL,
    "rods_square": RODS_SQUARE,
    "rods_hexagonal": RODS_HEXAGONAL,
}


def rowe_stress_ratio(interparticle_friction_angle, packing: RowePacking = FCC):
    """Rowe's peak principal stress ratio for a regular packing of rigid particles.

    R = σ'1/σ'3 = tan α · tan(φμ + β)   [C: Rowe (1962) Proc. R. Soc. A 269, 500–527; the paper's Eq. 3]

    Args:
      interparticle_friction_angle: φμ in radians, in [0, π/2 − β).
      packing: (tan α, β) of the packing; :data:`FCC` (tan α = 2, exact) by default, :data:`FCC_PAPER`
        for the paper's α = 63.5°.
    """
    check_range(
        "interparticle_friction_angle",
        interparticle_friction_angle,
        lower=0.0,
        upper=math.pi / 2 - packing.beta,
        upper_open=True,
        hint="Radians; use rowe_peak_friction_angle_deg for degrees.",
    )
    return packing.tan_alpha * jnp.tan(as_float(interparticle_friction_angle) + packing.beta)


def rowe_peak_friction_angle(interparticle_friction_angle, packing: RowePacking = FCC):
    """Peak friction angle (radians) from Rowe: sin φ' = (R − 1)/(R + 1), R from :func:`rowe_stress_ratio`.

    FCC, φμ = 25°: 43.794° with tan α = 2, 43.853° with the paper's α = 63.5° (reference §6, §12.6).
    """
    ratio = rowe_stress_ratio(interparticle_friction_angle, packing)
    return jnp.arcsin((ratio - 1.0) / (ratio + 1.0))


def rowe_peak_friction_angle_deg(interparticle_friction_angle_deg, packing: RowePacking = FCC):
    """:func:`rowe_peak_friction_angle` with φμ and the result in degrees."""
    check_range("interparticle_friction_angle_deg", interparticle_friction_angle_deg, **_ANGLE_DEG)
    friction = jnp.deg2rad(as_float(interparticle_friction_angle_deg))
    return jnp.rad2deg(rowe_peak_friction_angle(friction, packing))


# ---------------------------------------------------------------------------------------------------------
# Bolton (1986) and the paper's Eq. 1 (reference §7)
# ---------------------------------------------------------------------------------------------------------


def relative_density(void_ratio, void_ratio_min, void_ratio_max):
    """Relative density I_D = (e_max − e)/(e_max − e_min), a fraction   [C, Bolton (1986)].

    Args:
      void_ratio: e, > 0.
      void_ratio_min: e_min, > 0.
      void_ratio_max: e_max, > e_min.
    """
    check_range("void_ratio", void_ratio, **_POSITIVE)
    check_range("void_ratio_min", void_ratio_min, **_POSITIVE)
    check_range("void_ratio_max", void_ratio_max, **_POSITIVE)
    e_min = as_float(void_ratio_min)
    e_max = as_float(void_ratio_max)
    check_range(
        "void_ratio_max - void_ratio_min", e_max - e_min, **_POSITIVE, hint="e_max must exceed e_min."
    )
    return (e_max - as_float(void_ratio)) / (e_max - e_min)


def relative_dilatancy_index(
    relative_density,
    mean_effective_stress_kpa,
    *,
    q_constant: float = 10.0,
    r_constant: float = 1.0,
    clip: bool = False,
    low_pressure_rule: bool = False,
):
    """Bolton's relative dilatancy index I_R = I_D (Q − ln p') − R   [C, Bolton (1986) Géotechnique 36(1)].

    Args:
      relative_density: I_D as a fraction (see :func:`relative_density`), in [0, 1].
      mean_effective_stress_kpa: p' in kPa (the relation is not homogeneous in stress), > 0.
      q_constant: Q, 10 for quartz and feldspar.
      r_constant: R, 1.
      clip: clip I_R to Bolton's stated validity [0, 4].
      low_pressure_rule: below p' = 150 kPa use I_R = 5 I_D − R, the advice given after publication
        (Q − ln p' is replaced by 5 ≈ 10 − ln 150; reference §7, [C] as groundhog's note). Matters for
        ballast at 10–40 kPa.
    """
    check_range("relative_density", relative_density, lower=0.0, upper=1.0)
    check_range("mean_effective_stress_kpa", mean_effective_stress_kpa, **_POSITIVE)
    pressure = as_float(mean_effective_stress_kpa)
    log_term = q_constant - jnp.log(pressure)
    if low_pressure_rule:
        log_term = jnp.where(pressure < 150.0, 5.0, log_term)
    index = as_float(relative_density) * log_term - r_constant
    return jnp.clip(index, 0.0, 4.0) if clip else index


def bolton_peak_friction_angle_deg(
    critical_friction_angle_deg,
    relative_density,
    mean_effective_stress_kpa,
    *,
    plane_strain: bool = False,
    clip: bool = False,
    low_pressure_rule: bool = False,
):
    """Bolton's peak friction angle (degrees).

    triaxial:     φ'_peak = φ'_crit + 3 I_R;   plane strain: φ'_peak = φ'_crit + 5 I_R
    [C, Bolton (1986); reference §7]. I_R from :func:`relative_dilatancy_index` (same options).

    Args:
      critical_friction_angle_deg: φ'_crit, degrees.
      relative_density: I_D, dimensionless, 0–1.
      mean_effective_stress_kpa: p', kPa.
      plane_strain: 5 I_R instead of 3 I_R.
      clip: as :func:`relative_dilatancy_index`.
      low_pressure_rule: as :func:`relative_dilatancy_index`.
    """
    check_range("critical_friction_angle_deg", critical_friction_angle_deg, **_ANGLE_DEG)
    index = relative_dilatancy_index(
        relative_density, mean_effective_stress_kpa, clip=clip, low_pressure_rule=low_pressure_rule
    )
    return as_float(critical_friction_angle_deg) + (5.0 if plane_strain else 3.0) * index


def bolton_max_dilatancy_rate(relative_dilatancy_index_value):
    """Bolton's maximum dilatancy rate in triaxial compression, (−dεv/dε1)_max = 0.3 I_R   [C, §7]."""
    return 0.3 * as_float(relative_dilatancy_index_value)


def paper_eq1_peak_friction_angle_deg(
    critical_friction_angle_deg, relative_density, mean_effective_stress_kpa
):
    """The paper's Eq. 1: φ'_peak = 3 I_D (10 − ln p') − 1 + φ'_crit (degrees, p' in kPa).

    This is *not* Bolton's triaxial form φ'_crit + 3[I_D (10 − ln p') − 1]: it subtracts 1 instead of 3,
    so it is exactly 2° above :func:`bolton_peak_friction_angle_deg` (unclipped), and it has no I_R cap
    (reference §7).
    """
    check_range("critical_friction_angle_deg", critical_friction_angle_deg, **_ANGLE_DEG)
    check_range("relative_density", relative_density, lower=0.0, upper=1.0)
    check_range("mean_effective_stress_kpa", mean_effective_stress_kpa, **_POSITIVE)
    pressure = as_float(mean_effective_stress_kpa)
    return (
        3.0 * as_float(relative_density) * (10.0 - jnp.log(pressure))
        - 1.0
        + as_float(critical_friction_angle_deg)
    )


def leps_friction_angle_deg(
    reference_friction_angle_deg,
    friction_angle_drop_per_log_cycle_deg,
    confining_stress_kpa,
    atmospheric_pressure_kpa: float = 101.3,
):
    """Log-linear rockfill trend φ' = φ'_0 − Δφ' log10(σ'3/p_a) (degrees)   [U, reference §8].

    Leps (1970) gave a chart; this fitted form is usually attributed to Duncan et al. (1980). Treat
    φ'_0 and Δφ' as fit parameters.

    Args:
      reference_friction_angle_deg: φ'_0 at σ'3 = p_a, degrees.
      friction_angle_drop_per_log_cycle_deg: Δφ', degrees per tenfold σ'3.
      confining_stress_kpa: σ'3, kPa, > 0.
      atmospheric_pressure_kpa: p_a, kPa.
    """
    check_range("confining_stress_kpa", confining_stress_kpa, **_POSITIVE)
    return as_float(reference_friction_angle_deg) - as_float(
        friction_angle_drop_per_log_cycle_deg
    ) * jnp.log10(as_float(confining_stress_kpa) / atmospheric_pressure_kpa)


# ---------------------------------------------------------------------------------------------------------
# Membrane penetration (reference §5)
# ---------------------------------------------------------------------------------------------------------


class MolenkampLugerValidity(NamedTuple):
    """Whether inputs sit in Molenkamp & Luger's stated range (boolean arrays).

    Attributes:
      thin_membrane: t_m/D < 0.2.
      large_deflection: α/D > 0.2.
      valid: both.
    """

    thin_membrane: jnp.ndarray
    large_deflection: jnp.ndarray
    valid: jnp.ndarray


def molenkamp_luger_indentation_ratio(
    void_ratio,
    grain_diameter,
    membrane_thickness,
    effective_stress,
    membrane_modulus,
    constant: float = 0.275,
):
    """Indentation ratio of a membrane into the voids of equal spheres on a triangular grid.

    α/D = C (1 + e)^(4/9) (D/t_m)^(1/3) (σ'/E_m)^(1/3)
    [the paper's Eq. 2, attributed to Molenkamp & Luger (1981) Géotechnique 31(4); constants U, reference §5]

    Valid for t_m/D < 0.2 and α/D > 0.2 (see :func:`molenkamp_luger_validity`); C is 0.15–0.4, and the
    paper uses the mean 0.275.

    Args:
      void_ratio: e (FCC: :data:`FCC_VOID_RATIO`), > 0.
      grain_diameter: D, > 0 (same length unit as ``membrane_thickness``).
      membrane_thickness: t_m, > 0.
      effective_stress: σ' (cell pressure), >= 0, same unit as ``membrane_modulus``.
      membrane_modulus: E_m, > 0.
      constant: C.
    """
    check_range("void_ratio", void_ratio, **_POSITIVE)
    check_range("grain_diameter", grain_diameter, **_POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **_POSITIVE)
    check_range("effective_stress", effective_stress, lower=0.0)
    check_range("membrane_modulus", membrane_modulus, **_POSITIVE)
    check_range("constant", constant, **_POSITIVE, hint="Molenkamp & Luger give 0.15–0.4.")
    return (
        constant
        * (1.0 + as_float(void_ratio)) ** (4.0 / 9.0)
        * jnp.cbrt(as_float(grain_diameter) / as_float(membrane_thickness))
        * jnp.cbrt(as_float(effective_stress) / as_float(membrane_modulus))
    )


def molenkamp_luger_validity(
    void_ratio, grain_diameter, membrane_thickness, effective_stress, membrane_modulus, constant=0.275
) -> MolenkampLugerValidity:
    """Test the stated validity range of :func:`molenkamp_luger_indentation_ratio` (same arguments)."""
    ratio = molenkamp_luger_indentation_ratio(
        void_ratio, grain_diameter, membrane_thickness, effective_stress, membrane_modulus, constant
    )
    thin = as_float(membrane_thickness) / as_float(grain_diameter) < 0.2
    large = ratio > 0.2
    return MolenkampLugerValidity(thin_membrane=thin, large_deflection=large, valid=thin & large)


def baldi_nova_penetration(grain_diameter, effective_stress, membrane_modulus, membrane_thickness):
    """Membrane penetration volume per unit membrane area (a length), Baldi & Nova (1984) scaling.

    v_m = (d_g/2) (σ'3 d_g/(E_m t_m))^(1/3)   [form C via abstract; constant U; reference §5]

    Not valid for ballast (d_g/D ≈ 0.13 gives unrealistic strains, reference §12.9): use for scaling only.

    Args:
      grain_diameter: d_g, m (any length unit; the result is in it).
      effective_stress: σ'3, Pa (any stress unit, the same as ``membrane_modulus``), ≥ 0.
      membrane_modulus: E_m, Pa (the unit of ``effective_stress``), > 0.
      membrane_thickness: t_m, in the length unit of ``grain_diameter``, > 0.

    Returns:
      v_m, volume per membrane area, in the length unit of ``grain_diameter``.
    """
    check_range("grain_diameter", grain_diameter, **_POSITIVE)
    check_range("effective_stress", effective_stress, lower=0.0)
    check_range("membrane_modulus", membrane_modulus, **_POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **_POSITIVE)
    grain = as_float(grain_diameter)
    group = as_float(effective_stress) * grain / (as_float(membrane_modulus) * as_float(membrane_thickness))
    return 0.5 * grain * jnp.cbrt(group)


def baldi_nova_volumetric_strain(penetration, specimen_diameter):
    """Apparent volumetric strain from penetration on a cylinder's lateral surface.

    ε_vm = 4 v_m / D   [D, reference §5]

    Args:
      penetration: v_m from :func:`baldi_nova_penetration` (a length).
      specimen_diameter: D, > 0, same length unit.
    """
    check_range("specimen_diameter", specimen_diameter, **_POSITIVE)
    return 4.0 * as_float(penetration) / as_float(specimen_diameter)


# ---------------------------------------------------------------------------------------------------------
# Membrane inflation into a surface void: the neo-Hookean limit point
# ---------------------------------------------------------------------------------------------------------

#: a/R of the window between four touching equal spheres on a square grid (an FCC {100} face), measured in
#: the plane of their centres: a = (√2 − 1) R, the narrowest opening a membrane bulging into that surface
#: void must pass to reach the spheres behind it.
SQUARE_WINDOW_RATIO = math.sqrt(2.0) - 1.0


def _bulge_shape(relative_height):
    """4x(1 − λ⁻⁶)/(1 + x²) with λ² = 1 + x²: :func:`membrane_bulge_pressure` over μ t₀/a."""
    squared = 1.0 + relative_height * relative_height
    return 4.0 * relative_height * (1.0 - squared**-3) / squared


def _bulge_limit() -> tuple[float, float]:
    """(x*, max) of :func:`_bulge_shape` over x > 0, by golden-section search on [0.5, 3] to round-off."""
    ratio = 0.5 * (math.sqrt(5.0) - 1.0)
    low, high = 0.5, 3.0
    for _ in range(200):
        left, right = high - ratio * (high - low), low + ratio * (high - low)
        if _bulge_shape(left) < _bulge_shape(right):
            low = left
        else:
            high = right
    best = 0.5 * (low + high)
    return best, _bulge_shape(best)


#: (h/a, p a/(μ t₀)) at the maximum of :func:`membrane_bulge_pressure`: (1.2588, 1.8353).
BULGE_LIMIT_HEIGHT_RATIO, BULGE_LIMIT_COEFFICIENT = _bulge_limit()


def membrane_bulge_pressure(membrane_modulus, membrane_thickness, aperture_radius, bulge_height):
    """Pressure that holds a neo-Hookean membrane bulged to height h into a circular opening of radius a.

    p = 4 μ t₀ h (1 − λ⁻⁶)/(a² + h²),  λ² = 1 + (h/a)²,  μ = E_m/3   [D]

    Derivation (one-parameter Ritz estimate): the sheet over the opening becomes a spherical cap of height h
    with a uniform equibiaxial stretch λ (its area over the flat disc's, λ² = 1 + (h/a)²). The incompressible
    neo-Hookean membrane (:func:`membrax.membrane.energies.stretching_energy`) stores
    W = (μ t₀ π a²/2)(2λ² + λ⁻⁴ − 3), the cap encloses V = π h (3a² + h²)/6, and p = dW/dV. The pressure
    rises as 12 μ t₀ h³/a⁴ for a shallow bulge, peaks at p_max = 1.8353 μ t₀/a when h = 1.259 a and falls
    beyond: the limit point of inflated rubber membranes (Adkins & Rivlin 1952, Phil. Trans. R. Soc. A
    244, 505–531; the same law's closed sphere peaks at λ = 7^(1/6)). A cell pressure above p_max cannot
    be held by the sheet over that opening: it balloons through (:func:`membrane_limit_pressure`). The
    exact clamped-sheet solution has a non-uniform stretch; this estimate is the uniform-stretch mode's.

    Args:
      membrane_modulus: E_m (Pa, or any stress unit: the result is in it), > 0.
      membrane_thickness: t₀, m (any length unit, the same as the other lengths), > 0.
      aperture_radius: a, > 0.
      bulge_height: h, >= 0.
    """
    check_range("membrane_modulus", membrane_modulus, **_POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **_POSITIVE)
    check_range("aperture_radius", aperture_radius, **_POSITIVE)
    check_range("bulge_height", bulge_height, lower=0.0)
    aperture = as_float(aperture_radius)
    shear_modulus = as_float(membrane_modulus) / 3.0
    tension_scale = shear_modulus * as_float(membrane_thickness) / aperture
    return tension_scale * _bulge_shape(as_float(bulge_height) / aperture)


def membrane_limit_pressure(membrane_modulus, membrane_thickness, aperture_radius):
    """The largest pressure a neo-Hookean membrane over a circular opening of radius a can hold, [D].

    p_max = 1.8353 (E_m/3) t₀/a, the maximum of :func:`membrane_bulge_pressure` (see there). Over an FCC
    specimen's square surface windows, a = :data:`SQUARE_WINDOW_RATIO` × R: 1 mm of 700 kPa over 25 mm
    spheres holds 82.7 kPa, 1 mm of 1400 kPa 165 kPa. Above it, the membrane balloons into the specimen.

    Args:
      membrane_modulus: E_m (any stress unit: the result is in it), > 0.
      membrane_thickness: t₀, > 0.
      aperture_radius: a, in the length unit of ``membrane_thickness``, > 0.
    """
    check_range("membrane_modulus", membrane_modulus, **_POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **_POSITIVE)
    check_range("aperture_radius", aperture_radius, **_POSITIVE)
    return (
        BULGE_LIMIT_COEFFICIENT
        * (as_float(membrane_modulus) / 3.0)
        * as_float(membrane_thickness)
        / as_float(aperture_radius)
    )


# ---------------------------------------------------------------------------------------------------------
# Classical membrane corrections (reference §1–§4)
# ---------------------------------------------------------------------------------------------------------


class MembraneCorrection(NamedTuple):
    """Stress increments due to a membrane, in the unit of the modulus given.

    Attributes:
      axial_stress: Δσ_a, carried by the membrane in the axial direction: *subtract* from the measured
        axial stress to get the stress on the specimen.
      radial_stress: Δσ_r, extra confinement from membrane hoop tension: *add* to the cell pressure.
    """

    axial_stress: jnp.ndarray
    radial_stress: jnp.ndarray


class CorrectedStresses(NamedTuple):
    """Principal stresses on the specimen after a membrane correction, in the unit of the measured ones.

    Attributes:
      sigma_1: σ1 on the specimen (kPa when the inputs are in kPa).
      sigma_3: σ3 on the specimen, the same unit.
    """

    sigma_1: jnp.ndarray
    sigma_3: jnp.ndarray


def apply_membrane_correction(sigma_1, sigma_3, correction: MembraneCorrection) -> CorrectedStresses:
    """Apply a membrane correction to measured principal stresses.

    σ1,specimen = σ1,measured − Δσ_a;   σ3,specimen = σ3,measured + Δσ_r   (reference §1, §3, §12.4)

    Args:
      sigma_1: measured axial stress (ram force over the corrected area).
      sigma_3: measured radial stress (the cell pressure).
      correction: increments from one of the ``*_correction`` functions, in the same unit.
    """
    return CorrectedStresses(
        sigma_1=as_float(sigma_1) - correction.axial_stress,
        sigma_3=as_float(sigma_3) + correction.radial_stress,
    )


def _check_membrane(membrane_modulus, membrane_thickness, diameter_name, diameter):
    check_range("membrane_modulus", membrane_modulus, **_POSITIVE, hint="Latex is about 1.4e6 Pa (1400 kPa).")
    check_range("membrane_thickness", membrane_thickness, **_POSITIVE)
    check_range(diameter_name, diameter, **_POSITIVE)


def astm_shell_correction(membrane_modulus, membrane_thickness, specimen_diameter, axial_strain):
    """ASTM D4767/D7181 membrane correction (small-strain compression shell).

    Δ(σ1 − σ3) = Δσ_a = 4 E_m t_m ε_a / D_c,   Δσ_r = 0
    [U wording of the standards; identical to Henkel & Gilbert's small-strain shell, reference §1(a), §4]

    Args:
      membrane_modulus: E_m (Pa, or any stress unit).
      membrane_thickness: t_m (m).
      specimen_diameter: D_c, the diameter after consolidation (m).
      axial_strain: ε_a, compression positive, < 1.
    """
    _check_membrane(membrane_modulus, membrane_thickness, "specimen_diameter", specimen_diameter)
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    axial = (
        4.0
        * as_float(membrane_modulus)
        * as_float(membrane_thickness)
        * as_float(axial_strain)
        / as_float(specimen_diameter)
    )
    return MembraneCorrection(axial_stress=axial, radial_stress=jnp.zeros_like(axial))


def henkel_gilbert_shell_correction(
    membrane_modulus, membrane_thickness, initial_diameter, axial_strain, volumetric_strain=0.0
):
    """Henkel & Gilbert (1952) compression-shell correction at finite strain.

    Δσ_a = π D M ε_a / A = 4 M ε_a / D,   D = D0 √((1 − εv)/(1 − εa)),   M = E_m t_m,   Δσ_r = 0
    Undrained (εv = 0): Δσ_a = 4 M ε_a √(1 − ε_a)/D0   [U model, D mechanics; reference §1(a)]

    Args:
      membrane_modulus: E_m, Pa (or kPa: Δσ comes out in E_m's unit).
      membrane_thickness: t_m, m (or mm, with D0 in the same unit).
      initial_diameter: D0 of the specimen (right cylinder), in t_m's unit.
      axial_strain: ε_a, compression positive, < 1.
      volumetric_strain: ε_v, contraction positive, < 1 (0: undrained).
    """
    _check_membrane(membrane_modulus, membrane_thickness, "initial_diameter", initial_diameter)
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **_STRAIN, hint=_STRAIN_HINT)
    axial_strain = as_float(axial_strain)
    diameter = as_float(initial_diameter) * (1.0 - radial_strain(axial_strain, volumetric_strain))
    extension_modulus = as_float(membrane_modulus) * as_float(membrane_thickness)
    axial = 4.0 * extension_modulus * axial_strain / diameter
    return MembraneCorrection(axial_stress=axial, radial_stress=jnp.zeros_like(axial))


def hoop_tension_correction(
    membrane_modulus,
    membrane_thickness,
    initial_diameter,
    axial_strain,
    volumetric_strain=0.0,
    *,
    unstretched_membrane_diameter=None,
    small_strain: bool = False,
):
    """Henkel & Gilbert (1952) hoop-tension correction for an axially buckled membrane.

    Δσ_r = 2 M ε_θ / D,   ε_θ = (D − D_m0)/D_m0,   D = D0 √((1 − εv)/(1 − εa)),   Δσ_a = 0
    small strain (undrained, D_m0 = D0): Δσ_r ≈ M ε_a / D0   [U model, D mechanics; reference §1(b)]

    A buckled hoop carries no compression, so Δσ_r is clipped at zero when the specimen contracts
    radially.

    Args:
      membrane_modulus: E_m, Pa (or kPa: Δσ comes out in E_m's unit).
      membrane_thickness: t_m, m (or mm, with the diameters in the same unit).
      initial_diameter: D0 of the specimen, in t_m's unit.
      axial_strain: ε_a, < 1.
      volumetric_strain: ε_v, < 1 (0: undrained).
      unstretched_membrane_diameter: D_m0; defaults to D0.
      small_strain: use M ε_r'/D0 with the linearised hoop strain −(εv − εa)/2 instead.
    """
    _check_membrane(membrane_modulus, membrane_thickness, "initial_diameter", initial_diameter)
    check_range("axial_strain", axial_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **_STRAIN, hint=_STRAIN_HINT)
    check_range("unstretched_membrane_diameter", unstretched_membrane_diameter, **_POSITIVE)
    initial_diameter = as_float(initial_diameter)
    extension_modulus = as_float(membrane_modulus) * as_float(membrane_thickness)
    if small_strain:
        hoop_strain = -radial_strain_small(axial_strain, volumetric_strain)
        radial = 2.0 * extension_modulus * hoop_strain / initial_diameter
    else:
        rest = initial_diameter if unstretched_membrane_diameter is None else unstretched_membrane_diameter
        diameter = initial_diameter * (1.0 - radial_strain(axial_strain, volumetric_strain))
        hoop_strain = (diameter - rest) / rest
        radial = 2.0 * extension_modulus * hoop_strain / diameter
    radial = jnp.maximum(radial, 0.0)
    return MembraneCorrection(axial_stress=jnp.zeros_like(radial), radial_stress=radial)


def right_cylinder_shell_correction(
    membrane_modulus,
    membrane_thickness,
    membrane_diameter,
    axial_strain,
    volumetric_strain,
    *,
    poisson_ratio: float = 0.5,
    small_strain: bool = True,
    clip_hoop_compression: bool = False,
):
    """Thin elastic cylindrical shell bonded to a right-cylinder specimen (Kuerbis & Vaid 1990 type).

    Plane-stress membrane forces per unit length (compression positive), ε_θ the radial strain:
        N_a = E_m t_m/(1 − ν²) (ε_a + ν ε_θ),   T_θ = −E_m t_m/(1 − ν²) (ε_θ + ν ε_a)
        Δσ_a = 4 N_a / D,   Δσ_r = 2 T_θ / D
    With ν = 0.5: Δσ_a = (4 E t/3D)(3ε_a + ε_v), Δσ_r = −(4 E t/3D) ε_v, Δq = 4 E t ε_a/D for any ε_v.
    [C abstract of Kuerbis & Vaid (1990) GTJ 13(4); printed equations U; derivation D, reference §3]

    Args:
      membrane_modulus: E_m, Pa (or kPa: Δσ comes out in E_m's unit).
      membrane_thickness: t_m (unstretched), m (or mm, with D in the same unit).
      membrane_diameter: D, the unstretched membrane (cavity) diameter, in t_m's unit.
      axial_strain: ε_a of the membrane cavity, compression positive, < 1.
      volumetric_strain: ε_v of the membrane cavity, contraction positive, < 1.
      poisson_ratio: ν_m (0.5 for latex), in [0, 0.5].
      small_strain: hoop strain ε_θ ≈ (ε_v − ε_a)/2 (True) or the exact 1 − √((1 − ε_v)/(1 − ε_a)).
      clip_hoop_compression: a membrane cannot carry hoop compression (it buckles): clip Δσ_r at 0.
    """
    _check_membrane(membrane_modulus, membrane_thickness, "membrane_diameter", membrane_diameter)
    check_range("poisson_ratio", poisson_ratio, lower=0.0, upper=0.5)
    strain_fn = radial_strain_small if small_strain else radial_strain
    hoop_strain = strain_fn(axial_strain, volumetric_strain)
    axial_strain = as_float(axial_strain)
    stiffness = as_float(membrane_modulus) * as_float(membrane_thickness) / (1.0 - poisson_ratio**2)
    axial_force = stiffness * (axial_strain + poisson_ratio * hoop_strain)
    hoop_tension = -stiffness * (hoop_strain + poisson_ratio * axial_strain)
    diameter = as_float(membrane_diameter)
    radial = 2.0 * hoop_tension / diameter
    if clip_hoop_compression:
        radial = jnp.maximum(radial, 0.0)
    return MembraneCorrection(axial_stress=4.0 * axial_force / diameter, radial_stress=radial)


def filter_paper_correction(filter_paper_load_per_length, covered_perimeter, specimen_area, axial_strain):
    """Filter-paper side-drain correction (ASTM D4767 form, traced to Bishop & Henkel 1962).

    Δ(σ1 − σ3) = K_fp P_fp / A_c for ε_1 > 2 %,   50 ε_1 K_fp P_fp / A_c for ε_1 <= 2 %
    [U, reference §4]; K_fp ≈ 0.19 kN/m for Whatman No. 54. Returned as an axial increment.

    Args:
      filter_paper_load_per_length: K_fp (force per length, e.g. N/m).
      covered_perimeter: P_fp, the perimeter covered by paper (m).
      specimen_area: A_c after consolidation (m²).
      axial_strain: ε_1 as a fraction, < 1.
    """
    check_range("filter_paper_load_per_length", filter_paper_load_per_length, lower=0.0)
    check_range("covered_perimeter", covered_perimeter, lower=0.0)
    check_range("specimen_area", specimen_area, **_POSITIVE)
    check_range("axial_strain", axial_strain, lower=0.0, **_STRAIN, hint=_STRAIN_HINT)
    full = as_float(filter_paper_load_per_length) * as_float(covered_perimeter) / as_float(specimen_area)
    axial_strain = as_float(axial_strain)
    axial = jnp.where(axial_strain > 0.02, full, 50.0 * axial_strain * full)
    return MembraneCorrection(axial_stress=axial, radial_stress=jnp.zeros_like(axial))
