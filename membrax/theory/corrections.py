"""The classical membrane corrections: what a membrane adds to the stresses a triaxial test measures.

Contract. As :mod:`membrax.theory`'s (pure ``jax.numpy``, under ``jit``/``vmap``/``grad``, broadcasting,
dtype kept; the tags [C], [D], [U] of ``shared/reference/membrane-corrections.md``; concrete arguments
range-checked, tracers not).

Each ``*_correction`` function (reference §1–§4) returns a :class:`MembraneCorrection`, the axial
increment the membrane carries (to subtract from the measured σ1) and the radial confinement its hoop
tension adds (to add to σ3), in the unit of the modulus given; :func:`apply_membrane_correction` applies
one to measured stresses (:class:`CorrectedStresses`). The corrections: ASTM's small-strain compression
shell, Henkel & Gilbert's shell at finite strain and their hoop tension of a buckled membrane, a thin
elastic shell bonded to a right cylinder (Kuerbis & Vaid type), and the filter-paper side drains.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from membrax.theory._ranges import POSITIVE, STRAIN, STRAIN_HINT
from membrax.theory.measures import radial_strain, radial_strain_small
from membrax.validation import as_float, check_range

__all__ = [
    "CorrectedStresses",
    "MembraneCorrection",
    "apply_membrane_correction",
    "astm_shell_correction",
    "filter_paper_correction",
    "henkel_gilbert_shell_correction",
    "hoop_tension_correction",
    "right_cylinder_shell_correction",
]


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
    check_range("membrane_modulus", membrane_modulus, **POSITIVE, hint="Latex is about 1.4e6 Pa (1400 kPa).")
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
    check_range(diameter_name, diameter, **POSITIVE)


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
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
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
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **STRAIN, hint=STRAIN_HINT)
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
    check_range("axial_strain", axial_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("volumetric_strain", volumetric_strain, **STRAIN, hint=STRAIN_HINT)
    check_range("unstretched_membrane_diameter", unstretched_membrane_diameter, **POSITIVE)
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
    check_range("specimen_area", specimen_area, **POSITIVE)
    check_range("axial_strain", axial_strain, lower=0.0, **STRAIN, hint=STRAIN_HINT)
    full = as_float(filter_paper_load_per_length) * as_float(covered_perimeter) / as_float(specimen_area)
    axial_strain = as_float(axial_strain)
    axial = jnp.where(axial_strain > 0.02, full, 50.0 * axial_strain * full)
    return MembraneCorrection(axial_stress=axial, radial_stress=jnp.zeros_like(axial))
