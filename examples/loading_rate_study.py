"""The loading rate's effect on the paper reproduction: Table 1 at paper size at several inertial numbers.

Runs ``membrax reproduce --size paper`` (10 × 25 FCC, membrane edge D/5, float64) once per entry of
``--rates``, each into its own folder of ``OUT`` (an interrupted study resumes; a finished entry is read
back), and compares every entry with the first (the slowest, the reference). An entry is an inertial number
(``1e-3`` → ``I_0.001``), or ``FINE:COARSE``: I = FINE up to ``fine_until_strain`` (1 %, past every peak of
Table 1) and COARSE after it (``coarse_inertial_number``; ``I_0.001_then_0.005``); a ``+f32`` suffix
consolidates in float64 and shears in float32 (``float32_shearing``; ``..._float32_shearing``). The
comparison:

- Table 2: each case's peak φ' external and internal, the largest difference over the nine cases (°);
- Table 3: σ3 and σ1, external and internal, and Δσ3, Δσ1 at the start of shearing (kPa). Consolidation
  does not depend on the shearing rate, so these differ only if consolidation does (a check);
- the 10 kPa / 5 mm case's φ'_ext − φ'_int against axial strain (the membrane's effect on the
  friction angle, the paper's Fig. 5), the largest difference over 0–10 % strain, interpolated on the
  slowest run's strains (°);
- every case's φ' external and internal against axial strain, the largest difference over 1–10 % strain
  and the nine cases (°): what a faster coarse phase moves after the peaks;
- the wall time of each reproduction.

Writes ``OUT/loading_rate.csv`` (one row per rate), ``OUT/loading_rate.png`` (the 10 kPa / 5 mm
ext − int curves) and ``OUT/loading_rate_curves.png`` (every case's φ' external, every entry). The
tolerance for a faster default: an entry is acceptable if its peaks stay within 0.3° and its Table 3 within
0.3 kPa of the slowest run's.

Run: ``python examples/loading_rate_study.py [--rates 1e-3,2e-3,5e-3,1e-3:5e-3,1e-3:5e-3+f32]
[--out results/loading_rate]`` (about 2 h 30 min on 2 CPU cores for the default five; the figures are in
docs/loading_rate.md).
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
    parser.add_argument(
        "--rates",
        default="1e-3,2e-3,5e-3,1e-3:5e-3,1e-3:5e-3+f32",
        help="inertial numbers, the slowest first; FINE:COARSE changes to COARSE after fine_until_strain; "
        "a +f32 suffix shears in float32 after the float64 consolidation",
    )
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
    rates = [parse_rate(spec) for spec in args.rates.split(",")]
    runs = {}
    for rate in rates:
        fine, coarse, float32_shearing = rate
        folder = out / folder_name(rate)
        timing = folder / "wall_time.json"
        if not timing.exists():
            start = time.perf_counter()
            overrides = {
                "inertial_number": fine,
                "coarse_inertial_number": coarse or 0.0,
                "float32_shearing": float32_shearing,
            }
            reproduce(args.size, folder, resume=folder.exists(), progress=False, overrides=overrides)
            timing.write_text(json.dumps({"seconds": time.perf_counter() - start}))
        runs[rate] = (read_results(folder / "sweep.nc"), json.loads(timing.read_text())["seconds"])

    def curve(dataset, pressure=10.0, thickness=5.0, names=("external", "internal")):
        case = member_records(dataset, cell_pressure_kpa=pressure, membrane_thickness_mm=thickness)
        strain = np.asarray(case["axial_strain"]).ravel()
        angles = [np.asarray(case[f"{name}_friction_angle_deg"]).ravel() for name in names]
        return strain, angles[0] - angles[1] if len(angles) == 2 else angles[0]

    def largest_curve_difference(dataset, name):
        """max over the nine members and 1–10 % strain of |φ'(ε) − φ'_slowest(ε)|, φ' ``name``'s."""
        worst = 0.0
        for pressure in slowest["cell_pressure_kpa"].values:
            for thickness in slowest["membrane_thickness_mm"].values:
                args = (float(pressure), float(thickness), (name,))
                strain, angle = curve(slowest, *args)
                other_strain, other = curve(dataset, *args)
                inside = (strain >= 0.01) & (strain <= 0.10)
                difference = np.interp(strain[inside], other_strain, other) - angle[inside]
                worst = max(worst, float(np.nanmax(np.abs(difference))))
        return worst

    slowest, _ = runs[rates[0]]
    reference_strain, reference_gap = curve(slowest)
    keep = reference_strain <= 0.10
    rows = []
    figure, axis = plt.subplots(figsize=(6, 4))
    for rate, (dataset, seconds) in runs.items():
        strain, gap = curve(dataset)
        label = f"I = {rate[0]:g}" + ("" if rate[1] is None else f", then {rate[1]:g} after 1 %")
        label += ", float32 shearing" if rate[2] else ""
        axis.plot(100 * strain, gap, label=label)
        row = {
            "inertial_number": rate[0],
            "coarse_inertial_number": rate[1] or "",
            "float32_shearing": rate[2],
            "wall_s": round(seconds, 1),
        }
        row["shear_steps_10kPa"] = int(dataset["shear_steps"].sel(cell_pressure_kpa=10.0).max())
        for name in TABLE_2 + TABLE_3:
            difference = np.abs(dataset[name].values - slowest[name].values)
            row[f"max_diff_{name}"] = float(np.nanmax(difference))
        row["max_diff_ext_minus_int_10kPa_5mm_deg"] = float(
            np.max(np.abs(np.interp(reference_strain[keep], strain, gap) - reference_gap[keep]))
        )
        for name in ("external", "internal"):
            row[f"max_diff_{name}_friction_angle_1_to_10pct_deg"] = largest_curve_difference(dataset, name)
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
    figure, axes = plt.subplots(3, 3, figsize=(12, 9), sharex=True, sharey=True)
    for i, pressure in enumerate(slowest["cell_pressure_kpa"].values):
        for j, thickness in enumerate(slowest["membrane_thickness_mm"].values):
            for rate, (dataset, _) in runs.items():
                strain, angle = curve(dataset, float(pressure), float(thickness), ("external",))
                axes[i, j].plot(100 * strain, angle, lw=0.8, label=folder_name(rate))
            axes[i, j].set_title(f"{float(pressure):g} kPa, {float(thickness):g} mm", fontsize=9)
    for axis in axes[-1]:
        axis.set_xlabel("axial strain (%)")
    for axis in axes[:, 0]:
        axis.set_ylabel("φ' external (°)")
    axes[0, 0].legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(out / "loading_rate_curves.png", dpi=100)
    with (out / "loading_rate.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    for row in rows:
        print(json.dumps(row))


def folder_name(rate: tuple[float, float | None, bool]) -> str:
    """``I_0.001``, ``I_0.001_then_0.005``, ``I_0.001_then_0.005_float32_shearing``."""
    fine, coarse, float32_shearing = rate
    name = f"I_{fine:g}" if coarse is None else f"I_{fine:g}_then_{coarse:g}"
    return name + ("_float32_shearing" if float32_shearing else "")


def parse_rate(spec: str) -> tuple[float, float | None, bool]:
    """``"1e-3"`` → (1e-3, None, False); ``"1e-3:5e-3"`` → I = 1e-3 to ``fine_until_strain``, 5e-3 after;
    a ``+f32`` suffix shears in float32 after the float64 consolidation (``float32_shearing``)."""
    spec, plus, suffix = spec.partition("+")
    if plus and suffix != "f32":
        raise SystemExit(f"--rates: unknown suffix '+{suffix}' in '{spec}+{suffix}'; the one suffix is +f32.")
    fine, _, coarse = spec.partition(":")
    return float(fine), float(coarse) if coarse else None, bool(plus)


if __name__ == "__main__":
    main()
