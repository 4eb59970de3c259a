"""Make the shipped example series: three simulated tests of one specimen at three cell pressures.

Runs the ballast-graded dense random specimen of the shipped example record (seed 1, which no fit has
seen; 150 × 250 mm mould, the calibration grid's small protocol) in a 4 mm membrane of 2000 kPa at σc 25,
50 and 80 kPa, and writes each member as a laboratory record (:func:`calibrate.evaluate.write_member_record`:
external stresses, with the internal ones in columns ``membrax correct`` does not read) into
``calibrate/data/example_series/`` with the series sheet ``series.toml`` that lists them
(:mod:`calibrate.series`). About 10 min on 2 CPU cores.

Run: ``python examples/make_example_series.py [FOLDER]`` (the sweep is kept in ``results_example_series/``).
"""

import sys
from pathlib import Path

from membrax.devices import split_cpu_devices

split_cpu_devices()

from calibrate import datasets, designs, evaluate  # noqa: E402
from membrax import __version__  # noqa: E402
from membrax.config import TriaxialConfig  # noqa: E402
from membrax.io import read_results  # noqa: E402
from membrax.sweep import run_sweep  # noqa: E402

PRESSURES_KPA = (25.0, 50.0, 80.0)
SPECIMEN = {"mould": (150.0, 250.0), "grading": "ballast", "seed": 1}
MEMBRANE = {"membrane_thickness_mm": 4.0, "membrane_modulus_kpa": 2000.0}

out = (
    Path(sys.argv[1])
    if len(sys.argv) > 1
    else Path(__file__).resolve().parents[1] / "calibrate/data/example_series"
)
sweep = Path("results_example_series")
base = TriaxialConfig(name="example_series", **designs.specimen_fields(SPECIMEN), **MEMBRANE)
run_sweep(base, {"cell_pressure_kpa": list(PRESSURES_KPA)}, sweep, resume=sweep.exists())
lines = [
    "# The shipped example series: synthetic tests (membrax simulations), not a laboratory's.",
    "# The specimen's sizes as `membrax correct` takes them: shared where the three tests agree.",
]
tests = {}
for config, rows in datasets.sweep_members(read_results(sweep / "sweep.nc")):
    name = f"test_{config['cell_pressure_kpa']:g}kpa.csv"
    path = evaluate.write_member_record(
        config, rows, out / name, __version__, "examples/make_example_series.py"
    )
    words = evaluate.example_argv(evaluate.lab.read_lab_record(path).comments)
    tests[name] = {
        flag[2:].replace("-", "_"): value for flag, value in zip(words[::2], words[1::2], strict=True)
    }
shared = {k: v for k, v in next(iter(tests.values())).items() if all(t.get(k) == v for t in tests.values())}
lines += [f"{key} = {value}" for key, value in shared.items()]
for name, own in tests.items():
    lines += ["", "[[test]]", f'record = "{name}"']
    lines += [f"{key} = {value}" for key, value in own.items() if key not in shared]
(out / "series.toml").write_text("\n".join(lines) + "\n")
print(f"written to {out}: " + ", ".join([*tests, "series.toml"]))
