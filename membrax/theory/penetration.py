"""The membrane over the specimen's surface voids: penetration (Molenkamp & Luger, Baldi & Nova), inflation.

Contract. As :mod:`membrax.theory`'s (pure ``jax.numpy``, under ``jit``/``vmap``/``grad``, broadcasting,
dtype kept; the tags [C], [D], [U] of ``shared/reference/membrane-corrections.md``; concrete arguments
range-checked, tracers not).

Penetration (reference §5): the paper's Eq. 2, Molenkamp & Luger's indentation ratio α/D of a membrane
into the voids of equal spheres, with its stated range of validity; Baldi & Nova's penetration volume per
membrane area and the apparent volumetric strain it gives. Inflation: the pressure that holds a
neo-Hookean membrane bulged into a circular opening, and its limit point, above which the membrane
balloons into the specimen (:func:`membrane_limit_pressure`; :data:`SQUARE_WINDOW_RATIO` gives the opening
of an FCC specimen's square surface windows); the same for a strain-stiffening Gent membrane
(:func:`gent_bulge_pressure`, :func:`gent_membrane_limit_pressure`), whose limit point is higher, and
absent below :data:`GENT_MONOTONIC_LOCKING_JM`.
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
    "GENT_MONOTONIC_LOCKING_JM",
    "MolenkampLugerValidity",
    "SQUARE_WINDOW_RATIO",
    "baldi_nova_penetration",
    "baldi_nova_volumetric_strain",
    "gent_bulge_limit",
    "gent_bulge_pressure",
    "gent_equibiaxial_stress",
    "gent_membrane_limit_pressure",
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


# ---------------------------------------------------------------------------------------------------------
# The same for a Gent membrane: strain stiffening raises the limit point, or removes it
# ---------------------------------------------------------------------------------------------------------


def _cap_invariant_excess(relative_height):
    """I₁ − 3 = 2λ² + λ⁻⁴ − 3 of the cap's equibiaxial stretch, λ² = 1 + x², as x⁴(3 + 2x²)/(1 + x²)².

    The product form is exact (2q³ − 3q² + 1 = (q − 1)²(2q + 1), q = λ²) and free of the cancellation of the
    sum at small x.
    """
    squared = relative_height * relative_height
    return squared * squared * (3.0 + 2.0 * squared) / ((1.0 + squared) * (1.0 + squared))


def gent_equibiaxial_stress(shear_modulus, stretch, locking_jm):
    """Cauchy stress of an incompressible Gent sheet stretched equibiaxially by λ, in plane stress.

    σ = μ (λ² − λ⁻⁴)/(1 − (I₁ − 3)/J_m),  I₁ = 2λ² + λ⁻⁴   [D]

    From W = −(μ J_m/2) ln(1 − (I₁ − 3)/J_m) (Gent 1996, Rubber Chem. Technol. 69, 59–61): with
    λ₁ = λ₂ = λ, λ₃ = λ⁻² and σ₃ = 0, σ = λ ∂W/∂λ₁ = 2 (∂W/∂I₁)(λ² − λ⁻⁴), ∂W/∂I₁ = (μ/2)/(1 − (I₁ − 3)/J_m).
    The membrane tension per unit current length is σ t = σ t₀ λ⁻² (the thickness t = t₀/λ²); per unit
    reference length, σ t₀/λ. J_m → ∞ gives the neo-Hookean μ (λ² − λ⁻⁴). Valid below the lock,
    I₁ − 3 < J_m.

    Args:
      shear_modulus: μ = E_m/3 (any stress unit: the result is in it).
      stretch: λ, > 0.
      locking_jm: J_m, > 0.
    """
    squared = as_float(stretch) ** 2
    excess = 2.0 * squared + squared**-2 - 3.0
    return as_float(shear_modulus) * (squared - squared**-2) / (1.0 - excess / as_float(locking_jm))


def gent_bulge_pressure(membrane_modulus, membrane_thickness, aperture_radius, bulge_height, locking_jm):
    """Pressure that holds a Gent membrane bulged to height h into a circular opening of radius a.

    p = 4 μ t₀ h (1 − λ⁻⁶) / ((a² + h²)(1 − (I₁ − 3)/J_m)),  λ² = 1 + (h/a)²,  I₁ = 2λ² + λ⁻⁴,  μ = E_m/3
    [D]

    The spherical cap of :func:`membrane_bulge_pressure` (uniform equibiaxial stretch λ, the same one-mode
    Ritz estimate) with Gent's energy W = −(μ t₀ π a² J_m/2) ln(1 − (I₁ − 3)/J_m): p = dW/dV is the
    neo-Hookean pressure over 1 − (I₁ − 3)/J_m, Gent's equibiaxial stress factor
    (:func:`gent_equibiaxial_stress`), so it tends to the neo-Hookean one as J_m → ∞, with relative
    difference (I₁ − 3)/J_m to first order in 1/J_m. It grows without bound as the stretch nears the lock
    (I₁ − 3 → J_m); beyond the lock it is infinite (no cap of that height exists).

    Args:
      membrane_modulus: E_m (Pa, or any stress unit: the result is in it), > 0.
      membrane_thickness: t₀ (any length unit, the same as the other lengths), > 0.
      aperture_radius: a, > 0.
      bulge_height: h, >= 0.
      locking_jm: J_m, dimensionless, > 0.
    """
    check_range("locking_jm", locking_jm, **POSITIVE)
    neo_hookean = membrane_bulge_pressure(membrane_modulus, membrane_thickness, aperture_radius, bulge_height)
    relative_height = as_float(bulge_height) / as_float(aperture_radius)
    slack = 1.0 - _cap_invariant_excess(relative_height) / as_float(locking_jm)
    return jnp.where(slack > 0.0, neo_hookean / jnp.where(slack > 0.0, slack, 1.0), jnp.inf)


def _gent_log_slope(relative_height, locking_jm) -> float:
    """The log-slope d ln p/dx of :func:`gent_bulge_pressure` at x = h/a (host floats, below the lock)."""
    x = relative_height
    squared = 1.0 + x * x
    unlocked = -math.expm1(-3.0 * math.log1p(x * x))  # 1 − λ⁻⁶
    neo_hookean = 1.0 / x + 6.0 * x / (squared**4 * unlocked) - 2.0 * x / squared
    excess = x**4 * (3.0 + 2.0 * x * x) / (squared * squared)
    return neo_hookean + 4.0 * x * unlocked / (locking_jm - excess)  # dI₁/dx = 4x(1 − λ⁻⁶)


def _cap_lock_height(locking_jm) -> float:
    """The x = h/a at which the cap's I₁ − 3 reaches J_m, by bisection (I₁ − 3 grows with x)."""
    low, high = 0.0, 1.0
    while _cap_invariant_excess(high) < locking_jm:
        high *= 2.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if _cap_invariant_excess(middle) < locking_jm else (low, middle)
    return low


def _golden_minimum(function, low, high, iterations=200) -> float:
    ratio = 0.5 * (math.sqrt(5.0) - 1.0)
    for _ in range(iterations):
        left, right = high - ratio * (high - low), low + ratio * (high - low)
        low, high = (low, right) if function(left) < function(right) else (left, high)
    return 0.5 * (low + high)


def gent_bulge_limit(locking_jm) -> tuple[float, float]:
    """(h/a, p a/(μ t₀)) at the limit point of :func:`gent_bulge_pressure`; (nan, inf) when it has none.

    The log-slope d ln p/dx (x = h/a) is +∞ at both ends of (0, x_lock) and has one minimum between
    (checked on grids, ``tests/test_membrane_laws.py``): the pressure has a local maximum, the limit point,
    where the slope first crosses zero if that minimum is negative (golden-section search, then
    bisection, to round-off); if not, p(h) rises monotonically to the lock and the membrane never
    balloons (J_m < :data:`GENT_MONOTONIC_LOCKING_JM`). Beyond the limit point the sheet snaps through to
    the stiffened branch near the lock, a cap of height several a: deep in the void behind the opening.
    Host floats (not traced).

    Args:
      locking_jm: J_m, > 0.
    """
    check_range("locking_jm", locking_jm, **POSITIVE)
    locking_jm = float(locking_jm)
    if math.isinf(locking_jm):
        return BULGE_LIMIT_HEIGHT_RATIO, BULGE_LIMIT_COEFFICIENT
    lock = _cap_lock_height(locking_jm)
    lowest = _golden_minimum(lambda x: _gent_log_slope(x, locking_jm), 1e-6 * lock, lock * (1.0 - 1e-12))
    if _gent_log_slope(lowest, locking_jm) >= 0.0:
        return math.nan, math.inf
    low, high = 1e-6 * lock, lowest  # slope > 0, < 0
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if _gent_log_slope(middle, locking_jm) > 0.0 else (low, middle)
    best = 0.5 * (low + high)
    return best, _bulge_shape(best) / (1.0 - _cap_invariant_excess(best) / locking_jm)


#: The J_m below which :func:`gent_bulge_pressure` rises monotonically to the lock (no limit point): 32.6185,
#: where the minimum of its log-slope touches zero (bisection on :func:`gent_bulge_limit`, [D]).
GENT_MONOTONIC_LOCKING_JM = 32.6185


def gent_membrane_limit_pressure(membrane_modulus, membrane_thickness, aperture_radius, locking_jm):
    """The largest pressure a Gent membrane over a circular opening of radius a holds before it snaps, [D].

    p_max = c(J_m) (E_m/3) t₀/a, c the coefficient of :func:`gent_bulge_limit`: 1.8827 for J_m = 97.2
    (:data:`membrax.defaults.GENT_LOCKING_JM`) against the neo-Hookean 1.8353 (1 mm of 700 kPa over 25 mm
    spheres' square windows: 84.8 kPa against 82.7), → 1.8353 as J_m → ∞, and infinite (no limit point)
    for J_m below :data:`GENT_MONOTONIC_LOCKING_JM`. Host floats.

    Args:
      membrane_modulus: E_m (any stress unit: the result is in it), > 0.
      membrane_thickness: t₀, > 0.
      aperture_radius: a, in the length unit of ``membrane_thickness``, > 0.
      locking_jm: J_m, > 0.
    """
    check_range("membrane_modulus", membrane_modulus, **POSITIVE)
    check_range("membrane_thickness", membrane_thickness, **POSITIVE)
    check_range("aperture_radius", aperture_radius, **POSITIVE)
    coefficient = gent_bulge_limit(locking_jm)[1]
    return coefficient * (float(membrane_modulus) / 3.0) * float(membrane_thickness) / float(aperture_radius)
