"""The membrane over the specimen's surface voids: penetration (Molenkamp & Luger, Baldi & Nova), inflation.

Contract. As :mod:`membrax.theory`'s (pure ``jax.numpy``, under ``jit``/``vmap``/``grad``, broadcasting,
dtype kept; the tags [C], [D], [U] of ``shared/reference/membrane-corrections.md``; concrete arguments
range-checked, tracers not).

Penetration (reference §5): the paper's Eq. 2, Molenkamp & Luger's indentation ratio α/D of a membrane
into the voids of equal spheres, with its stated range of validity; Baldi & Nova's penetration volume per
membrane area and the apparent volumetric strain it gives. Inflation: the pressure that holds a
neo-Hookean membrane bulged into a circular opening, and its limit point, above which the membrane
balloons into the specimen (:func:`membrane_limit_pressure`; :data:`SQUARE_WINDOW_RATIO` gives the opening
of an FCC specimen's square surface windows).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

from membrax.theory._ranges import POSITIVE
from membrax.validation import as_float, check_range

__all__ = [
    "BULGE_LIMIT_COEFFICIENT",
    "BULGE_LIMIT_HEIGHT_RATIO",
    "MolenkampLugerValidity",
    "SQUARE_WINDOW_RATIO",
    "baldi_nova_penetration",
    "baldi_nova_volumetric_strain",
    "membrane_bulge_pressure",
    "membrane_limit_pressure",
    "molenkamp_luger_indentation_ratio",
    "molenkamp_luger_validity",
]


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
    check_range("void_ratio", void_ratio, **POSITIVE)
    check_range("grain_diameter", grain_diameter, **POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
    check_range("effective_stress", effective_stress, lower=0.0)
    check_range("membrane_modulus", membrane_modulus, **POSITIVE)
    check_range("constant", constant, **POSITIVE, hint="Molenkamp & Luger give 0.15–0.4.")
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
    check_range("grain_diameter", grain_diameter, **POSITIVE)
    check_range("effective_stress", effective_stress, lower=0.0)
    check_range("membrane_modulus", membrane_modulus, **POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
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
    check_range("specimen_diameter", specimen_diameter, **POSITIVE)
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
    check_range("membrane_modulus", membrane_modulus, **POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
    check_range("aperture_radius", aperture_radius, **POSITIVE)
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
    check_range("membrane_modulus", membrane_modulus, **POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
    check_range("aperture_radius", aperture_radius, **POSITIVE)
    return (
        BULGE_LIMIT_COEFFICIENT
        * (as_float(membrane_modulus) / 3.0)
        * as_float(membrane_thickness)
        / as_float(aperture_radius)
    )
