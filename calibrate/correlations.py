"""The paper's correlations tested on a packing family: two regressions, their spread, and a verdict.

Contract. :func:`paper_correlations` takes a :class:`calibrate.datasets.FittingTable` (one packing family's
members, e.g. the FCC reproduction's or the random one's ``sweep.nc`` through
:func:`calibrate.datasets.fitting_table`) and returns, for each of the paper's conclusions (its §5.2 and
§6; Figs 7–9):

- ``initial``: the membrane's extra stresses at zero strain, Δσ_a/σc and Δσ_r/σc of each member's first
  record (the end of consolidation): mean, sample s.d., min, max over the members;
- ``axial``: Δσ_a/σc = k_a · dε_r/dε_a + a₀ (the paper's Fig. 7: the additional axial stress follows the
  change of strain ratio);
- ``radial``: Δσ_r/σc = k_r · h + r₀ with h = 2 E_m t_m (−ε_r)/(D_s σc), Henkel & Gilbert's hoop stress
  ratio (the paper's Fig. 8: the additional radial stress is in proportion to the radial strain).

Each regression is ordinary least squares over every record with finite values
(``scipy.stats.linregress``): slope, intercept, R², the number of records and members. Records of one
member are serially correlated, so the slope's standard error is the jackknife over members,

    se² = (m − 1)/m · Σ_c (k_(−c) − k̄)²,

k_(−c) the slope fitted without member c and k̄ their mean (m members). ``loco_rms`` is the
leave-one-case-out error: each member predicted by the line fitted on the others, the RMS over all
records of the residuals, in σc.

:func:`verdicts` compares a family with a reference family (the paper's FCC lattice) by rules stated in
its docstring, so that "holds", "holds with other coefficients" and "fails" mean the same thing every time.
:func:`write_correlations` writes the table (``correlations.md``, ``correlations.csv``) and a figure
(``correlations.png``: both regressions, each family's records and line).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from scipy import stats

__all__ = ["TARGETS", "paper_correlations", "regression", "verdicts", "write_correlations"]

#: The two regressions: name → (input column, target attribute, the paper's statement).
TARGETS = {
    "axial": ("strain_ratio_change", "axial_target", "Δσ_a/σc follows the change of strain ratio dε_r/dε_a"),
    "radial": ("hoop_ratio", "radial_target", "Δσ_r/σc is in proportion to the radial strain"),
}

#: R² below which a correlation is said to fail, and below which it holds only weakly (:func:`verdicts`).
FAIL_R2 = 0.25
WEAK_R2 = 0.5


def regression(x, y, case) -> dict:
    """Least-squares line y = slope · x + intercept with a jackknife over cases (module docstring).

    Args:
      x: the input per record; records where x or y is not finite are left out.
      y: the target per record.
      case: the member (case) number of each record.

    Returns:
      {"slope", "intercept", "r2", "slope_se", "loco_rms", "records", "members"} (floats and ints; the
      standard error and ``loco_rms`` are NaN with fewer than 3 members).

    Raises:
      ValueError: fewer than 3 usable records or no spread in x.
    """
    x, y, case = (np.asarray(a) for a in (x, y, case))
    keep = np.isfinite(x) & np.isfinite(y)
    x, y, case = x[keep].astype(np.float64), y[keep].astype(np.float64), case[keep]
    if x.size < 3 or np.ptp(x) == 0.0:
        raise ValueError(
            f"{x.size} usable records with x spread {np.ptp(x) if x.size else 0.0:g}: a line needs at "
            "least 3 records with different x (check the sweep has shearing records)."
        )
    line = stats.linregress(x, y)
    members = np.unique(case)
    slope_se, loco_rms = math.nan, math.nan
    if members.size >= 3:
        slopes, squares = [], 0.0
        for member in members:
            held = case == member
            if np.ptp(x[~held]) == 0.0:
                continue
            other = stats.linregress(x[~held], y[~held])
            slopes.append(other.slope)
            squares += float(np.sum((other.slope * x[held] + other.intercept - y[held]) ** 2))
        slopes = np.asarray(slopes)
        m = slopes.size
        slope_se = math.sqrt((m - 1) / m * float(np.sum((slopes - slopes.mean()) ** 2)))
        loco_rms = math.sqrt(squares / x.size)
    return {
        "slope": float(line.slope),
        "intercept": float(line.intercept),
        "r2": float(line.rvalue**2),
        "slope_se": slope_se,
        "loco_rms": loco_rms,
        "records": int(x.size),
        "members": int(members.size),
    }


def _spread(values) -> dict:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return {
        "mean": float(values.mean()),
        "sd": float(values.std(ddof=1)) if values.size > 1 else math.nan,
        "min": float(values.min()),
        "max": float(values.max()),
        "members": int(values.size),
    }


def paper_correlations(table) -> dict:
    """The paper's three conclusions measured on one family's fitting table (module docstring).

    Returns:
      {"initial": {"axial": spread, "radial": spread}, "axial": regression, "radial": regression}.
    """
    initial = np.asarray(table.initial, dtype=bool)
    result = {
        "initial": {
            "axial": _spread(np.asarray(table.axial_target)[initial]),
            "radial": _spread(np.asarray(table.radial_target)[initial]),
        }
    }
    for name, (column, target, _) in TARGETS.items():
        result[name] = regression(table.inputs[column], getattr(table, target), table.case)
    return result


def verdicts(family: Mapping, reference: Mapping | None = None) -> dict:
    """Whether each of the paper's conclusions holds on ``family``, judged against ``reference`` (FCC).

    Rules (R² and slopes from :func:`paper_correlations`; intervals slope ± 2 se):

    - zero strain, axial and radial apart: "holds" when the family's mean initial Δσ/σc is positive (the
      paper's Table 3: the specimen carries more than the cell and ram apply) by more than 2 standard
      errors (s.d./√members); "fails" otherwise;
    - each regression: "fails" when R² < 0.25 or the slope's sign differs from the reference's; "holds
      weakly" when R² < 0.5; otherwise "holds" when the slope intervals overlap, and "holds with other
      coefficients" when they do not.

    Without ``reference`` the family is judged on its own: the sign and slope comparisons are dropped.

    Returns:
      {"initial_axial" | "initial_radial" | "axial" | "radial": (verdict, reason)}.
    """
    out = {}
    for side in ("axial", "radial"):
        ours = family["initial"][side]
        error = ours["sd"] / math.sqrt(ours["members"]) if math.isfinite(ours["sd"]) else math.inf
        reason = f"{ours['mean']:+.3f} ± {ours['sd']:.3f} over {ours['members']} members"
        if reference is not None:
            reason += f" (reference {reference['initial'][side]['mean']:+.3f})"
        out[f"initial_{side}"] = ("holds" if ours["mean"] > 2.0 * error else "fails", reason)
    for name in TARGETS:
        ours = family[name]
        reason = f"slope {ours['slope']:.3f} ± {ours['slope_se']:.3f}, R² {ours['r2']:.2f}"
        flipped = False
        if reference is not None:
            theirs = reference[name]
            reason += f" (reference {theirs['slope']:.3f} ± {theirs['slope_se']:.3f}, R² {theirs['r2']:.2f})"
            flipped = bool(np.sign(ours["slope"]) != np.sign(theirs["slope"]))
        if ours["r2"] < FAIL_R2 or flipped:
            verdict = "fails"
        elif ours["r2"] < WEAK_R2:
            verdict = "holds weakly"
        elif reference is None:
            verdict = "holds"
        else:
            gap = abs(ours["slope"] - theirs["slope"])
            reach = 2.0 * (np.nan_to_num(ours["slope_se"]) + np.nan_to_num(theirs["slope_se"]))
            verdict = "holds" if gap <= reach else "holds with other coefficients"
        out[name] = (verdict, reason)
    return out


def _rows(results: Mapping) -> list[dict]:
    rows = []
    for family, result in results.items():
        row = {"family": family}
        for side in ("axial", "radial"):
            for key, value in result["initial"][side].items():
                row[f"initial_{side}_{key}"] = value
        for name in TARGETS:
            for key, value in result[name].items():
                row[f"{name}_{key}"] = value
        rows.append(row)
    return rows


def write_correlations(tables: Mapping, folder, reference: str | None = None) -> dict:
    """Measure :func:`paper_correlations` per family and write the table and the figure into ``folder``.

    Args:
      tables: {family label: FittingTable}, e.g. {"FCC": ..., "random": ...}.
      folder: output folder (created).
      reference: the family the others are judged against (:func:`verdicts`); default the first.

    Returns:
      {"results": {family: paper_correlations}, "verdicts": {family: verdicts} (the reference's on its
      own),
      "files": {"correlations.md", "correlations.csv", "correlations.png": paths}}.
    """
    from membrax.io.files import atomic_write_bytes, ensure_folder

    if not tables:
        raise ValueError("tables is empty; give {family: FittingTable}, e.g. {'FCC': ..., 'random': ...}.")
    folder = ensure_folder(folder)
    results = {family: paper_correlations(table) for family, table in tables.items()}
    reference = reference or next(iter(results))
    judged = {
        family: verdicts(result, None if family == reference else results[reference])
        for family, result in results.items()
    }
    rows = _rows(results)
    columns = list(rows[0])
    csv = [",".join(columns)] + [
        ",".join(str(row[c]) if isinstance(row[c], str) else repr(float(row[c])) for c in columns)
        for row in rows
    ]
    lines = [
        "# The paper's correlations by packing family",
        "",
        "Initial: Δσ/σc at the end of consolidation, mean ± s.d. (min…max) over members. Regressions over "
        "every shearing record: slope ± jackknife s.e. over members, intercept, R², leave-one-case-out RMS "
        "(σc).",
        "",
        "| family | members | initial Δσ_a/σc | initial Δσ_r/σc | k_a (Δσ_a/σc on dε_r/dε_a) | a₀ | R² "
        "| LOCO RMS | k_r (Δσ_r/σc on hoop ratio) | r₀ | R² | LOCO RMS |",
        "|---|" + "---:|" * 11,
    ]
    for family, result in results.items():
        cells = [family, str(result["axial"]["members"])]
        for side in ("axial", "radial"):
            s = result["initial"][side]
            cells.append(f"{s['mean']:+.3f} ± {s['sd']:.3f} ({s['min']:+.3f}…{s['max']:+.3f})")
        for name in TARGETS:
            r = result[name]
            cells += [
                f"{r['slope']:.3f} ± {r['slope_se']:.3f}",
                f"{r['intercept']:+.3f}",
                f"{r['r2']:.2f}",
                f"{r['loco_rms']:.3f}",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Verdicts, {reference} on its own and the others against it (rules: "
        "`calibrate.correlations.verdicts`):",
        "",
    ]
    statements = {
        "initial_axial": "extra axial stress at zero strain",
        "initial_radial": "extra radial stress at zero strain",
        **{k: v[2] for k, v in TARGETS.items()},
    }
    for family, verdict in judged.items():
        for name, (word, reason) in verdict.items():
            lines.append(f"- {family}, {statements[name]}: **{word}** — {reason}")
    files = {
        "correlations.md": folder / "correlations.md",
        "correlations.csv": folder / "correlations.csv",
    }
    atomic_write_bytes(files["correlations.md"], ("\n".join(lines) + "\n").encode("utf-8"))
    atomic_write_bytes(files["correlations.csv"], ("\n".join(csv) + "\n").encode("utf-8"))
    files["correlations.png"] = _figure(tables, results, folder / "correlations.png")
    return {"results": results, "verdicts": judged, "files": files}


def _figure(tables: Mapping, results: Mapping, path: Path) -> Path:
    # A Figure without pyplot: no backend switched in the caller's session (as membrax.plots).
    from matplotlib.figure import Figure

    figure = Figure(figsize=(11, 4.5), layout="constrained")
    axes = figure.subplots(1, 2)
    labels = {
        "axial": ("dε_r/dε_a", "Δσ_a/σc"),
        "radial": ("hoop ratio 2 E_m t_m (−ε_r)/(D_s σc)", "Δσ_r/σc"),
    }
    for axis, (name, (column, target, statement)) in zip(axes, TARGETS.items(), strict=True):
        for k, (family, table) in enumerate(tables.items()):
            x = np.asarray(table.inputs[column])
            y = np.asarray(getattr(table, target))
            color = f"C{k}"
            axis.plot(x, y, ".", ms=2, alpha=0.3, color=color)
            r = results[family][name]
            span = np.linspace(np.nanmin(x), np.nanmax(x), 2)
            axis.plot(
                span,
                r["slope"] * span + r["intercept"],
                color=color,
                label=f"{family}: slope {r['slope']:.3f}, R² {r['r2']:.2f}",
            )
        axis.set_xlabel(labels[name][0])
        axis.set_ylabel(labels[name][1])
        axis.set_title(statement, fontsize=9)
        axis.legend(fontsize=8)
    figure.savefig(path, dpi=120)
    return path
