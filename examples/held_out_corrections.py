"""How close each membrane correction brings φ' to the internal φ' on simulated tests held out of the fit.

Runs the held-out members of a design of :mod:`calibrate.grid` unless their sweeps exist: by default
``LAB_HELD_OUT`` (18 members at a laboratory's H/D = 2 and the paper's protocol, seeds 1 and 3 that no fit
has seen, σc 15–80 kPa, 1.5 and 4 mm membranes, the medium state, the narrow and ballast gradings),
``random_held_out`` (``RANDOM_HELD_OUT``: seed 1 in the shorter moulds of the random grid; about 8 min on 2
cores) or ``fcc_held_out`` (the FCC 7-across members of the first, FCC-fitted correction; about 2 min).

Each member is scored as a user would meet the correction: written as a laboratory record
(:func:`calibrate.evaluate.write_member_record`, external stresses plus the internal ones in columns the
command does not read), corrected by the ``membrax correct`` command from its external columns and the
specimen's sizes, and its output compared with the internal φ' (:func:`calibrate.evaluate.
corrected_csv_errors`), against each internal σ3 the sweep records: the correction's own radial target
with its fitted column, the other with its alternate's. Prints per member the mean and worst
|φ' − φ'_internal| over 0 < ε_a ≤ 10 % for no correction, the three classical corrections and the fitted
one, and per target the members where the fitted one is worse than none (mean, and worst).

Each group's sweep is kept compressed in the repository's ``data/sweeps/<design>/`` (``--archive``;
:func:`calibrate.grid.run_grid`), so a group run once is not run again on another machine.

Run: ``python examples/held_out_corrections.py [FOLDER] [--design lab_held_out|random_held_out|fcc_held_out]
[--model corrections.json] [--archive FOLDER]``.
"""

import argparse
import contextlib
import io
from pathlib import Path

from membrax.devices import split_cpu_devices

split_cpu_devices()

import numpy as np  # noqa: E402

from calibrate import correct, datasets, designs, evaluate, grid, lab, persistence  # noqa: E402
from membrax import __version__, cli  # noqa: E402
from membrax.io import read_results  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
parser.add_argument("folder", nargs="?", default="calibration_held_out")
parser.add_argument(
    "--design", choices=("lab_held_out", "random_held_out", "fcc_held_out"), default="lab_held_out"
)
parser.add_argument("--model", default=None, help="corrections.json (default: the shipped correction)")
parser.add_argument("--archive", default=None, help="the compressed sweeps (default: data/sweeps/DESIGN)")
args = parser.parse_args()
archive = args.archive or Path(__file__).resolve().parents[1] / "data" / "sweeps" / args.design
corrections = (
    correct.default_corrections() if args.model is None else persistence.load_corrections(args.model)
)
groups = designs.DESIGNS[args.design]
paths = grid.run_grid(args.folder, groups, archive=archive)
records = Path(args.folder) / "records"
members = []  # (group, fields, {target: {method: (mean, worst)}})
for name, path in zip(groups, paths, strict=True):
    for config, rows in datasets.sweep_members(read_results(path)):
        label = (
            f"{name}_{config['cell_pressure_kpa']:g}kPa_{config['membrane_thickness_mm']:g}mm_"
            f"{config['membrane_modulus_kpa']:g}kPa"
        )
        record = evaluate.write_member_record(
            config, rows, records / f"{label}.csv", __version__, f"calibrate.grid {args.design}"
        )
        corrected = records / f"{label}_corrected.csv"
        argv = ["correct", str(record), "--out", str(corrected), "--no-plot"]
        comments = lab.read_lab_record(record).comments
        argv += evaluate.example_argv(comments)
        if args.model is not None:
            argv += ["--model", args.model]
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as errors:
            if cli.main(argv) != 0:
                raise SystemExit(f"membrax correct failed on {record}: {errors.getvalue()}")
        fields = {
            k: config[k] for k in ("cell_pressure_kpa", "membrane_thickness_mm", "membrane_modulus_kpa")
        }
        scores = evaluate.corrected_csv_errors(record, corrected, corrections.radial_target)
        columns = evaluate.csv_columns(corrected)
        particle_mm = evaluate.example_arguments(comments)[1]
        fields["ratio"] = (
            fields["membrane_modulus_kpa"]
            * fields["membrane_thickness_mm"]
            / (fields["cell_pressure_kpa"] * particle_mm)
        )
        fields["shrink"] = (columns["fitted_shrink_axial"][0], columns["fitted_shrink_radial"][0])
        members.append((name, fields, scores))

short = {
    "uncorrected": "none",
    "astm": "ASTM",
    "henkel_gilbert": "H&G",
    "kuerbis_vaid": "K&V",
    "fitted": "fitted",
}
for target in datasets.RADIAL_TARGETS:
    scored = [(group, fields, scores[target]) for group, fields, scores in members if target in scores]
    if not scored:
        continue
    which = "its own" if target == corrections.radial_target else "the alternate's"
    print(f"\ninternal σ3 {target!r} (fitted: {which}); |φ' − φ'_internal| (°), mean / worst, 0 < ε_a ≤ 10 %")
    print(
        f"{'group':>18}{'σc kPa':>7}{'t_m mm':>7}{'E_m kPa':>8}{'EtσD':>6}{'w σ1/σ3':>10}"
        + "".join(f"{short[m]:>13}" for m in correct.METHODS)
    )
    for group, fields, errors in scored:
        print(
            f"{group:>18}{fields['cell_pressure_kpa']:7g}{fields['membrane_thickness_mm']:7g}"
            f"{fields['membrane_modulus_kpa']:8g}{fields['ratio']:6.2f}"
            f"{fields['shrink'][0]:6.2f}/{fields['shrink'][1]:.2f}"
            + "".join(f"{errors[m][0]:7.2f}/{errors[m][1]:5.2f}" for m in correct.METHODS)
        )
    pooled = {
        m: (np.mean([e[m][0] for _, _, e in scored]), np.max([e[m][1] for _, _, e in scored]))
        for m in correct.METHODS
    }
    print(f"{'pooled':>56}" + "".join(f"{pooled[m][0]:7.2f}/{pooled[m][1]:5.2f}" for m in correct.METHODS))
    worse_mean = [(g, f) for g, f, e in scored if e["fitted"][0] > e["uncorrected"][0]]
    worse_worst = [(g, f) for g, f, e in scored if e["fitted"][1] > e["uncorrected"][1]]
    print(
        f"fitted worse than none: {len(worse_mean)} of {len(scored)} members on the mean, "
        f"{len(worse_worst)} on the worst error"
    )
    for group, fields in sorted(
        {
            (g, tuple((k, f[k]) for k in ("cell_pressure_kpa", "membrane_thickness_mm")))
            for g, f in worse_mean + worse_worst
        }
    ):
        print(f"  {group} {dict(fields)}")
