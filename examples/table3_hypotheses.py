"""What accounts for the paper's Δσ3 ≈ 0.1 σc? Table 3 at paper size under several readings.

The paper's Table 3 has internal σ3 − σc = 1.2–1.8, 4.1–5.0 and 9.4–10.6 kPa at σc = 10, 40 and 100 kPa:
close to 0.1 σc at every pressure and thickness, which points to a geometric factor rather than membrane
stiffness (a membrane's extra stress grows slower than σc). This script consolidates the paper's nine
cases (Table 1: σc × t_m) with both node–sphere contact surfaces (``membrane_contact_offset_factor`` 0:
nodes on the sphere surface, the paper's wording; 1: the membrane's inner face on the sphere, membrax's
default) in one float64 sweep, each to an unbalanced-force ratio ≤ 1e-3, and prints internal σ3 and σ1
at the end of consolidation under four readings of the paper's "radial force received by the internal
boundary particles (including the radial forces from the membrane) divided by surface area of the right
cylinder" (its §4.3):

- ``platen``: membrax's internal σ3, (F_spheres + F_clamps) / (2 √(π A) H), A the platen area, H the
  platen separation (the cylinder on which the cell pressure acts: with no membrane it equals σc);
- ``spheres``: the same without the clamp strips' radial load F_clamps;
- ``centres``: (F_spheres + F_clamps) / (2 π r_c H), the right cylinder through the boundary spheres'
  centres, r_c = √(A/π) − R (×1.11 at paper size);
- ``centres, spheres``: both changes.

and σ1 (ram force and force received by the spheres over A), the mid-height hoop strain ε_θ and the
ratio reached, beside the paper's Table 3 (:mod:`membrax.paper`). Nothing is fitted: the readings are
geometric definitions, and the model's constants are the paper's.

Run: ``python examples/table3_hypotheses.py [folder]`` (about 14 min on 2 CPU cores; results in
``results_table3_hypotheses/``). ``--small`` runs a 4 × 5 specimen in a few minutes, for a try;
``--resume`` continues an interrupted run (or reprints a finished one).
"""

import math
import sys
import time

import jax

from membrax.devices import split_cpu_devices

split_cpu_devices()  # one JAX device per core, before the rest of membrax (docs/model.md, Sweeps)

import numpy as np  # noqa: E402

from membrax import paper  # noqa: E402
from membrax import sweep as sweep_lib  # noqa: E402
from membrax.config import TriaxialConfig  # noqa: E402

GRID = {
    "cell_pressure_kpa": (10.0, 40.0, 100.0),
    "membrane_thickness_mm": (2.5, 3.33, 5.0),
    "membrane_contact_offset_factor": (0.0, 1.0),
}


def main(folder: str, small: bool, resume: bool) -> None:
    size = dict(particles_across=4, layers=5, membrane_edges_per_diameter=3.0) if small else {}
    # Consolidation only: shearing stops after the first record (1e-5 strain, no ramp).
    base = TriaxialConfig(
        name="table3_hypotheses",
        float64=True,
        consolidation_tolerance=1e-3,
        consolidation_max_steps=40000,
        target_axial_strain=1e-5,
        fine_until_strain=1e-5,
        shear_ramp_strain=0.0,
        chunk_steps=2000,
        **size,
    )
    started = time.perf_counter()
    result = sweep_lib.run_sweep(base, GRID, folder, resume=resume, progress=True)
    print(f"{len(jax.devices())} devices, {time.perf_counter() - started:.0f} s\n")
    radius = 0.5 * base.particle_diameter
    for factor in GRID["membrane_contact_offset_factor"]:
        first = result.dataset.isel(record=0).sel(membrane_contact_offset_factor=factor)
        consolidation = result.consolidation.sel(membrane_contact_offset_factor=factor)
        print(f"contact offset factor {factor:g}: internal − external at the end of consolidation, kPa")
        print(
            "  σc   t_m | Δσ3 platen | spheres | centres | centres, spheres | paper Δσ3 | Δσ1 | paper Δσ1"
            " | ε_θ | ratio"
        )
        for pressure in GRID["cell_pressure_kpa"]:
            for thickness in GRID["membrane_thickness_mm"]:
                case = first.sel(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness)
                ratio = np.asarray(
                    consolidation.sel(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness)[
                        "unbalanced_force_ratio"
                    ]
                ).ravel()
                ratio = ratio[np.isfinite(ratio)][-1]
                area, height = float(case.platen_area), float(case.height)
                spheres, clamps = float(case.membrane_radial_force), float(case.clamp_radial_force)
                platen_lateral = 2.0 * math.sqrt(math.pi * area) * height
                centre_lateral = 2.0 * math.pi * (math.sqrt(area / math.pi) - radius) * height
                sigma3 = {
                    "platen": (spheres + clamps) / platen_lateral,
                    "spheres": spheres / platen_lateral,
                    "centres": (spheres + clamps) / centre_lateral,
                    "centres, spheres": spheres / centre_lateral,
                }
                published = paper.PAPER_TABLE_3.get(paper.paper_key(pressure, thickness), {})
                paper_sigma3 = published.get("sigma3_internal_kpa", math.nan) - published.get(
                    "sigma3_external_kpa", math.nan
                )
                paper_sigma1 = published.get("sigma1_internal_kpa", math.nan) - published.get(
                    "sigma1_external_kpa", math.nan
                )
                sigma1 = 1e-3 * (float(case.internal_axial_stress) - float(case.external_axial_stress))
                cells = " | ".join(f"{1e-3 * value - pressure:7.2f}" for value in sigma3.values())
                print(
                    f"{pressure:5.0f} {thickness:5.2f} | {cells} | {paper_sigma3:7.2f} | {sigma1:5.2f} |"
                    f" {paper_sigma1:7.2f} | {float(case.hoop_strain):.4f} | {ratio:.1e}"
                )
        print()


if __name__ == "__main__":
    arguments = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(
        arguments[0] if arguments else "results_table3_hypotheses",
        "--small" in sys.argv,
        "--resume" in sys.argv,
    )
