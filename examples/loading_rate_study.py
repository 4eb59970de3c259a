"""The loading rate's effect on the paper reproduction: Table 1 at paper size at several inertial numbers.

Runs ``membrax reproduce --size paper`` (10 × 25 FCC, membrane edge D/5, float64) once per inertial number
of ``--rates`` (default 1e-3, the preset, then 2e-3 and 5e-3), each into ``OUT/I_<rate>`` (an interrupted
study resumes; a finished rate is read back), and compares every rate with the slowest:

- Table 2: each case's peak φ' external and internal, the largest difference over the nine cases (°);
- Table 3: σ3 and σ1, external and internal, and Δσ3, Δσ1 at the start of shearing (kPa). Consolidation
  does not depend on the shearing rate, so these differ only if consolidation does (a check);
- the 10 kPa / 5 mm case's φ'_ext − φ'_int against axial strain (the membrane's effect on the
  friction angle, the paper's Fig. 5), the largest difference over 0–10 % strain, interpolated on the
  slowest run's strains (°);
- the wall time of each reproduction.

Writes ``OUT/loading_rate.csv`` (one row per rate) and ``OUT/loading_rate.png`` (the 10 kPa / 5 mm
ext − int curves). The tolerance of issue 47: a rate is acceptable if its peaks stay within 0.3° and its
Table 3 within 0.3 kPa of the slowest run's.

Run: ``python examples/loading_rate_study.py [--rates 1e-3,2e-3,5e-3] [--out results/loading_rate]``
(measured 2026-11-27 on 2 CPU cores: 45 min 49 s at 1e-3, 20 min 55 s at 5e-3; docs/loading_rate.md).
"""

import argparse
import csv
import json
import time
from pathlib import Path

TABLE_2 = ("peak_external_friction_angle_deg", "peak_internal_friction_angle_deg")
TABLE_3 = ("sigma3_external_kpa", "sigma3_internal_kpa", "sigma1_external_kpa", "sigma1_internal_kpa")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="1e-3,2e-3,5e-3", help="inertial numbers, the slowest first")
    parser.add_argument("--out", default="results/loading_rate")
    parser.add_argument("--size", default="paper", choices=("small", "paper"))
    args = parser.parse_args()

    from membrax.devices import split_cpu_devices

    split_cpu_devices()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from membrax.io import read_results
    from membrax.reproduce import reproduce
    from membrax.sweep import member_records

    out = Path(args.out)
    rates = [float(rate) for rate in args.rates.split(",")]
    runs = {}
    for rate in rates:
        folder = out / f"I_{rate:g}"
        timing = folder / "wall_time.json"
        if not timing.exists():
            start = time.perf_counter()
            reproduce(
                args.size, folder, resume=folder.exists(), progress=False, overrides={"inertial_number": rate}
            )
            timing.write_text(json.dumps({"seconds": time.perf_counter() - start}))
        runs[rate] = (read_results(folder / "sweep.nc"), json.loads(timing.read_text())["seconds"])

    def curve(dataset):
        case = member_records(dataset, cell_pressure_kpa=10.0, membrane_thickness_mm=5.0)
        strain = np.asarray(case["axial_strain"]).ravel()
        gap = np.asarray(case["external_friction_angle_deg"]) - np.asarray(
            case["internal_friction_angle_deg"]
        )
        return strain, gap.ravel()

    slowest, _ = runs[rates[0]]
    reference_strain, reference_gap = curve(slowest)
    keep = reference_strain <= 0.10
    rows = []
    figure, axis = plt.subplots(figsize=(6, 4))
    for rate, (dataset, seconds) in runs.items():
        strain, gap = curve(dataset)
        axis.plot(100 * strain, gap, label=f"I = {rate:g}")
        row = {"inertial_number": rate, "wall_s": round(seconds, 1)}
        row["shear_steps_10kPa"] = int(dataset["shear_steps"].sel(cell_pressure_kpa=10.0).max())
        for name in TABLE_2 + TABLE_3:
            difference = np.abs(dataset[name].values - slowest[name].values)
            row[f"max_diff_{name}"] = float(np.nanmax(difference))
        row["max_diff_ext_minus_int_10kPa_5mm_deg"] = float(
            np.max(np.abs(np.interp(reference_strain[keep], strain, gap) - reference_gap[keep]))
        )
        peaks = max(row[f"max_diff_{name}"] for name in TABLE_2)
        table3 = max(row[f"max_diff_{name}"] for name in TABLE_3)
        row["within_tolerance"] = bool(peaks <= 0.3 and table3 <= 0.3)
        rows.append(row)
    axis.set_xlabel("axial strain (%)")
    axis.set_ylabel("φ'_ext − φ'_int (°)")
    axis.set_title(f"10 kPa, 5 mm membrane ({args.size} size)")
    axis.legend()
    figure.tight_layout()
    figure.savefig(out / "loading_rate.png", dpi=120)
    with (out / "loading_rate.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    for row in rows:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
