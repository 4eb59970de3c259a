"""Make the shipped examples from held-out simulations: the example record and the example series.

Both come from :data:`calibrate.designs.LAB_HELD_OUT`, the members the shipped correction was never fitted
on (seeds 1 and 3, H/D 2, the paper's protocol), read from their archived sweeps in
``data/sweeps/lab_held_out/`` (run, about 15 min a group on 2 CPU cores, where a sweep is missing):

- the example record ``calibrate/data/example_record.csv``: ``g6_medium_held`` at σc 25 kPa in a 4 mm
  membrane of 1400 kPa (ballast-graded, medium-dense, 150 × 300 mm);
- the example series ``calibrate/data/example_series/``: ``e7_medium_held``'s three tests of one specimen
  (equal 25 mm spheres, medium-dense, 175 × 350 mm) in a 4 mm membrane of 1400 kPa at σc 15, 50 and 80 kPa,
  with the series sheet ``series.toml`` that lists them (:mod:`calibrate.series`).

Each member is written by :func:`calibrate.evaluate.write_member_record`: external stresses, with the
internal ones (σ1, the §4.3 σ3 and the received σ3) in columns ``membrax correct`` does not read.

Run: ``python examples/make_examples.py [FOLDER]`` (default ``calibrate/data``; the sweeps of missing
groups run in ``results_examples/``).
"""

import math
import sys
from pathlib import Path

from membrax.devices import split_cpu_devices

split_cpu_devices()

from calibrate import datasets, designs, evaluate, grid  # noqa: E402
from membrax import __version__  # noqa: E402
from membrax.io import read_results  # noqa: E402

RECORD = ("g6_medium_held", {"cell_pressure_kpa": 25.0, "membrane_thickness_mm": 4.0})
SERIES = ("e7_medium_held", {"membrane_thickness_mm": 4.0})
SOURCE = "calibrate.designs.LAB_HELD_OUT"

root = Path(__file__).resolve().parents[1]
out = Path(sys.argv[1]) if len(sys.argv) > 1 else root / "calibrate" / "data"
groups = {name: designs.LAB_HELD_OUT[name] for name in (RECORD[0], SERIES[0])}
paths = dict(
    zip(
        groups,
        grid.run_grid("results_examples", groups, archive=root / "data/sweeps/lab_held_out"),
        strict=True,
    )
)


def members(group, coordinates):
    """The members of ``group``'s sweep at ``coordinates``, in the sweep's order."""
    return [
        (config, rows)
        for config, rows in datasets.sweep_members(read_results(paths[group]))
        if all(math.isclose(config[k], v) for k, v in coordinates.items())
    ]


((config, rows),) = members(*RECORD)
record = evaluate.write_member_record(config, rows, out / "example_record.csv", __version__, SOURCE)
print(f"written {record}")

folder = out / "example_series"
folder.mkdir(parents=True, exist_ok=True)
lines = [
    "# The shipped example series: synthetic tests (membrax simulations), not a laboratory's.",
    "# The specimen's sizes as `membrax correct` takes them: shared where the three tests agree.",
]
tests = {}
for config, rows in members(*SERIES):
    name = f"test_{config['cell_pressure_kpa']:g}kpa.csv"
    path = evaluate.write_member_record(config, rows, folder / name, __version__, SOURCE)
    words = evaluate.example_argv(evaluate.lab.read_lab_record(path).comments)
    tests[name] = {
        flag[2:].replace("-", "_"): value for flag, value in zip(words[::2], words[1::2], strict=True)
    }
for stale in set(p.name for p in folder.glob("test_*.csv")) - set(tests):
    (folder / stale).unlink()
shared = {k: v for k, v in next(iter(tests.values())).items() if all(t.get(k) == v for t in tests.values())}
lines += [f"{key} = {value}" for key, value in shared.items()]
for name, own in tests.items():
    lines += ["", "[[test]]", f'record = "{name}"']
    lines += [f"{key} = {value}" for key, value in own.items() if key not in shared]
(folder / "series.toml").write_text("\n".join(lines) + "\n")
print(f"written to {folder}: " + ", ".join([*tests, "series.toml"]))
