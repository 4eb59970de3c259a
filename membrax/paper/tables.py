"""Tables 2 and 3 of the paper for membrax's cases, beside the paper's: one specimen per case, or several.

Contract. Every function takes ``results``, a mapping from a case key ``(cell_pressure_kpa,
membrane_thickness_mm)`` (two positive finite numbers, kPa and mm) to that case's shear records: the
mapping described in :mod:`membrax.triaxial.analysis` (a ``dict`` of arrays or an ``xarray.Dataset``, the
first record being the end of consolidation). Each case needs the series of :data:`REQUIRED_SERIES`
(:func:`checked_cases` checks them). Everything runs on the host in numpy float64.

- :func:`table_2` and :func:`table_3` return one row (a ``dict`` of floats) per case, sorted by thickness
  then pressure as in the paper; for each quantity the row holds ours (``{quantity}``), the paper's
  (``paper_{quantity}``, NaN when the case is not in the paper's grid, :func:`membrax.paper.paper_key`)
  and ``difference_{quantity}`` = ours − paper. Table 2 is the peak mobilised φ'
  (:func:`membrax.triaxial.analysis.peak`), Table 3 the initial stresses
  (:func:`membrax.triaxial.analysis.initial_state`, first record) and the additional (membrane) stresses
  internal − external.
- :func:`write_tables` writes both as CSV (exact floats) and Markdown (2 decimals, "–" for NaN).
- :func:`spread_tables` and :func:`write_spread_tables`: the same tables over several specimens per case
  (the seeds of a random packing): mean, sample s.d., min and max, beside a reference packing's values
  (the FCC lattice) and the paper's.

Checks. An empty ``results``, a key that is not a pair of positive finite numbers, or records missing a
required series (or holding none) raise ``ValueError`` naming the case and the fix.
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from membrax.io.files import atomic_write_bytes, ensure_folder
from membrax.paper.published import PAPER_TABLE_2, PAPER_TABLE_3, paper_key
from membrax.triaxial import analysis

__all__ = [
    "REQUIRED_SERIES",
    "checked_cases",
    "table_2",
    "table_3",
    "centre_cylinder_radial_stress",
    "write_tables",
    "spread_tables",
    "write_spread_tables",
]

#: Series every case's records must hold (see :mod:`membrax.triaxial.analysis`).
REQUIRED_SERIES = (
    "axial_strain",
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
)

# (column, Markdown label, unit) of each quantity, in column order.
_TABLE_2_QUANTITIES = (
    ("peak_external_friction_angle_deg", "Peak φ' external", "°"),
    ("peak_internal_friction_angle_deg", "Peak φ' internal", "°"),
)
_TABLE_3_QUANTITIES = (
    ("sigma3_external_kpa", "σ3 external", "kPa"),
    ("sigma3_internal_kpa", "σ3 internal", "kPa"),
    ("sigma1_external_kpa", "σ1 external", "kPa"),
    ("sigma1_internal_kpa", "σ1 internal", "kPa"),
    ("additional_sigma3_kpa", "Δσ3 = σ3 int − ext", "kPa"),
    ("additional_sigma1_kpa", "Δσ1 = σ1 int − ext", "kPa"),
)
#: With the particle radius: the paper's "right cylinder" read through the boundary spheres' centres.
_CENTRES_QUANTITY = ("additional_sigma3_centres_kpa", "Δσ3, cylinder through boundary sphere centres", "kPa")
_KEY_COLUMNS = (
    ("cell_pressure_kpa", "Cell pressure σc", "kPa"),
    ("membrane_thickness_mm", "Membrane t_m", "mm"),
)


# ---------------------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------------------

_RESULTS_HINT = (
    "pass a mapping {(cell_pressure_kpa, membrane_thickness_mm): shear records}, e.g. "
    "{(10.0, 5.0): read_results('results_10kPa_5mm/results.nc')}"
)


def _case_key(key) -> tuple[float, float]:
    """``key`` as ``(cell_pressure_kpa, membrane_thickness_mm)`` floats; ValueError if it is not one."""
    if isinstance(key, str | bytes) or not isinstance(key, Sequence) or len(key) != 2:
        raise ValueError(
            f"results has the key {key!r}, not a (cell_pressure_kpa, membrane_thickness_mm) pair; "
            f"{_RESULTS_HINT}."
        )
    values = []
    for name, value in zip(("cell_pressure_kpa", "membrane_thickness_mm"), key, strict=True):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ValueError(
                f"results has the key {key!r}, whose {name} {value!r} is not a number; {_RESULTS_HINT}."
            )
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(
                f"results has the key {key!r}, whose {name} = {value} is not a positive finite "
                f"number; {_RESULTS_HINT}."
            )
        values.append(value)
    return values[0], values[1]


def _check_records(key: tuple[float, float], records) -> None:
    """ValueError unless ``records`` holds the :data:`REQUIRED_SERIES`, non-empty and equally long."""
    case = f"results[({key[0]:g}, {key[1]:g})]"
    if not isinstance(records, Mapping):
        raise ValueError(
            f"{case} is a {type(records).__name__}; pass the case's shear records, a mapping "
            "name -> 1-D series (dict or xarray.Dataset, see membrax.triaxial.analysis)."
        )
    missing = [name for name in REQUIRED_SERIES if name not in records]
    if missing:
        raise ValueError(
            f"{case} has no series {', '.join(map(repr, missing))}; pass the shear records of a "
            f"membrane triaxial test, which hold {', '.join(REQUIRED_SERIES)} (membrax.triaxial.analysis)."
        )
    sizes = {name: np.size(records[name]) for name in REQUIRED_SERIES}
    if 0 in sizes.values() or len(set(sizes.values())) != 1:
        raise ValueError(
            f"{case} holds series of {sizes} records; each must hold the same number (at least "
            "one: the first is the end of consolidation)."
        )


def checked_cases(results) -> list[tuple[tuple[float, float], object]]:
    """The checked ``(key, records)`` pairs of ``results``, sorted by thickness then pressure."""
    if not isinstance(results, Mapping):
        raise ValueError(f"results is a {type(results).__name__}; {_RESULTS_HINT}.")
    if not results:
        raise ValueError(f"results is empty; {_RESULTS_HINT}.")
    cases = []
    for key, records in results.items():
        key = _case_key(key)
        _check_records(key, records)
        cases.append((key, records))
    return sorted(cases, key=lambda case: (case[0][1], case[0][0]))


# ---------------------------------------------------------------------------------------------------------
# Tables 2 and 3
# ---------------------------------------------------------------------------------------------------------


def _row(key: tuple[float, float], ours: Mapping, paper_table: Mapping, quantities) -> dict:
    """One table row: the key columns, then ours, paper's and ours − paper for each quantity."""
    paper = paper_table.get(paper_key(*key), {})
    row = {"cell_pressure_kpa": key[0], "membrane_thickness_mm": key[1]}
    for name, _, _ in quantities:
        value = float(ours[name])
        reference = float(paper.get(name, np.nan))
        row[name] = value
        row[f"paper_{name}"] = reference
        row[f"difference_{name}"] = value - reference
    return row


def _peak_angles(records) -> dict:
    """:func:`membrax.triaxial.analysis.peak` from the four stresses and the axial strain only."""
    derived = {
        f"{side}_friction_angle_deg": analysis.friction_angle_deg(
            analysis.record(records, f"{side}_axial_stress"),
            analysis.record(records, f"{side}_radial_stress"),
        )
        for side in ("external", "internal")
    }
    return analysis.peak(records, derived)


def _with_additional(stresses: Mapping) -> dict:
    """Initial stresses with the additional (membrane) stresses internal − external added (kPa)."""
    return {
        **stresses,
        "additional_sigma3_kpa": stresses["sigma3_internal_kpa"] - stresses["sigma3_external_kpa"],
        "additional_sigma1_kpa": stresses["sigma1_internal_kpa"] - stresses["sigma1_external_kpa"],
    }


def table_2(results) -> list[dict]:
    """The paper's Table 2 for our cases: peak mobilised φ' from external and internal stresses.

    Args:
      results: ``{(cell_pressure_kpa, membrane_thickness_mm): shear records}`` (see the module docstring).

    Returns:
      One dict of floats per case, sorted by thickness then pressure, with the columns
      ``cell_pressure_kpa, membrane_thickness_mm`` and, for ``q`` in ``peak_external_friction_angle_deg,
      peak_internal_friction_angle_deg`` (degrees, :func:`membrax.triaxial.analysis.peak`): ``q``,
      ``paper_q`` (NaN outside the paper's grid) and ``difference_q`` = ours − paper.

    Raises:
      ValueError: see the module docstring (Checks).
    """
    return [
        _row(key, _peak_angles(records), PAPER_TABLE_2, _TABLE_2_QUANTITIES)
        for key, records in checked_cases(results)
    ]


def centre_cylinder_radial_stress(records, particle_radius: float, index: int = 0) -> float:
    """Internal σ3 over the right cylinder through the boundary spheres' centres, kPa.

    membrax's internal σ3 divides the radial load by the lateral area of the cylinder of the platen area
    A, 2 π r H with r = √(A/π) (:func:`membrax.membrane.records.right_cylinder_stresses`). The paper's
    "surface area of the right cylinder" (its §4.3) may be that of the cylinder through the centres of
    the boundary spheres, r_c = r − R, which scales σ3 by r / (r − R) (1.11 at paper size); that reading
    reproduces the paper's Δσ3 ≈ 0.1 σc:

        σ3,c = σ3,int · r / (r − R)

    Args:
      records: shear records with ``internal_radial_stress`` (Pa) and ``platen_area`` (m²).
      particle_radius: R, m, > 0 and below r.
      index: the record (0: the end of consolidation).

    Raises:
      ValueError: R not in (0, r).
    """
    radius = math.sqrt(float(analysis.record(records, "platen_area")[index]) / math.pi)
    if not 0.0 < particle_radius < radius:
        raise ValueError(
            f"particle_radius = {particle_radius!r} m; it must lie in (0, {radius:g}) m, the radius of the "
            "platen's right cylinder (pass the configuration's particle_radius, in metres)."
        )
    sigma3 = float(analysis.record(records, "internal_radial_stress")[index])
    return analysis.KPA_PER_PA * sigma3 * radius / (radius - particle_radius)


def table_3(results, particle_radius: float | None = None) -> list[dict]:
    """The paper's Table 3 for our cases: initial stresses and the additional membrane stresses.

    Args:
      results: ``{(cell_pressure_kpa, membrane_thickness_mm): shear records}`` (see the module docstring).
      particle_radius: R (m); when given, a last quantity ``additional_sigma3_centres_kpa``: Δσ3 with
        internal σ3 over the cylinder through the boundary spheres' centres
        (:func:`centre_cylinder_radial_stress`, records need ``platen_area``), beside the paper's Δσ3.

    Returns:
      One dict of floats per case, sorted by thickness then pressure, with the columns
      ``cell_pressure_kpa, membrane_thickness_mm`` and, for ``q`` in ``sigma3_external_kpa,
      sigma3_internal_kpa, sigma1_external_kpa, sigma1_internal_kpa`` (the first record,
      :func:`membrax.triaxial.analysis.initial_state`) and ``additional_sigma3_kpa, additional_sigma1_kpa``
      (internal − external), all kPa: ``q``, ``paper_q`` (NaN outside the paper's grid) and ``difference_q``
      = ours − paper.

    Raises:
      ValueError: see the module docstring (Checks).
    """
    paper = {key: _with_additional(values) for key, values in PAPER_TABLE_3.items()}
    quantities = _TABLE_3_QUANTITIES
    if particle_radius is not None:
        quantities = (*quantities, _CENTRES_QUANTITY)
        for values in paper.values():
            values[_CENTRES_QUANTITY[0]] = values["additional_sigma3_kpa"]
    rows = []
    for key, records in checked_cases(results):
        ours = _with_additional(analysis.initial_state(records))
        if particle_radius is not None:
            ours[_CENTRES_QUANTITY[0]] = (
                centre_cylinder_radial_stress(records, particle_radius) - ours["sigma3_external_kpa"]
            )
        rows.append(_row(key, ours, paper, quantities))
    return rows


def _csv_text(rows: list[dict]) -> str:
    """Header line of column names, then one line per row; floats by ``repr`` (exact; ``nan`` for NaN)."""
    columns = list(rows[0])
    lines = [",".join(columns)]
    lines.extend(",".join(repr(float(row[column])) for column in columns) for row in rows)
    return "\n".join(lines) + "\n"


def _markdown_cell(value: float) -> str:
    return f"{value:.2f}" if math.isfinite(value) else "–"


def _markdown_text(rows: list[dict], quantities, title: str, note: str) -> str:
    """A titled Markdown table: key columns, then ours, paper and ours − paper for each quantity."""
    header, columns = [], []
    for name, label, unit in _KEY_COLUMNS:
        header.append(f"{label} ({unit})")
        columns.append(name)
    for name, label, unit in quantities:
        header += [f"{label} ({unit})", f"{label}, paper ({unit})", f"{label}, ours − paper ({unit})"]
        columns += [name, f"paper_{name}", f"difference_{name}"]
    lines = [f"# {title}", "", note, "", "| " + " | ".join(header) + " |", "|" + "---:|" * len(header)]
    lines.extend("| " + " | ".join(_markdown_cell(row[column]) for column in columns) + " |" for row in rows)
    return "\n".join(lines) + "\n"


def write_tables(results, folder, particle_radius: float | None = None) -> dict[str, Path]:
    """Write Tables 2 and 3 as CSV and Markdown into ``folder``, each file atomically.

    Files: ``table2.csv`` and ``table3.csv`` (the columns of :func:`table_2` / :func:`table_3`, one line per
    case, floats written exactly, ``nan`` for NaN; read with ``np.loadtxt(path, delimiter=",",
    skiprows=1)`` or the ``csv`` module), and ``table2.md`` and ``table3.md`` (a title, a note and one
    table row per case, units in the headers, numbers to 2 decimals, "–" for NaN).

    Args:
      results: ``{(cell_pressure_kpa, membrane_thickness_mm): shear records}`` (see the module docstring).
      folder: output directory, created (with parents) if missing.
      particle_radius: R (m), for Table 3's Δσ3 through the boundary spheres' centres (:func:`table_3`).

    Returns:
      ``{"table2.csv": path, "table2.md": path, "table3.csv": path, "table3.md": path}``.

    Raises:
      ValueError: for bad ``results`` (see the module docstring), or if ``folder`` exists and is not a
        directory or cannot be created.
    """
    rows_2, rows_3 = table_2(results), table_3(results, particle_radius)
    quantities_3 = _table_3_quantities(particle_radius)
    folder = ensure_folder(folder)
    note = (
        "Ours from membrax; paper from Tables 2 and 3 of the paper (– where it has no such case; its "
        "3.3 mm is the 3.33 mm membrane)."
    )
    texts = {
        "table2.csv": _csv_text(rows_2),
        "table2.md": _markdown_text(
            rows_2, _TABLE_2_QUANTITIES, "Table 2: peak mobilised friction angle, external and internal", note
        ),
        "table3.csv": _csv_text(rows_3),
        "table3.md": _markdown_text(
            rows_3, quantities_3, "Table 3: initial stresses and additional membrane stresses", note
        ),
    }
    paths = {}
    for name, text in texts.items():
        paths[name] = folder / name
        atomic_write_bytes(paths[name], text.encode("utf-8"))
    return paths


def _table_3_quantities(particle_radius):
    """Table 3's quantities, with the Δσ3 through the sphere centres when ``particle_radius`` is given."""
    return (*_TABLE_3_QUANTITIES, *((_CENTRES_QUANTITY,) if particle_radius is not None else ()))


# ---------------------------------------------------------------------------------------------------------
# Tables 2 and 3 over several specimens per case (random packings: one per seed)
# ---------------------------------------------------------------------------------------------------------

_SPREAD_STATISTICS = ("mean", "sd", "min", "max")


def spread_tables(results_by_specimen, reference=None, particle_radius: float | None = None) -> dict:
    """Tables 2 and 3 over several specimens of each case: mean, s.d., min and max, beside a reference.

    For each case and quantity of :func:`table_2` / :func:`table_3` over the specimens (e.g. the seeds of
    a random packing), with n specimens of values v_k:

        mean = Σ v_k / n,   sd = √(Σ (v_k − mean)² / (n − 1))  (NaN for n = 1),   min, max

    Args:
      results_by_specimen: ``{specimen label: results}``, each ``results`` as :func:`table_2` takes it
        (``{(cell_pressure_kpa, membrane_thickness_mm): shear records}``); a case missing from some
        specimens (a failed member) is summarised over the others.
      reference: optional ``results`` of the same cases on another packing (the FCC lattice), shown as
        ``reference_{quantity}`` (NaN where it lacks the case).
      particle_radius: as :func:`table_3`.

    Returns:
      ``{"table2": rows, "table3": rows}``: one dict of floats per case, sorted by thickness then pressure,
      with ``cell_pressure_kpa``, ``membrane_thickness_mm``, ``specimens`` (n) and, per quantity ``q``:
      ``q_mean``, ``q_sd``, ``q_min``, ``q_max``, ``reference_q`` and ``paper_q``.

    Raises:
      ValueError: no specimens, or bad ``results`` (see the module docstring).
    """
    if not isinstance(results_by_specimen, Mapping) or not results_by_specimen:
        raise ValueError(
            "results_by_specimen must map a specimen label (e.g. the packing seed) to its results; "
            f"got {results_by_specimen!r:.80}."
        )
    tables = {}
    for name, table, quantities in (
        ("table2", table_2, _TABLE_2_QUANTITIES),
        (
            "table3",
            functools.partial(table_3, particle_radius=particle_radius),
            _table_3_quantities(particle_radius),
        ),
    ):
        per_case: dict[tuple, list[dict]] = {}
        for results in results_by_specimen.values():
            for row in table(results):
                per_case.setdefault((row["cell_pressure_kpa"], row["membrane_thickness_mm"]), []).append(row)
        references = (
            {(r["cell_pressure_kpa"], r["membrane_thickness_mm"]): r for r in table(reference)}
            if reference
            else {}
        )
        rows = []
        for key in sorted(per_case, key=lambda k: (k[1], k[0])):
            specimens = per_case[key]
            row = {"cell_pressure_kpa": key[0], "membrane_thickness_mm": key[1], "specimens": len(specimens)}
            for quantity, _, _ in quantities:
                values = np.array([float(r[quantity]) for r in specimens])
                row[f"{quantity}_mean"] = float(np.mean(values))
                row[f"{quantity}_sd"] = float(np.std(values, ddof=1)) if values.size > 1 else math.nan
                row[f"{quantity}_min"] = float(np.min(values))
                row[f"{quantity}_max"] = float(np.max(values))
                row[f"reference_{quantity}"] = float(references.get(key, {}).get(quantity, math.nan))
                row[f"paper_{quantity}"] = float(specimens[0][f"paper_{quantity}"])
            rows.append(row)
        tables[name] = rows
    return tables


def _spread_cell(row: dict, quantity: str) -> str:
    mean, sd = row[f"{quantity}_mean"], row[f"{quantity}_sd"]
    spread = f" ± {sd:.2f}" if math.isfinite(sd) else ""
    return f"{mean:.2f}{spread} ({row[f'{quantity}_min']:.2f}…{row[f'{quantity}_max']:.2f})"


def _spread_markdown(rows: list[dict], quantities, title: str, note: str, reference_label: str) -> str:
    header = [f"{label} ({unit})" for _, label, unit in _KEY_COLUMNS] + ["specimens"]
    for _, label, unit in quantities:
        header += [
            f"{label}, mean ± s.d. (min…max) ({unit})",
            f"{reference_label} ({unit})",
            f"paper ({unit})",
        ]
    lines = [f"# {title}", "", note, "", "| " + " | ".join(header) + " |", "|" + "---:|" * len(header)]
    for row in rows:
        cells = [_markdown_cell(row[name]) for name, _, _ in _KEY_COLUMNS] + [str(int(row["specimens"]))]
        for quantity, _, _ in quantities:
            cells += [
                _spread_cell(row, quantity),
                _markdown_cell(row[f"reference_{quantity}"]),
                _markdown_cell(row[f"paper_{quantity}"]),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_spread_tables(
    results_by_specimen,
    folder,
    reference=None,
    particle_radius: float | None = None,
    stem: str = "random",
    reference_label: str = "FCC",
) -> dict[str, Path]:
    """Write :func:`spread_tables` as ``{stem}_table2.csv/.md`` and ``{stem}_table3.csv/.md`` in ``folder``.

    The CSV files hold every column of :func:`spread_tables` (exact floats); the Markdown tables show per
    quantity "mean ± s.d. (min…max)" over the specimens, the reference's value (``reference_label``) and
    the paper's, to 2 decimals ("–" for NaN).
    """
    tables = spread_tables(results_by_specimen, reference, particle_radius)
    folder = ensure_folder(folder)
    note = (
        f"Over the specimens of each case (one per seed); {reference_label} from membrax on the lattice of "
        "the same size (– where not run); paper from its Tables 2 and 3 (FCC, paper size)."
    )
    texts = {
        f"{stem}_table2.csv": _csv_text(tables["table2"]),
        f"{stem}_table2.md": _spread_markdown(
            tables["table2"],
            _TABLE_2_QUANTITIES,
            "Table 2 on random specimens: peak mobilised φ'",
            note,
            reference_label,
        ),
        f"{stem}_table3.csv": _csv_text(tables["table3"]),
        f"{stem}_table3.md": _spread_markdown(
            tables["table3"],
            _table_3_quantities(particle_radius),
            "Table 3 on random specimens: initial and additional membrane stresses",
            note,
            reference_label,
        ),
    }
    paths = {}
    for name, text in texts.items():
        paths[name] = folder / name
        atomic_write_bytes(paths[name], text.encode("utf-8"))
    return paths
