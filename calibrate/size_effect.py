"""The size effect: how far a membrane specimen's internal φ' stands above the material's own.

Contract. A correction maps a membrane specimen's external stresses to its internal ones (the reference
study's §4.3); the internal φ' of a specimen a few particles across is not the material's own, boundary-free
φ'. :data:`BOUNDARY_SPLIT` (``calibrate/data/boundary_split.csv``, written by
``examples/boundary_split.py``) holds, for the same spheres, packing state and σc, the peak and late φ' of
the membrane cell (external, internal, Love–Weber) at D_s/D = 6–12 and of the periodic element (no boundary,
:mod:`membrax.triaxial.periodic`). :func:`size_effects` reads the specimen part, internal − element, of a
state at the table's diameter ratios; :func:`size_effect_note` words it for a specimen of D_s/D (linear in
D/D_s between the table's ratios, never extrapolated), the line ``membrax correct`` reports.

D_s is the specimen's diameter, D the particle size ``membrax correct`` takes
(:func:`membrax.config.characteristic_size_mm`: equal spheres' diameter, a grading's d50); the table is of
equal 25 mm spheres (states ``"dense"``, ``"loose"``) and the ballast grading (``"ballast"``: its 150 mm
mould is 6 largest sieves across, D_s/d50 = 9.3).
"""

from __future__ import annotations

import csv
import functools
import math
from importlib import resources
from typing import NamedTuple

import numpy as np

__all__ = [
    "BOUNDARY_SPLIT",
    "NOMINAL_DIAMETER_TOLERANCE",
    "SizeEffect",
    "boundary_split_rows",
    "size_effect_lines",
    "size_effect_note",
    "size_effects",
]

#: The boundary split's table, shipped with the correction (``examples/boundary_split.py`` writes it).
BOUNDARY_SPLIT = "boundary_split.csv"

#: How far (relative) a specimen's D_s/D may lie outside the table's ratios and still take the nearest: the
#: table's D_s are the moulds' nominal diameters (150–300 mm), and a laboratory gives the diameter after
#: consolidation, which differs from its mould's by up to a few millimetres (the shipped example record:
#: 150.5 mm in a 150 mm mould, +0.3 %).
NOMINAL_DIAMETER_TOLERANCE = 0.02


class SizeEffect(NamedTuple):
    """The specimen part of φ' at one diameter ratio: internal − element, degrees, over the table's σc.

    Attributes:
      state: the packing state of the table's rows (``"dense"``, ``"loose"``, ``"ballast"``).
      diameter_ratio: D_s/D.
      cell_pressures_kpa: the σc it holds, increasing.
      peak_deg: internal − element peak φ' at each σc (mean over the membranes of the table).
      late_deg: the same of the late φ' (the mean over ε_a ≥ 0.8 × the last).
    """

    state: str
    diameter_ratio: float
    cell_pressures_kpa: tuple
    peak_deg: tuple
    late_deg: tuple


@functools.cache
def boundary_split_rows() -> tuple:
    """The rows of :data:`BOUNDARY_SPLIT` as dicts of strings (its header's columns)."""
    text = resources.files("calibrate").joinpath("data", BOUNDARY_SPLIT).read_text()
    return tuple(csv.DictReader(text.splitlines()))


def _value(row, key) -> float:
    text = row.get(key, "")
    return float(text) if text not in ("", None) else math.nan


def size_effects(state: str = "dense", rows=None) -> list[SizeEffect]:
    """The specimen part (internal − element φ') of ``state`` at each diameter ratio of the table.

    Args:
      state: ``"dense"``, ``"loose"`` or ``"ballast"``.
      rows: the table's rows as dicts (default :data:`BOUNDARY_SPLIT`'s).

    Returns:
      One :class:`SizeEffect` per diameter ratio with a membrane cell and a periodic element at the same σc,
      by increasing ratio (empty if none).
    """
    rows = boundary_split_rows() if rows is None else rows
    mine = [row for row in rows if row["state"] == state]
    element = {_value(r, "pressure_kpa"): r for r in mine if r["cell"] == "periodic"}
    by_ratio: dict[float, dict[float, list]] = {}
    for row in mine:
        pressure = _value(row, "pressure_kpa")
        if row["cell"] != "membrane" or pressure not in element:
            continue
        ratio = _value(row, "d_over_ds")
        parts = by_ratio.setdefault(ratio, {}).setdefault(pressure, [])
        parts.append(
            (
                _value(row, "peak_int") - _value(element[pressure], "peak_lw"),
                _value(row, "late_int") - _value(element[pressure], "late_lw"),
            )
        )
    effects = []
    for ratio in sorted(by_ratio):
        pressures = sorted(by_ratio[ratio])
        means = [np.nanmean(np.asarray(by_ratio[ratio][p]), axis=0) for p in pressures]
        effects.append(
            SizeEffect(
                state,
                ratio,
                tuple(pressures),
                tuple(float(m[0]) for m in means),
                tuple(float(m[1]) for m in means),
            )
        )
    return effects


def size_effect_note(diameter_ratio: float, state: str = "dense", rows=None) -> str:
    """A line on the size effect expected at D_s/D = ``diameter_ratio`` for ``state`` (module docstring).

    Within the table's ratios (widened by :data:`NOMINAL_DIAMETER_TOLERANCE` at each end): the specimen
    part's range over σc, linear in D/D_s between the two nearest ratios at the σc they share; outside
    them: that the table has none there.
    """
    effects = [e for e in size_effects(state, rows) if e.cell_pressures_kpa]
    if not effects:
        return f"size effect: the boundary split has no {state} rows (calibrate/data/{BOUNDARY_SPLIT})."
    ratios = [e.diameter_ratio for e in effects]
    span = f"{min(ratios):.3g}" if min(ratios) == max(ratios) else f"{min(ratios):.3g}–{max(ratios):.3g}"
    low_end = min(ratios) * (1.0 - NOMINAL_DIAMETER_TOLERANCE)
    high_end = max(ratios) * (1.0 + NOMINAL_DIAMETER_TOLERANCE)
    if not (low_end <= diameter_ratio <= high_end):
        return (
            f"size effect: none simulated at D_s/D = {diameter_ratio:.3g} ({state} specimens were run at "
            f"D_s/D = {span}, calibrate/data/{BOUNDARY_SPLIT}); how far the internal φ' stands from the "
            "material's own is not known there."
        )
    quoted = diameter_ratio
    diameter_ratio = min(max(diameter_ratio, min(ratios)), max(ratios))  # a nominal end counts as the end
    upper = min(k for k, r in enumerate(ratios) if r >= diameter_ratio)
    lower = max(k for k, r in enumerate(ratios) if r <= diameter_ratio)
    low, high = effects[lower], effects[upper]
    shared = sorted(set(low.cell_pressures_kpa) & set(high.cell_pressures_kpa))
    if high.diameter_ratio == low.diameter_ratio:
        weight = 0.0
    else:  # linear in D/D_s, the boundary's share of the specimen
        weight = (1.0 / diameter_ratio - 1.0 / low.diameter_ratio) / (
            1.0 / high.diameter_ratio - 1.0 / low.diameter_ratio
        )

    def at(field):
        a = dict(zip(low.cell_pressures_kpa, getattr(low, field), strict=True))
        b = dict(zip(high.cell_pressures_kpa, getattr(high, field), strict=True))
        return [(1.0 - weight) * a[p] + weight * b[p] for p in shared]

    peak, late = at("peak_deg"), at("late_deg")
    return (
        f"size effect (simulated, {state}, calibrate/data/{BOUNDARY_SPLIT}): at D_s/D = {quoted:.3g} "
        f"the internal φ' stood {min(peak):+.1f} to {max(peak):+.1f}° from the boundary-free element's at "
        f"the peak and {min(late):+.1f} to {max(late):+.1f}° late (σc {shared[0]:g}–{shared[-1]:g} kPa); "
        "the corrections correct to the internal φ', not to the material's own."
    )


def size_effect_lines(diameter_ratio: float, rows=None) -> list[str]:
    """:func:`size_effect_note` for every state of the table with a periodic element (dense first)."""
    rows = boundary_split_rows() if rows is None else rows
    states = sorted(
        {row["state"] for row in rows if row["cell"] == "periodic"}, key=lambda s: (s != "dense", s)
    )
    return [size_effect_note(diameter_ratio, state, rows) for state in states]
