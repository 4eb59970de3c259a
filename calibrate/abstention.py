"""When the fitted correction abstains: a shrinkage toward no correction, fitted on cross-validation.

Contract. :func:`fit_rule` takes a :class:`calibrate.datasets.FittingTable` and the model's
cross-validated predictions on it (each case predicted by a fit without it,
:func:`calibrate.fit.cross_validated_predictions`) and returns the rule, a JSON-ready dict that
:func:`calibrate.persistence.save_corrections` stores with the correction. :func:`record_shrink` looks a
laboratory record up in it; :mod:`calibrate.correct` applies it.

The rule. The cases are binned by the membrane's stiffness against the cell pressure, E_m t_m/(σc D)
(``stiffness_ratio``), in octaves [2^k, 2^(k+1)) — the membrane's share of the stresses halves from one
region to the next down (the hoop stress over σc is 2 (E_m t_m/(σc D)) (D/D_s) (−ε_r)) — keeping the
octaves that hold a case. In each region, and for each stress separately (Δσ_a/σc, Δσ_r/σc), the
correction is multiplied by a factor w chosen among three candidates, the one whose error on cases it was
not fitted on is least:

- 1, the fitted correction: its leave-one-case-out error;
- 0, no correction: its error (nothing fitted);
- w* = clip(Σ_c ⟨p t⟩_c / Σ_c ⟨p²⟩_c, 0, 1), the least-squares shrinkage of the cross-validated prediction
  p toward zero (t the target, ⟨·⟩_c the mean over case c's readings, so that each simulated test counts
  once, as a laboratory record does, whatever its number of readings): its error with each case's w*
  refitted without that case (from the rest of its region or, for a region of one case, the nearest
  other region's).

Errors are RMS over the region's cases of each case's mean square, in Δσ/σc. No correction is the
default: a correction (1 or w*) is chosen only where it beats none by more than one standard error of the
paired difference of the cases' mean squares (the one-standard-error rule of model selection: Breiman et
al. 1984, *Classification and Regression Trees* §3.4.3; Hastie, Tibshirani & Friedman 2009, *The Elements
of Statistical Learning* §7.10), and among those that do, the one erring least (a tie to the larger
factor). Choosing the least of three errors measured on the same few cases is optimistic, and where all
three are within noise of each other that optimism picks a factor that helps in sample only; the rule
gives the benefit of the doubt to no correction, so a region of one case (no standard error) abstains.
Since no correction is a candidate, in each region the chosen factor errs, on cases it was not fitted
on, no more than no correction: never worse than none, by construction. The shrinkage is only
taken where it beats the correction on unseen cases, so a w* that fits the noise of a few cases (on the
random grid's table, σ3 in 32–64: w* = 0.89 in sample, worse than unshrunk out of it) is not applied; w* is
clipped at 1 because amplifying the model would be a new fitted term, not an abstention.

Why per stress: φ' depends on both, sin φ' = (σ1 − σ3)/(σ1 + σ3); linearised with σ3 ≈ σc and R = σ1/σ3,
δφ' = (δσ1/σc − R δσ3/σc)/(√R (R + 1)) rad: the two stresses' errors combined, σ3's weighted by R, which
the fitting table does not hold (it keeps Δσ/σc, not σ1). A correction no worse than none in each stress
is what can be guaranteed without R (not a bound on φ' itself: the two errors can add or cancel, and do
either for a correction and for none alike); on the shipped table the two behave differently (in
E_m t_m/(σc D) 2–4 the σ1 correction is shrunk to 0.64, the σ3 one kept at 0.89, where it cuts none's error
fourfold), so one shared factor would give up a good σ3 correction with a bad σ1 one.

Stored per region and stress: ``weight`` (the chosen w), ``shrinkage`` (w*), ``none_rms``, ``fitted_rms``,
``shrunk_rms`` (w* in sample), ``held_out_rms`` (w* refitted without each case), ``fitted_gain`` and
``held_out_gain`` (the mean over the cases of none's mean square minus the candidate's, in (Δσ/σc)²)
with their standard errors ``fitted_gain_se`` and ``held_out_gain_se``, and ``rms``, the chosen factor's
error on unseen cases, which is the band's prediction error where the rule shrinks
(:mod:`calibrate.correct`).

Per record, not per reading: a record's region is that of its median E_m t_m/(σc D) (constant in a test at
constant cell pressure), so one test gets one decision, which a laboratory can act on, and a cell
pressure logged with noise at an octave's edge does not flip it from reading to reading. A record outside
every region takes the nearest one (in logarithms).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

__all__ = ["QUANTITY", "TARGETS", "fit_rule", "main", "record_shrink", "region_of", "rule_lines"]

#: The dimensionless group the regions bin (:data:`calibrate.datasets.INPUTS`).
QUANTITY = "stiffness_ratio"
#: The two corrected stresses, in the order of the model's predictions: Δσ_a/σc, Δσ_r/σc.
TARGETS = ("axial", "radial")
KIND = (
    "per octave of E_m t_m/(σc D) and per stress, 0 unless 1 or the least-squares shrinkage toward none "
    "beats it by more than one standard error on leave-one-case-out errors; then the one erring least"
)


def _case_sums(table, predictions):
    """Per case: its E_m t_m/(σc D), and per target the mean over its finite readings of p·t, p², t²."""
    cases = np.unique(table.case)
    value = np.asarray(table.inputs[QUANTITY], dtype=np.float64)
    sums = np.zeros((cases.size, 2, 3))
    counts = np.zeros((cases.size, 2))
    levels = np.full(cases.size, np.nan)
    targets = (table.axial_target, table.radial_target)
    for i, case in enumerate(cases):
        rows = table.case == case
        levels[i] = np.nanmedian(value[rows])
        for k in range(2):
            p, t = np.asarray(predictions[k], np.float64)[rows], np.asarray(targets[k], np.float64)[rows]
            finite = np.isfinite(p) & np.isfinite(t)
            counts[i, k] = np.sum(finite)
            if counts[i, k]:
                p, t = p[finite], t[finite]
                sums[i, k] = (np.mean(p * t), np.mean(p * p), np.mean(t * t))
    return levels, sums, counts


def _weight(pt: float, pp: float) -> float:
    """clip(Σpt/Σp², 0, 1); 1 where there is nothing to shrink (Σp² = 0)."""
    return 1.0 if pp <= 0.0 else float(min(max(pt / pp, 0.0), 1.0))


def _mean_square(weight, sums):
    """⟨(w p − t)²⟩ from ⟨pt⟩, ⟨p²⟩, ⟨t²⟩ (rounding can take it a hair below 0)."""
    pt, pp, tt = sums[..., 0], sums[..., 1], sums[..., 2]
    return np.maximum(weight * weight * pp - 2.0 * weight * pt + tt, 0.0)


def _gain(none, candidate) -> tuple[float, float]:
    """Mean over cases of none's mean square minus the candidate's, and its standard error (∞ if one)."""
    difference = np.asarray(none) - np.asarray(candidate)
    if difference.size < 2:
        return (float(np.mean(difference)) if difference.size else math.nan), math.inf
    return float(np.mean(difference)), float(np.std(difference, ddof=1) / math.sqrt(difference.size))


def fit_rule(table, axial_prediction, radial_prediction) -> dict:
    """The abstention rule of a correction from its cross-validated predictions (module docstring).

    Args:
      table: the :class:`calibrate.datasets.FittingTable` the correction was fitted on.
      axial_prediction: Δσ_a/σc of each row, predicted by a fit that did not see the row's case.
      radial_prediction: Δσ_r/σc of each row, likewise.

    Returns:
      {"quantity", "kind", "regions": [{"low", "high", "cases", "axial": {...}, "radial": {...}}]}, each
      stress's entry {"weight", "shrinkage", "none_rms", "fitted_rms", "shrunk_rms", "held_out_rms",
      "fitted_gain", "fitted_gain_se", "held_out_gain", "held_out_gain_se", "rms"} (module docstring;
      errors in Δσ/σc).

    Raises:
      ValueError: predictions of another length than the table, or no case with a positive finite
        E_m t_m/(σc D).
    """
    predictions = (np.asarray(axial_prediction), np.asarray(radial_prediction))
    if any(p.shape != (table.num_rows,) for p in predictions):
        raise ValueError(
            f"predictions of shapes {[p.shape for p in predictions]} for a table of {table.num_rows} rows; "
            "give one cross-validated prediction per row (calibrate.fit.cross_validated_predictions)."
        )
    values, sums, counts = _case_sums(table, predictions)
    usable = np.isfinite(values) & (values > 0.0) & np.any(counts > 0, axis=1)
    if not np.any(usable):
        raise ValueError(f"no case with a positive finite {QUANTITY}: the rule needs one.")
    octave = np.where(usable, np.floor(np.log2(np.where(usable, values, 1.0))), np.nan)
    levels = np.unique(octave[usable]).astype(int)
    # Region sums: each case's means, so that each case counts once.
    region_sums = np.stack([np.sum(sums[octave == level], axis=0) for level in levels])
    weights = np.vectorize(_weight)(region_sums[..., 0], region_sums[..., 1])  # (regions, 2)
    held = np.full(sums.shape[:2], np.nan)  # each case's mean square with its w refitted without it
    for i in np.flatnonzero(usable):
        r = int(np.searchsorted(levels, octave[i]))
        alone = np.sum(octave == octave[i]) == 1
        if alone and levels.size > 1:
            # the nearest other region's w (its sums do not hold this case)
            others = np.delete(np.arange(levels.size), r)
            near = others[np.argmin(np.abs(levels[others] - levels[r]))]
            w = weights[near]
        elif alone:
            w = np.ones(2)
        else:
            rest = region_sums[r] - sums[i]
            w = np.array([_weight(rest[k, 0], rest[k, 1]) for k in range(2)])
        held[i] = _mean_square(w, sums[i])
    regions = []
    for r, level in enumerate(levels):
        members = octave == level
        region = {"low": 2.0**level, "high": 2.0 ** (level + 1), "cases": int(np.sum(members))}
        for k, target in enumerate(TARGETS):
            rows = members & (counts[:, k] > 0)

            def rms(values, rows=rows):
                return float(math.sqrt(np.mean(values[rows]))) if np.any(rows) else math.nan

            none = sums[:, k, 2]
            fitted = _mean_square(1.0, sums[:, k])
            scores = {
                "none_rms": rms(none),
                "fitted_rms": rms(fitted),
                "shrunk_rms": rms(_mean_square(weights[r, k], sums[:, k])),
                "held_out_rms": rms(held[:, k]),
            }
            for name, errors in (("fitted", fitted), ("held_out", held[:, k])):
                scores[f"{name}_gain"], scores[f"{name}_gain_se"] = _gain(none[rows], errors[rows])
            # No correction unless one beats it by more than a standard error; then the least error on
            # unseen cases, ties to the larger factor (listed first).
            candidates = [
                (factor, scores[f"{name}_rms"])
                for factor, name in ((1.0, "fitted"), (float(weights[r, k]), "held_out"))
                if scores[f"{name}_gain"] > scores[f"{name}_gain_se"]
            ]
            weight, error = min(candidates or [(0.0, scores["none_rms"])], key=lambda candidate: candidate[1])
            region[target] = {"weight": weight, "shrinkage": float(weights[r, k]), "rms": error, **scores}
        regions.append(region)
    return {"quantity": QUANTITY, "kind": KIND, "regions": regions}


def region_of(rule: dict, value: float) -> dict:
    """The region of ``rule`` holding ``value`` of E_m t_m/(σc D), or the nearest in logarithms."""
    regions = rule["regions"]
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"{QUANTITY} = {value!r}: the rule needs a positive finite value.")
    x = math.log(value)

    def distance(region):
        return max(math.log(region["low"]) - x, x - math.log(region["high"]), 0.0)

    inside = [region for region in regions if region["low"] <= value < region["high"]]
    return inside[0] if inside else min(regions, key=distance)


def record_shrink(rule: dict | None, stiffness_ratio) -> tuple[float, float, dict | None]:
    """(w for Δσ_a, w for Δσ_r, the region) of a record from its readings' E_m t_m/(σc D).

    The record's value is the median of its finite readings (module docstring). No rule (a correction
    written before rules were stored), or no finite reading, gives (1, 1, None): nothing shrunk.
    """
    values = np.asarray(stiffness_ratio, dtype=np.float64)
    values = values[np.isfinite(values) & (values > 0.0)]
    if not rule or not rule.get("regions") or values.size == 0:
        return 1.0, 1.0, None
    region = region_of(rule, float(np.median(values)))
    return float(region["axial"]["weight"]), float(region["radial"]["weight"]), region


def rule_lines(rule: dict) -> list[str]:
    """The rule as ``membrax fit`` reports it: per region and stress, w and the RMS errors (Δσ/σc)."""
    lines = [
        "when the correction abstains: its σ1 and σ3 corrections scaled by w per octave of E_m t_m/(σc D), "
        "w = 0 unless 1 or the least-squares shrinkage w* beat it by more than one standard error on unseen "
        "cases, then whichever erred least; RMS in Δσ/σc of none / fitted / shrunk by w*:"
    ]
    for region in rule["regions"]:
        cells = [
            f"{symbol} w {region[target]['weight']:.2f} (w* {region[target]['shrinkage']:.2f}; "
            f"{region[target]['none_rms']:.3f} / {region[target]['fitted_rms']:.3f} / "
            f"{region[target]['held_out_rms']:.3f})"
            for symbol, target in (("σ1", "axial"), ("σ3", "radial"))
        ]
        lines.append(f"  {region['low']:g}–{region['high']:g} ({region['cases']} cases): " + "; ".join(cells))
    return lines


def main(argv=None) -> int:
    """``python -m calibrate.abstention TABLE CORRECTIONS [--design NAME]``: add the rule to a correction.

    Refits leave-one-case-out on the fitting table (``membrax fit --table``), checks that the predictions
    reproduce the per-case errors stored in the correction (the same fit, so the same rule ``membrax fit``
    would have stored), fits the rule and writes it into the JSON, with the specimens' H/D_s range from
    the sweeps' groups in the design (:func:`calibrate.designs.mould_aspect_ratios`) when the file has none.

    Returns the exit status: 0, or 2 for predictions that do not reproduce the stored errors.
    """
    from pathlib import Path

    from calibrate import datasets, designs, fit, persistence

    parser = argparse.ArgumentParser(
        prog="python -m calibrate.abstention", description=main.__doc__.split("\n")[0]
    )
    parser.add_argument("table", help="the fitting table (.npz) the correction was fitted on")
    parser.add_argument("corrections", help="the corrections JSON to amend")
    parser.add_argument(
        "--design", choices=sorted(designs.DESIGNS), default="random", help="the sweeps' design"
    )
    args = parser.parse_args(argv)
    table = datasets.load_table(args.table)
    corrections = persistence.load_corrections(args.corrections)
    start = time.perf_counter()
    predictions = fit.cross_validated_predictions(corrections.model, table)
    seconds = time.perf_counter() - start
    scores = fit.cross_validate(corrections.model, table, predictions)
    stored = corrections.provenance.get("cross_validation")
    if stored:
        for target in TARGETS:
            mine = np.array([score[target] for score in scores.values()])
            theirs = np.asarray(stored[f"{target}_rms"], dtype=np.float64)
            if mine.shape != theirs.shape or not np.allclose(mine, theirs, rtol=1e-6, atol=1e-9):
                print(
                    f"the leave-one-case-out {target} errors on {args.table} differ from those stored in "
                    f"{args.corrections}: it was not fitted on this table; refit with membrax fit.",
                    file=sys.stderr,
                )
                return 2
    rule = fit_rule(table, *predictions)
    aspect = None
    if persistence.ASPECT_RATIO not in corrections.input_ranges:
        ratios = designs.mould_aspect_ratios(designs.DESIGNS[args.design])
        groups = [Path(sweep).parent.name for sweep in corrections.provenance.get("sweeps", ())]
        found = [ratios[group] for group in groups if group in ratios]
        aspect = (min(found), max(found)) if found else None
    persistence.amend_corrections(args.corrections, aspect_ratio=aspect, abstention=rule)
    print(f"leave-one-case-out predictions of {table.num_cases} cases: {seconds:.0f} s")
    print("\n".join(rule_lines(rule)))
    if aspect is not None:
        print(f"H/D_s of the {args.design} design's moulds: {aspect[0]:.3g}–{aspect[1]:.3g}")
    print(f"written to {args.corrections}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
