"""The paper's numbers (Table 1 grid, fixed parameters, Tables 2–3, Fig. 9) and membrax's results beside them.

Modules, one per concept, each name imported here: :mod:`~membrax.paper.published` (the paper's numbers:
its Table 1 grid, fixed parameters, laboratory ballast, Tables 2 and 3, and :func:`paper_key`, which
matches a case to its grid), :mod:`~membrax.paper.tables` (its Tables 2 and 3 for our cases beside its
values, one specimen per case or several) and :mod:`~membrax.paper.fig9` (the numbers of its Fig. 9). Use
them as ``membrax.paper.<name>``.

Contract. Every function but :func:`paper_key` and :func:`paper_fig9_data` takes ``results``, a mapping
from a case key ``(cell_pressure_kpa, membrane_thickness_mm)`` (two positive finite numbers, kPa and mm)
to that case's shear records: the mapping described in :mod:`membrax.triaxial.analysis` (a ``dict`` of
arrays or an ``xarray.Dataset``, the first record being the end of consolidation). Each case needs the
series ``axial_strain``, ``external_axial_stress``, ``external_radial_stress``, ``internal_axial_stress``
and ``internal_radial_stress`` (:data:`REQUIRED_SERIES`). Everything runs on the host in numpy float64.

- :func:`table_2` and :func:`table_3` return one row (a ``dict`` of floats) per case, sorted by thickness
  then pressure as in the paper; for each quantity the row holds ours (``{quantity}``), the paper's
  (``paper_{quantity}``, NaN when the case is not in the paper's grid) and ``difference_{quantity}`` =
  ours − paper. Table 2 is the peak mobilised φ' (:func:`membrax.triaxial.analysis.peak`), Table 3 the
  initial stresses (:func:`membrax.triaxial.analysis.initial_state`, first record) and the additional
  (membrane) stresses internal − external.
- :func:`write_tables` writes both as CSV (exact floats) and Markdown (2 decimals, "–" for NaN).
- :func:`spread_tables` and :func:`write_spread_tables`: the same tables over several specimens per case
  (the seeds of a random packing): mean, sample s.d., min and max, beside a reference packing's values
  (the FCC lattice) and the paper's.
- :func:`fig9_data` and :func:`paper_fig9_data` give, per thickness, the numbers of the paper's Fig. 9:
  the Molenkamp & Luger indentation ratio and the negative of the relative initial axial stress ratio
  (:mod:`membrax.paper.fig9` says how the figure is read); :func:`membrax.plots.plot_fig9` draws them.

Checks. An empty ``results``, a key that is not a pair of positive finite numbers, or records missing a
required series (or holding none) raise ``ValueError`` naming the case and the fix.
"""

from __future__ import annotations

from membrax.paper.fig9 import fig9_data, paper_fig9_data
from membrax.paper.published import (
    BALLAST_CRITICAL_FRICTION_DEG,
    BALLAST_VOID_RATIO,
    BALLAST_VOID_RATIO_MAX,
    BALLAST_VOID_RATIO_MIN,
    INTERPARTICLE_FRICTION_DEG,
    MEMBRANE_MODULUS_KPA,
    PAPER_10KPA_5MM,
    PAPER_CELL_PRESSURES_KPA,
    PAPER_TABLE_2,
    PAPER_TABLE_3,
    PAPER_THICKNESSES_MM,
    PARTICLE_DIAMETER_MM,
    SPECIMEN_DIAMETER_MM,
    TABLE_1_GRID,
    paper_key,
)
from membrax.paper.tables import (
    REQUIRED_SERIES,
    centre_cylinder_radial_stress,
    spread_tables,
    table_2,
    table_3,
    write_spread_tables,
    write_tables,
)

__all__ = [
    "BALLAST_CRITICAL_FRICTION_DEG",
    "BALLAST_VOID_RATIO",
    "BALLAST_VOID_RATIO_MAX",
    "BALLAST_VOID_RATIO_MIN",
    "INTERPARTICLE_FRICTION_DEG",
    "MEMBRANE_MODULUS_KPA",
    "PAPER_10KPA_5MM",
    "PAPER_CELL_PRESSURES_KPA",
    "PAPER_THICKNESSES_MM",
    "PARTICLE_DIAMETER_MM",
    "SPECIMEN_DIAMETER_MM",
    "TABLE_1_GRID",
    "PAPER_TABLE_2",
    "PAPER_TABLE_3",
    "REQUIRED_SERIES",
    "spread_tables",
    "write_spread_tables",
    "paper_key",
    "table_2",
    "table_3",
    "centre_cylinder_radial_stress",
    "write_tables",
    "fig9_data",
    "paper_fig9_data",
]
