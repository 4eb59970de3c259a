"""Peak strength in closed form: Rowe's stress–dilatancy, Bolton's relation, the paper's Eq. 1, Leps' trend.

Contract. As :mod:`membrax.theory`'s (pure ``jax.numpy``, under ``jit``/``vmap``/``grad``, broadcasting,
dtype kept; the tags [C], [D], [U] of ``shared/reference/membrane-corrections.md``; concrete arguments
range-checked, tracers not).

Rowe (1962, reference §6): the peak stress ratio of a regular packing of rigid particles,
R = tan α · tan(φμ + β), for the packings :data:`FCC`, :data:`FCC_PAPER`, :data:`TETRAHEDRAL`,
:data:`RODS_SQUARE` and :data:`RODS_HEXAGONAL` (:class:`RowePacking`). Bolton (1986, reference §7): the
relative density and the relative dilatancy index I_R, the peak friction angle φ'_crit + 3 I_R and the
maximum dilatancy rate; the paper's Eq. 1, which differs from Bolton's by 2°. Leps (reference §8): the
log-linear rockfill trend of φ' with σ'3. Bolton's and the paper's relations take p' in kPa (``ln p'``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

from membrax.theory._ranges import ANGLE_DEG, POSITIVE
from membrax.validation import as_float, check_range

__all__ = [
    "FCC",
    "FCC_PAPER",
    "RODS_HEXAGONAL",
    "RODS_SQUARE",
    "ROWE_PACKINGS",
    "TETRAHEDRAL",
    "RowePacking",
    "bolton_max_dilatancy_rate",
    "bolton_peak_friction_angle_deg",
    "leps_friction_angle_deg",
    "paper_eq1_peak_friction_angle_deg",
    "relative_density",
    "relative_dilatancy_index",
    "rowe_peak_friction_angle",
    "rowe_peak_friction_angle_deg",
    "rowe_stress_ratio",
]


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
    check_range("interparticle_friction_angle_deg", interparticle_friction_angle_deg, **ANGLE_DEG)
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
    check_range("void_ratio", void_ratio, **POSITIVE)
    check_range("void_ratio_min", void_ratio_min, **POSITIVE)
    check_range("void_ratio_max", void_ratio_max, **POSITIVE)
    e_min = as_float(void_ratio_min)
    e_max = as_float(void_ratio_max)
    check_range("void_ratio_max - void_ratio_min", e_max - e_min, **POSITIVE, hint="e_max must exceed e_min.")
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
    check_range("mean_effective_stress_kpa", mean_effective_stress_kpa, **POSITIVE)
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
    check_range("critical_friction_angle_deg", critical_friction_angle_deg, **ANGLE_DEG)
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
    check_range("critical_friction_angle_deg", critical_friction_angle_deg, **ANGLE_DEG)
    check_range("relative_density", relative_density, lower=0.0, upper=1.0)
    check_range("mean_effective_stress_kpa", mean_effective_stress_kpa, **POSITIVE)
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
    check_range("confining_stress_kpa", confining_stress_kpa, **POSITIVE)
    return as_float(reference_friction_angle_deg) - as_float(
        friction_angle_drop_per_log_cycle_deg
    ) * jnp.log10(as_float(confining_stress_kpa) / atmospheric_pressure_kpa)
