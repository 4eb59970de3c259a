"""How close each membrane correction brings φ' to the internal φ' on simulated tests held out of the fit.

Runs the held-out members of a design of :mod:`calibrate.grid` unless their sweeps exist: by default
``RANDOM_HELD_OUT`` (random packings of seed 1, which no fit has seen: ballast-graded dense and loose in a
150 mm mould and equal spheres in a 175 mm one; σc 25/70 kPa, t_m 4 mm, E_m 1000/2000 kPa, off every line of
the random calibration grid; about 8 min on 2 cores), or ``--design fcc_held_out`` (``HELD_OUT``: the FCC
7-across members of the first, FCC-fitted correction; about 2 min). Prints per member and pooled the mean
and worst |φ' − φ'_internal| over 0 < ε_a ≤ 10 % for no correction, the three classical corrections and the
shipped fitted one (or ``--model corrections.json``).

Run: ``python examples/held_out_corrections.py [FOLDER] [--design random_held_out|fcc_held_out]
[--model corrections.json]``.
"""

import argparse

from membrax.devices import split_cpu_devices

split_cpu_devices()

import numpy as np  # noqa: E402

from calibrate import correct, evaluate, grid, persistence  # noqa: E402
from membrax.io import read_results  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
parser.add_argument("folder", nargs="?", default="calibration_held_out")
parser.add_argument("--design", choices=("random_held_out", "fcc_held_out"), default="random_held_out")
parser.add_argument("--model", default=None, help="corrections.json (default: the shipped correction)")
args = parser.parse_args()
corrections = None if args.model is None else persistence.load_corrections(args.model)
paths = grid.run_grid(args.folder, grid.DESIGNS[args.design])
members = []
for name, path in zip(grid.DESIGNS[args.design], paths, strict=True):
    members += [
        (name, *member) for member in evaluate.held_out_errors(read_results(path), corrections)["members"]
    ]
names = {
    "uncorrected": "none",
    "astm": "ASTM",
    "henkel_gilbert": "H&G",
    "kuerbis_vaid": "K&V",
    "fitted": "fitted",
}
print("|φ' − φ'_internal| (°), mean / worst over 0 < ε_a ≤ 10 %")
print(
    f"{'group':>14}{'σc kPa':>7}{'t_m mm':>7}{'E_m kPa':>8}"
    + "".join(f"{names[m]:>13}" for m in correct.METHODS)
)
for group, fields, errors in members:
    print(
        f"{group:>14}{fields['cell_pressure_kpa']:7g}{fields['membrane_thickness_mm']:7g}"
        f"{fields['membrane_modulus_kpa']:8g}"
        + "".join(f"{errors[m][0]:7.2f}/{errors[m][1]:5.2f}" for m in correct.METHODS)
    )
pooled = {
    m: (np.mean([e[m][0] for _, _, e in members]), np.max([e[m][1] for _, _, e in members]))
    for m in correct.METHODS
}
print(f"{'pooled':>36}" + "".join(f"{pooled[m][0]:7.2f}/{pooled[m][1]:5.2f}" for m in correct.METHODS))
