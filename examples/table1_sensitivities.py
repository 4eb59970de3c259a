"""Implicit sensitivities of the initial stresses over the paper's Table 1 grid, as elasticities.

For each of the 3 × 3 cases (σc × t_m) on the small specimen of ``membrax reproduce --size small`` (6 spheres
across, 10 layers, membrane edge D/3, the paper's damping), consolidated to an unbalanced-force ratio of
1e-7 in float64, it computes d ln y/d ln x of the initial internal and additional (internal − external)
stresses y with respect to σc, E_m and t_m by the implicit function theorem at the equilibrium
(:func:`membrax.sensitivity`, without its finite-difference check, which the tests run on a smaller
specimen). It writes ``table1_sensitivities.csv`` and ``.md`` into the output folder and prints the
Markdown table.

Run: ``python examples/table1_sensitivities.py [OUT]`` (default ``docs/``); about 2 min per case on 2 CPU
cores.
"""

import csv
import sys
import time
from pathlib import Path

import membrax
from membrax.paper import PAPER_CELL_PRESSURES_KPA, PAPER_THICKNESSES_MM
from membrax.reproduce import SIZES

WRT = ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_thickness_mm")
OUTPUTS = (
    "internal_axial_stress",
    "internal_radial_stress",
    "additional_axial_stress",
    "additional_radial_stress",
)


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "docs")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for thickness in PAPER_THICKNESSES_MM:
        for pressure in PAPER_CELL_PRESSURES_KPA:
            config = membrax.TriaxialConfig(
                **SIZES["small"], cell_pressure_kpa=pressure, membrane_thickness_mm=thickness
            )
            start = time.perf_counter()
            table = membrax.sensitivity(config, outputs=OUTPUTS, wrt=WRT, finite_differences=False)
            for row in table.rows:
                rows.append({"cell_pressure_kpa": pressure, "membrane_thickness_mm": thickness, **row})
            print(f"{pressure:g} kPa, {thickness:g} mm: {time.perf_counter() - start:.0f} s", flush=True)
    with open(out / "table1_sensitivities.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = [
        "| σc (kPa) | t_m (mm) | output | y (kPa) | ε(σc) | ε(E_m) | ε(t_m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for pressure_thickness in sorted({(r["cell_pressure_kpa"], r["membrane_thickness_mm"]) for r in rows}):
        for output in OUTPUTS:
            mine = {
                r["parameter"]: r
                for r in rows
                if (r["cell_pressure_kpa"], r["membrane_thickness_mm"]) == pressure_thickness
                and r["output"] == output
            }
            value = 1e-3 * mine[WRT[0]]["value"]
            elasticities = " | ".join(f"{mine[name]['elasticity']:.3g}" for name in WRT)
            pressure, thickness = pressure_thickness
            lines.append(f"| {pressure:g} | {thickness:g} | {output} | {value:.3f} | {elasticities} |")
    (out / "table1_sensitivities.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
