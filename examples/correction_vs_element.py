"""The shipped correction scored two ways: against the internal φ' it was fitted to, and the material's own.

A correction maps a membrane specimen's external stresses to its internal ones; the internal φ' of a
specimen 6–12 particles across is not the boundary-free material's (``examples/boundary_split.py``). This
script corrects every member of the laboratory grid's membrane cells (``--lab``: its archive, the
repository's ``data/sweeps/lab``, or a run folder; the groups of ``--groups`` that have run; the shipped
correction was fitted on them, so its internal scores are in sample: ``--model`` scores another) by every
method of ``membrax correct`` (:func:`calibrate.evaluate.element_errors`) and compares each method's peak
and late φ' (the mean over ε_a ≥ 8 %) with the member's internal ones and with the periodic element's at
the same state and σc (``calibrate/data/boundary_split.csv``). Prints, per group and pooled, the mean
|error| and the mean signed error (a correction that removes only the membrane leaves the specimen's part
as a positive bias against the element).

Run: ``python examples/correction_vs_element.py [--lab data/sweeps/lab] [--groups e6_h25,e8,...]
[--state dense] [--model corrections.json]``; a minute on 2 cores (no simulation).
"""

import argparse
from pathlib import Path

import numpy as np

from calibrate import correct, evaluate, persistence
from calibrate.grid import find_sweep
from calibrate.size_effect import boundary_split_rows
from membrax.io import read_results

parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
parser.add_argument(
    "--lab",
    default=str(Path(__file__).resolve().parents[1] / "data" / "sweeps" / "lab"),
    help="the laboratory grid's sweeps: its archive or its run folder",
)
parser.add_argument("--groups", default="e6,e6_h25,e8,e10,e12", help="group names (seeds _s0, _s2 read)")
parser.add_argument("--state", default="dense", help="the element rows' state in the boundary split table")
parser.add_argument("--model", default=None, help="corrections.json (default: the shipped correction)")
args = parser.parse_args()

corrections = (
    correct.default_corrections() if args.model is None else persistence.load_corrections(args.model)
)
element = {
    float(row["pressure_kpa"]): (float(row["peak_lw"]), float(row["late_lw"]))
    for row in boundary_split_rows()
    if row["state"] == args.state and row["cell"] == "periodic"
}
if not element:
    raise SystemExit(f"calibrate/data/boundary_split.csv has no periodic {args.state} rows.")
print(
    f"element ({args.state}): "
    + ", ".join(f"{p:g} kPa peak {a:.2f}°, late {b:.2f}°" for p, (a, b) in element.items())
)

found, scored = [], []
for group in args.groups.split(","):
    for seed in (0, 2):
        path = find_sweep(args.lab, f"{group}_s{seed}")
        if path is None:
            continue
        found.append(f"{group}_s{seed}")
        for fields, errors in evaluate.element_errors(read_results(path), element, corrections)["members"]:
            scored.append((group, seed, fields, errors))
print(f"groups: {', '.join(found) or 'none'}; {len(scored)} members")
if not scored:
    raise SystemExit("no member to score.")

KEYS = ("peak_internal", "peak_element", "late_internal", "late_element")
print(
    "\nmean |φ'_method − φ'_target| (mean signed), degrees; targets: internal φ' and the periodic element's"
)
print(f"{'method':>16}" + "".join(f"{key:>22}" for key in KEYS))
for method in correct.METHODS:
    cells = []
    for key in KEYS:
        values = np.array([errors[method][key] for *_, errors in scored])
        cells.append(f"{np.mean(np.abs(values)):10.2f} ({np.mean(values):+6.2f})")
    print(f"{method:>16}" + "".join(f"{cell:>22}" for cell in cells))

print("\nper member, fitted and none: peak error against internal / element, degrees")
for group, seed, fields, errors in scored:
    print(
        f"{group}_s{seed} {fields['cell_pressure_kpa']:5g} kPa {fields['membrane_thickness_mm']:g} mm: "
        f"fitted {errors['fitted']['peak_internal']:+.2f} / {errors['fitted']['peak_element']:+.2f}, "
        f"none {errors['uncorrected']['peak_internal']:+.2f} / {errors['uncorrected']['peak_element']:+.2f}"
    )
