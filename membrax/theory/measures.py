"""The stress and strain measures of a triaxial test, and the FCC packing's density.

Contract. As :mod:`membrax.theory`'s (pure ``jax.numpy``, under ``jit``/``vmap``/``grad``, broadcasting,
dtype kept; the tags [C], [D], [U] of ``shared/reference/membrane-corrections.md``; concrete arguments
range-checked, tracers not).

Measures (reference §9): the stress ratio R = σ1/σ3, the mean and deviator stresses p and q, the mobilised
friction angle from the Mohr–Coulomb circle and its conversions from R and q/p, the right cylinder's area
correction and radial strain (exact and small-strain), and the axial strain rate of an inertial number.
Geometry: the solid fraction, porosity and void ratio of face-centred cubic packing of equal spheres.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from membrax.theory._ranges import POSITIVE, STRAIN, STRAIN_HINT
from membrax.validation import as_float, check_range

__all__ = [
    "FCC_POROSITY",
    "FCC_SOLID_FRACTION",
    "FCC_VOID_RATIO",
    "area_correction",
    "deviator_stress",
    "friction_angle_from_q_over_p",
    "friction_angle_from_stress_ratio",
    "mean_stress",
    "mobilised_friction_angle",
    "mobilised_friction_angle_deg",
    "radial_strain",
    "radial_strain_small",
    "stress_ratio",
    "stress_ratio_from_friction_angle",
    "strain_rate_from_inertial_number",
]


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
    check_range("sigma_3", sigma_3, **POSITIVE)
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
    check_range("sigma_1", sigma_1, **POSITIVE)
    check_range("sigma_3", sigma_3, **POSITIVE)
    sigma_1 = as_float(sigma_1)
    sigma_3 = as_float(sigma_3)
    return jnp.arcsin((sigma_1 - sigma_3) / (sigma_1 + sigma_3))


def mobilised_friction_angle_deg(sigma_1, sigma_3):
    """:func:`mobilised_friction_angle` in degrees."""
    return jnp.rad2deg(mobilised_friction_angle(sigma_1, sigma_3))


def friction_angle_from_stress_ratio(ratio):
    """Friction angle (radians) from R = σ1/σ3: sin φ' = (R − 1)/(R + 1)   [C, reference §6]."""
    check_range("ratio", ratio, **POSITIVE)
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
    check_range("initial_area", initial_area, **POSITIVE)
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **STRAIN, hint=STRAIN_HINT)
    return as_float(initial_area) * (1.0 - as_float(volumetric_strain)) / (1.0 - as_float(axial_strain))


def radial_strain(axial_strain, volumetric_strain):
    """Exact right-cylinder radial strain εr = 1 − √((1 − εv)/(1 − εa))   [D, reference §9].

    Derivation: V = π r² H, so (r/r0)² = (V/V0)/(H/H0) = (1 − εv)/(1 − εa). Compression positive, so a
    bulging specimen has εr < 0.
    """
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **STRAIN, hint=STRAIN_HINT)
    return 1.0 - jnp.sqrt((1.0 - as_float(volumetric_strain)) / (1.0 - as_float(axial_strain)))


def radial_strain_small(axial_strain, volumetric_strain):
    """Small-strain radial strain εr ≈ (εv − εa)/2, from εv = εa + 2εr   [D, reference §9]."""
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **STRAIN, hint=STRAIN_HINT)
    return 0.5 * (as_float(volumetric_strain) - as_float(axial_strain))
