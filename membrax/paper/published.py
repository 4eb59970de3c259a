"""The paper's numbers: its Table 1 grid, fixed parameters, laboratory ballast, Tables 2 and 3.

Contract. Constants, and :func:`paper_key`, which matches a case to the paper's grid. The numbers live
here and nowhere else: its Table 1 grid (:data:`TABLE_1_GRID`, the default grid of
:func:`membrax.sweep.run_sweep`), its fixed parameters (:data:`PARTICLE_DIAMETER_MM`,
:data:`MEMBRANE_MODULUS_KPA`, :data:`INTERPARTICLE_FRICTION_DEG`; membrax's defaults are these values, so
they are read from :mod:`membrax.defaults`, as the configuration's are, and checked against the paper in
``tests/test_paper.py``), its laboratory ballast (``BALLAST_*``) and its Tables 2 and 3
(:data:`PAPER_TABLE_2`, :data:`PAPER_TABLE_3`, :data:`PAPER_10KPA_5MM`).

Matching the paper's grid. A case is the paper's case when its pressure and thickness are each within
0.005 (kPa, mm) of one of the paper's (:func:`paper_key`): a run at 10/3 mm is the paper's 3.33 mm case.

The paper's values (:data:`PAPER_TABLE_2`, :data:`PAPER_TABLE_3`) are copied from its Tables 2 and 3 as
printed, keyed by ``(cell_pressure_kpa, membrane_thickness_mm)`` floats over (10, 40, 100) kPa × (2.5,
3.33, 5.0) mm. The tables print the middle thickness as "3.3"; the study's thickness is 3.33 mm (Table 1:
membrane/particle ratio 2/15 of 25 mm spheres), so it is keyed 3.33.
"""

from __future__ import annotations

from membrax import defaults

__all__ = [
    "PAPER_CELL_PRESSURES_KPA",
    "PAPER_THICKNESSES_MM",
    "TABLE_1_GRID",
    "PARTICLE_DIAMETER_MM",
    "MEMBRANE_MODULUS_KPA",
    "INTERPARTICLE_FRICTION_DEG",
    "SPECIMEN_DIAMETER_MM",
    "BALLAST_CRITICAL_FRICTION_DEG",
    "BALLAST_VOID_RATIO_MIN",
    "BALLAST_VOID_RATIO_MAX",
    "BALLAST_VOID_RATIO",
    "PAPER_TABLE_2",
    "PAPER_TABLE_3",
    "PAPER_10KPA_5MM",
    "paper_key",
]

#: The paper's cell pressures (kPa), its Table 1.
PAPER_CELL_PRESSURES_KPA = (10.0, 40.0, 100.0)
#: The paper's membrane thicknesses (mm), its Table 1 (Tables 2 and 3 print 3.33 as "3.3").
PAPER_THICKNESSES_MM = (2.5, 3.33, 5.0)
#: The paper's Table 1 as a sweep grid (configuration field → values).
TABLE_1_GRID = {"cell_pressure_kpa": PAPER_CELL_PRESSURES_KPA, "membrane_thickness_mm": PAPER_THICKNESSES_MM}

# The paper's fixed parameters (its §3, Table 1; reference §12). membrax's defaults are the paper's, so the
# one source is membrax.defaults (in SI); tests/test_paper.py checks them against the paper's text.
#: Sphere diameter D, mm (25 mm granite spheres).
PARTICLE_DIAMETER_MM = 1e3 * defaults.PARTICLE_DIAMETER
#: Latex membrane Young's modulus E_m, kPa (1400 kPa).
MEMBRANE_MODULUS_KPA = defaults.MEMBRANE_MODULUS / 1e3
#: Interparticle friction angle φ_μ, degrees (25°).
INTERPARTICLE_FRICTION_DEG = defaults.FRICTION_ANGLE_DEG
#: Nominal specimen diameter, mm (10 spheres across).
SPECIMEN_DIAMETER_MM = defaults.PARTICLES_ACROSS * PARTICLE_DIAMETER_MM

# The paper's laboratory ballast (its Fig. 1 and Eq. 1).
#: Critical-state friction angle φ'_crit, degrees.
BALLAST_CRITICAL_FRICTION_DEG = 36.0
#: Minimum void ratio e_min.
BALLAST_VOID_RATIO_MIN = 0.71
#: Maximum void ratio e_max.
BALLAST_VOID_RATIO_MAX = 1.00
#: Void ratio of the tested ballast.
BALLAST_VOID_RATIO = 0.78

# The paper's Table 2 in its row order: σc (kPa), t_m (mm), peak φ' external, internal (degrees).
_TABLE_2_ROWS = (
    (10.0, 2.5, 40.3, 40.0),
    (40.0, 2.5, 39.8, 40.3),
    (100.0, 2.5, 39.1, 40.1),
    (10.0, 3.33, 40.6, 40.1),
    (40.0, 3.33, 39.9, 40.2),
    (100.0, 3.33, 39.4, 40.1),
    (10.0, 5.0, 41.1, 40.2),
    (40.0, 5.0, 40.2, 40.2),
    (100.0, 5.0, 39.7, 40.1),
)
# The paper's Table 3 in its row order: σc (kPa), t_m (mm), initial σ3 ext, σ3 int, σ1 ext, σ1 int (kPa).
_TABLE_3_ROWS = (
    (10.0, 2.5, 10.0, 11.2, 10.6, 13.5),
    (40.0, 2.5, 40.0, 44.1, 40.7, 49.1),
    (100.0, 2.5, 100.0, 109.4, 101.1, 117.7),
    (10.0, 3.33, 10.0, 11.5, 10.9, 13.9),
    (40.0, 3.33, 40.0, 44.4, 40.9, 50.2),
    (100.0, 3.33, 100.0, 109.7, 100.8, 119.6),
    (10.0, 5.0, 10.0, 11.8, 10.7, 14.6),
    (40.0, 5.0, 40.0, 45.0, 41.0, 52.1),
    (100.0, 5.0, 100.0, 110.6, 101.1, 123.4),
)

#: The paper's Table 2 (peak mobilised friction angles, degrees, external and internal stresses as in its
#: §4.3), keyed by ``(cell_pressure_kpa, membrane_thickness_mm)``; the keys of
#: :func:`membrax.triaxial.analysis.peak`.
PAPER_TABLE_2 = {
    (pressure, thickness): {
        "peak_external_friction_angle_deg": external,
        "peak_internal_friction_angle_deg": internal,
    }
    for pressure, thickness, external, internal in _TABLE_2_ROWS
}

#: The paper's Table 3 (initial external and internal principal stresses, kPa), keyed by
#: ``(cell_pressure_kpa, membrane_thickness_mm)``; the keys of
#: :func:`membrax.triaxial.analysis.initial_state`.
PAPER_TABLE_3 = {
    (pressure, thickness): {
        "sigma3_external_kpa": sigma3_external,
        "sigma3_internal_kpa": sigma3_internal,
        "sigma1_external_kpa": sigma1_external,
        "sigma1_internal_kpa": sigma1_internal,
    }
    for pressure, thickness, sigma3_external, sigma3_internal, sigma1_external, sigma1_internal in (
        _TABLE_3_ROWS
    )
}

#: The paper's values for 10 kPa cell pressure and a 5 mm membrane (the test of its Figs 5–8), keyed as
#: the results of :func:`membrax.triaxial.analysis.initial_state`, :func:`~membrax.triaxial.analysis.peak` and
#: :func:`~membrax.triaxial.analysis.largest_overestimate`, for
#: :func:`membrax.triaxial.analysis.summary_table`: its Table 2 and 3 rows, and from Fig. 5 and §5.2 that
#: beyond about 3 % axial strain the external φ' exceeds the internal one "by up to 4°" (§5.2 says only that
#: the peak "occurs almost immediately at close to 0% axial strain", and not at which strain the largest
#: difference falls, so no strains are given).
PAPER_10KPA_5MM = {**PAPER_TABLE_3[(10.0, 5.0)], **PAPER_TABLE_2[(10.0, 5.0)], "overestimate_deg": 4.0}

# A case matches the paper's when pressure and thickness are both within this of the paper's (kPa, mm).
_GRID_TOLERANCE = 0.005


def paper_key(cell_pressure_kpa: float, membrane_thickness_mm: float) -> tuple[float, float] | None:
    """The key of the paper's case matching a pressure and thickness, or ``None`` outside its grid.

    A case matches when its pressure and thickness are each within 0.005 (kPa, mm) of the paper's, so
    ``paper_key(10, 10 / 3)`` is ``(10.0, 3.33)``.

    Args:
      cell_pressure_kpa: σc, kPa.
      membrane_thickness_mm: t_m, mm.

    Returns:
      A key of :data:`PAPER_TABLE_2` and :data:`PAPER_TABLE_3`, or ``None``.
    """
    for pressure in PAPER_CELL_PRESSURES_KPA:
        for thickness in PAPER_THICKNESSES_MM:
            if (
                abs(float(cell_pressure_kpa) - pressure) <= _GRID_TOLERANCE
                and abs(float(membrane_thickness_mm) - thickness) <= _GRID_TOLERANCE
            ):
                return pressure, thickness
    return None
