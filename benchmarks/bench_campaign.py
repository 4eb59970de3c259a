"""A sweep in-process on split CPU devices against the same sweep as Dask tasks on worker processes.

Answers whether one process per core (``--scheduler local``, :mod:`membrax.campaign`) should replace the
split CPU devices (one process, one JAX device per core, :func:`membrax.devices.split_cpu_devices`) as the
default on a CPU. The grid is the paper's Table 1 (``--grid table1``, 9 members) or a group of the
calibration grid (``--grid d6``: 18 members; :data:`calibrate.designs.CALIBRATION`), on the small preset of
``membrax reproduce`` (6 × 10, edge D/3, I = 5e-3, float64). Each mode runs in a fresh process, one
after another:

- ``in-process``: ``run_sweep`` on one device per core (today's default);
- ``dask, default tasks``: ``run_sweep(scheduler="local")``, one worker process per core, each group
  shared evenly over the workers (one task per worker);
- ``dask, 1 member/task``: the same with one member per task (finer balance, one compile per member).

Columns: ``process_s`` the whole process (imports, cluster start); ``sweep_s`` the ``run_sweep`` call;
``busiest_s`` the busiest process's time inside its units (building batches, compiling, simulating: the
``build_s`` + ``run_s`` of each unit); ``overhead_s`` = ``sweep_s`` − ``busiest_s`` (cluster start,
planning, scheduling, the merge, and the idle tail of the less busy process); ``task_s`` the mean time
of one unit; member-steps/s over ``sweep_s``; and the largest difference of the records from the
in-process run's (relative to each variable's largest magnitude): 0 means bit-identical.

Run: ``python benchmarks/bench_campaign.py [--grid table1|d6] [--dtypes float64] [--strain 0.1]``.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = """
import json, sys, time
from pathlib import Path
mode, dtype, grid_name, strain, folder = sys.argv[1:6]
import jax
from membrax.devices import split_cpu_devices
if mode == "in-process":
    split_cpu_devices()
from membrax import sweep
from membrax.config import TriaxialConfig
from membrax.io import read_results
from membrax.reproduce import SIZES
def main():
    fields = {**SIZES["small"], "target_axial_strain": float(strain)}
    if grid_name == "table1":
        grid = None
    else:
        from calibrate.designs import CALIBRATION
        specimen, grid = CALIBRATION[grid_name]
        fields.update(specimen)
    base = TriaxialConfig(**{**fields, "float64": dtype == "float64"})
    start = time.perf_counter()
    if mode == "in-process":
        result = sweep.run_sweep(base, grid, folder, progress=False)
    else:
        per_task = None if mode == "dask" else 1
        result = sweep.run_sweep(
            base, grid, folder, progress=False, scheduler="local", members_per_task=per_task
        )
    seconds = time.perf_counter() - start
    steps = float(result.dataset["consolidation_steps"].sum() + result.dataset["shear_steps"].sum())
    # Each unit's build (specimen, mesh, batch) and run (compiles + chunks) time, per process that ran it.
    units = sorted(Path(folder, "groups").glob("*/task_*")) or sorted(Path(folder, "groups").glob("group_*"))
    busy, compute = {}, 0.0
    for unit in units:
        attrs = read_results(unit / "consolidation_0.nc").attrs
        attempts = unit / "attempts.jsonl"
        pid = json.loads(attempts.read_text().splitlines()[-1])["pid"] if attempts.exists() else 0
        busy[pid] = busy.get(pid, 0.0) + float(attrs["build_s"]) + float(attrs["run_s"])
        compute += float(attrs["build_s"]) + float(attrs["run_s"])
    print(json.dumps({"seconds": seconds, "member_steps": steps, "tasks": len(units),
                      "busiest_s": max(busy.values()), "unit_s": compute / len(units)}))
if __name__ == "__main__":
    main()
"""

COMPARED = ("external_axial_stress", "internal_axial_stress", "internal_radial_stress", "volumetric_strain")


def difference(folder_a: Path, folder_b: Path) -> float:
    """The largest relative difference of the compared records (NaN padding ignored)."""
    import numpy as np
    import xarray as xr

    with xr.open_dataset(folder_a / "sweep.nc") as a, xr.open_dataset(folder_b / "sweep.nc") as b:
        return max(
            float(np.nanmax(np.abs(a[name].values - b[name].values)) / np.nanmax(np.abs(a[name].values)))
            for name in COMPARED
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--grid",
        default="table1",
        help="table1 (the paper's 9 cases) or a group of calibrate.designs.CALIBRATION (d6: 18 members)",
    )
    parser.add_argument("--dtypes", default="float64", help="comma-separated (the presets run float64)")
    parser.add_argument("--strain", type=float, default=0.1, help="target axial strain of every member")
    args = parser.parse_args()
    modes = ("in-process", "dask", "dask-1")
    labels = {"in-process": "in-process", "dask": "dask, default tasks", "dask-1": "dask, 1 member/task"}
    print(f"grid {args.grid} (small preset, to {100 * args.strain:g} % strain); one mode at a time")
    columns = ("dtype", "mode", "tasks", "process_s", "sweep_s", "busiest_s", "overhead_s", "task_s")
    print(f"{columns[0]:>8} {columns[1]:>22}" + "".join(f" {c:>10}" for c in columns[2:]), end="")
    print(f" {'member_steps/s':>15} {'max_rel_diff':>13}")
    with tempfile.TemporaryDirectory() as scratch:
        for dtype in args.dtypes.split(","):
            folders = {}
            for mode in modes:
                folders[mode] = Path(scratch) / f"{dtype}_{mode}"
                started = time.perf_counter()
                child = [mode, dtype, args.grid, str(args.strain), str(folders[mode])]
                done = subprocess.run(
                    [sys.executable, "-c", CHILD, *child],
                    capture_output=True,
                    text=True,
                    check=False,
                )
                if done.returncode != 0:
                    print(done.stderr[-3000:], file=sys.stderr)
                    return 1
                report = json.loads(done.stdout.strip().splitlines()[-1])
                wall = time.perf_counter() - started  # the process: imports included
                rate = report["member_steps"] / report["seconds"]
                diff = difference(folders["in-process"], folders[mode])
                overhead = report["seconds"] - report["busiest_s"]
                cells = (
                    report["tasks"],
                    wall,
                    report["seconds"],
                    report["busiest_s"],
                    overhead,
                    report["unit_s"],
                )
                row = f"{dtype:>8} {labels[mode]:>22} {cells[0]:>10}" + "".join(
                    f" {c:>10.1f}" for c in cells[1:]
                )
                print(f"{row} {rate:>15.0f} {diff:>13.2e}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
