"""How close each membrane correction brings φ' to the internal φ' on simulated tests held out of the fit.

Runs the held-out members of ``calibrate.grid.HELD_OUT`` (7 spheres across, σc 25/70 kPa, t_m 2/4 mm,
E_m 1000/2000 kPa: off every line of the calibration grid; about 2 min on 2 cores) unless their sweep
exists, then prints per member and pooled the mean and worst |φ' − φ'_internal| over 0 < ε_a ≤ 10 % for no
correction, the three classical corrections and the shipped fitted one (or ``--model corrections.json``).

Run: ``python examples/held_out_corrections.py [FOLDER] [--model corrections.json]``.
"""

import argparse

from membrax.devices import split_cpu_devices

split_cpu_devices()

from calibrate import correct, evaluate, grid, persistence  # noqa: E402
from membrax.io import read_results  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
parser.add_argument("folder", nargs="?", default="calibration_held_out")
parser.add_argument("--model", default=None, help="corrections.json (default: the shipped correction)")
args = parser.parse_args()
corrections = None if args.model is None else persistence.load_corrections(args.model)
(path,) = grid.run_grid(args.folder, grid.HELD_OUT)
report = evaluate.held_out_errors(read_results(path), corrections)
names = {
    "uncorrected": "none",
    "astm": "ASTM",
    "henkel_gilbert": "H&G",
    "kuerbis_vaid": "K&V",
    "fitted": "fitted",
}
print("|φ' − φ'_internal| (°), mean / worst over 0 < ε_a ≤ 10 %")
print(f"{'σc kPa':>7}{'t_m mm':>7}{'E_m kPa':>8}" + "".join(f"{names[m]:>13}" for m in correct.METHODS))
for fields, errors in report["members"]:
    print(
        f"{fields['cell_pressure_kpa']:7g}{fields['membrane_thickness_mm']:7g}{fields['membrane_modulus_kpa']:8g}"
        + "".join(f"{errors[m][0]:7.2f}/{errors[m][1]:5.2f}" for m in correct.METHODS)
    )
pooled = report["pooled"]
print(f"{'pooled':>22}" + "".join(f"{pooled[m][0]:7.2f}/{pooled[m][1]:5.2f}" for m in correct.METHODS))
