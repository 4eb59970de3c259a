"""Closed-form theory: stress measures, stress–dilatancy and classical membrane corrections.

Modules, one per concept, each name imported here: :mod:`~membrax.theory.measures` (stress and strain
measures, the FCC packing's density), :mod:`~membrax.theory.strength` (Rowe, Bolton, the paper's Eq. 1,
Leps), :mod:`~membrax.theory.penetration` (Molenkamp & Luger, Baldi & Nova, the membrane's inflation
limit) and :mod:`~membrax.theory.corrections` (the classical membrane corrections). Use them as
``membrax.theory.<name>``.

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

from membrax.theory.corrections import (
    CorrectedStresses,
    MembraneCorrection,
    apply_membrane_correction,
    astm_shell_correction,
    filter_paper_correction,
    henkel_gilbert_shell_correction,
    hoop_tension_correction,
    right_cylinder_shell_correction,
)
from membrax.theory.measures import (
    FCC_POROSITY,
    FCC_SOLID_FRACTION,
    FCC_VOID_RATIO,
    area_correction,
    deviator_stress,
    friction_angle_from_q_over_p,
    friction_angle_from_stress_ratio,
    mean_stress,
    mobilised_friction_angle,
    mobilised_friction_angle_deg,
    radial_strain,
    radial_strain_small,
    strain_rate_from_inertial_number,
    stress_ratio,
    stress_ratio_from_friction_angle,
)
from membrax.theory.penetration import (
    BULGE_LIMIT_COEFFICIENT,
    BULGE_LIMIT_HEIGHT_RATIO,
    GENT_MONOTONIC_LOCKING_JM,
    SQUARE_WINDOW_RATIO,
    MolenkampLugerValidity,
    baldi_nova_penetration,
    baldi_nova_volumetric_strain,
    gent_bulge_limit,
    gent_bulge_pressure,
    gent_equibiaxial_stress,
    gent_membrane_limit_pressure,
    membrane_bulge_pressure,
    membrane_limit_pressure,
    molenkamp_luger_indentation_ratio,
    molenkamp_luger_validity,
)
from membrax.theory.strength import (
    FCC,
    FCC_PAPER,
    RODS_HEXAGONAL,
    RODS_SQUARE,
    ROWE_PACKINGS,
    TETRAHEDRAL,
    RowePacking,
    bolton_max_dilatancy_rate,
    bolton_peak_friction_angle_deg,
    leps_friction_angle_deg,
    paper_eq1_peak_friction_angle_deg,
    relative_density,
    relative_dilatancy_index,
    rowe_peak_friction_angle,
    rowe_peak_friction_angle_deg,
    rowe_stress_ratio,
)

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
    "GENT_MONOTONIC_LOCKING_JM",
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
    "gent_bulge_limit",
    "gent_bulge_pressure",
    "gent_equibiaxial_stress",
    "gent_membrane_limit_pressure",
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
