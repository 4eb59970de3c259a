"""Speed of the calibration half: the default fit, cross-validation, and ``membrax correct`` on 1,000 rows.

Prints one row per dtype the step runs in (the fit and the corrections run in float64, scoped to their
call; there is no float32 path), with:

- ``fit (s)``: the shipped default model (``calibrate/data/default_corrections.json``) fitted on the
  shipped calibration table (``calibrate/data/calibration_table.npz``, the fitting table of
  ``calibrate.designs.LAB_CALIBRATION``), first call including compilation; ``warm (s)``, the second call;
- ``loo (s)``: the leave-one-case-out cross-validation (one fit per case);
- ``nm evals`` / ``optax evals``: loss evaluations of scipy's Nelder–Mead and of Adam + L-BFGS;
- ``correct (s)``: ``calibrate.report.correct_file`` on a 1,000-row record (the shipped example record
  interpolated), CSV and plot written, in-process and first call; ``command (s)``: the whole
  ``membrax correct`` command in a fresh process (interpreter, imports, compilation, files);
  ``1e6 rows (s)``: the same command on the record interpolated onto 1,000,000 readings (a logger at
  high rate), CSV and plot written.

Run: ``python benchmarks/bench_calibrate.py``.
"""

import subprocess
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

from calibrate import correct, datasets, evaluate, fit, lab, report

SPECIMEN_ARGS = (
    "--specimen-diameter-mm",
    "--particle-size-mm",
    "--membrane-thickness-mm",
    "--membrane-modulus-kpa",
)


def _thousand_rows(folder: Path, rows: int = 1000) -> tuple[Path, list[str]]:
    """The example record interpolated onto ``rows`` axial strains, and its specimen's arguments."""
    with correct.example_record_path() as source:
        record = lab.read_lab_record(source)
    path = evaluate.write_resampled_record(record, rows, folder / f"rows_{rows}.csv")
    values = evaluate.example_arguments(record.comments)
    return path, values


def _command_seconds(record_path, specimen_args, folder) -> float:
    """Wall-clock seconds of the whole ``membrax correct`` command in a fresh process."""
    start = time.perf_counter()
    command = [sys.executable, "-m", "membrax.cli", "correct", str(record_path), *specimen_args]
    subprocess.run(command, check=True, capture_output=True, cwd=folder)
    return time.perf_counter() - start


def main() -> None:
    table = datasets.load_table(resources.files("calibrate") / "data" / "calibration_table.npz")
    start = time.perf_counter()
    model = correct.default_corrections().model
    result = fit.fit(model, table)
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    fit.fit(model, table)
    warm_s = time.perf_counter() - start
    start = time.perf_counter()
    fit.cross_validate(model, table)
    loo_s = time.perf_counter() - start
    baseline = fit.nelder_mead_baseline(model, table)
    optax_evals = result.evaluations["adam"] + result.evaluations["lbfgs"]
    with tempfile.TemporaryDirectory() as folder:
        record_path, values = _thousand_rows(Path(folder))
        specimen = correct.LabSpecimen.from_mm_kpa(*values)
        specimen_args = [
            item
            for name, value in zip(evaluate.SPECIMEN_FLAGS, values, strict=True)
            for item in (name, f"{value:g}")
        ]
        start = time.perf_counter()
        report.correct_file(record_path, specimen, out=Path(folder) / "out.csv")
        correct_s = time.perf_counter() - start
        command_s = _command_seconds(record_path, specimen_args, folder)
        million_s = _command_seconds(_thousand_rows(Path(folder), 1_000_000)[0], specimen_args, folder)
    print(f"calibration benchmark: {table.num_cases} cases, {table.num_rows} records; correct on 1,000 rows")
    print(
        f"{'dtype':<8}{'fit (s)':>9}{'warm (s)':>10}{'loo (s)':>9}{'nm evals':>10}{'optax evals':>13}"
        f"{'correct (s)':>13}{'command (s)':>13}{'1e6 rows (s)':>14}"
    )
    print(
        f"{'float64':<8}{fit_s:>9.2f}{warm_s:>10.2f}{loo_s:>9.1f}{baseline['evaluations']:>10d}{optax_evals:>13d}"
        f"{correct_s:>13.2f}{command_s:>13.2f}{million_s:>14.1f}"
    )


if __name__ == "__main__":
    main()
