"""The periodic element test beside YADE: the same packing, contact law, damping, rate and protocol.

For each seed and packing state, membrax compacts a random packing of equal spheres in a periodic cell
(:func:`membrax.triaxial.periodic_packing.compact_periodic`: frictionless for the dense state, compaction
friction 0.5 for the loose one) and hands the same centres, radii and box to both codes, which then run:

1. isotropic consolidation at σc from those positions (every axis servo-held, contact friction on);
2. drained compression: z shortened at ε̇ = I/(d √(ρ/σc)) to ``--strain``, x and y servo-held at σc.

Both use the paper's contact law (k_n = 1e7 N/m, k_t = k_n/2, φ_μ = 25°), Cundall local damping 0.3 on the
velocity's fluctuation about the box's affine field, and membrax's time step. YADE's side is
``examples/yade_periodic.py`` (``PeriTriaxController``); without a ``yade`` executable only membrax runs.

Prints per case: peak φ' (the largest of asin((σ1 − σ3)/(σ1 + σ3)), σ1 = σ_zz, σ3 the lateral mean), the
large-strain φ' (the mean over the last fifth of the strain), ε_v at the end, and the two codes' differences.

Run: ``python examples/periodic_vs_yade.py [--spheres 500] [--seeds 0,1,2] [--states dense,loose]
[--strain 0.1] [--out results/periodic_vs_yade.csv]`` (about 2 min per case on 2 cores).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from yade_periodic import friction_angle_deg, run_yade

DIAMETER, DENSITY, PRESSURE = 0.025, 2650.0, 1e4
NORMAL_STIFFNESS, TANGENTIAL_STIFFNESS, FRICTION_DEG, DAMPING = 1e7, 5e6, 25.0, 0.3
#: Compaction friction of each state (the mould's rule: frictionless → dense, tan⁻¹ 0.5 → loose).
STATES = {"dense": 0.0, "loose": 0.5}


def summary(axial_strain, angle, volumetric_strain) -> dict:
    """Peak φ', large-strain φ' (mean over the last fifth of the strain) and the final ε_v."""
    axial_strain, angle = np.asarray(axial_strain), np.asarray(angle)
    late = axial_strain >= 0.8 * axial_strain[-1]
    return {
        "peak_deg": float(np.max(angle)),
        "large_strain_deg": float(np.mean(angle[late])),
        "final_volumetric_strain": float(np.asarray(volumetric_strain)[-1]),
    }


def run_case(spheres: int, seed: int, state: str, strain: float, inertial_number: float) -> dict:
    """One packing through both codes: {"membrax": summary, "yade": summary or None, ...}."""
    import jax.numpy as jnp

    from membrax.spheres.contact import ContactParams
    from membrax.spheres.integrate import DampingParams
    from membrax.theory import mobilised_friction_angle_deg
    from membrax.triaxial.periodic import periodic_test
    from membrax.triaxial.periodic_packing import compact_periodic

    diameters = np.full(spheres, DIAMETER)
    law = ContactParams.paper(FRICTION_DEG, 0.0, NORMAL_STIFFNESS, TANGENTIAL_STIFFNESS)
    _, packed, _ = compact_periodic(
        diameters, PRESSURE, friction_coefficient=STATES[state], seed=seed, contact_params=law
    )
    fraction = np.asarray(packed.fraction + packed.fraction_compensation)
    length = np.asarray(packed.box_length)
    radius = np.full(spheres, 0.5 * DIAMETER)
    test = periodic_test(
        jnp.asarray(fraction),
        length,
        radius,
        PRESSURE,
        contact_params=law,
        damping=DampingParams.local(DAMPING),
    )
    start = time.perf_counter()
    # The unbalanced-force ratio of the runs in docs/validation.md (the float32 default is now 5e-3).
    consolidated, _ = test.consolidate(tolerance=1e-3)
    _, records = test.shear(consolidated, target_axial_strain=strain, inertial_number=inertial_number)
    seconds = time.perf_counter() - start
    ours = summary(
        records.axial_strain,
        np.asarray(mobilised_friction_angle_deg(records.axial_stress, records.lateral_stress)),
        records.volumetric_strain,
    )
    ours["solid_fraction"] = float(np.asarray(records.solid_fraction)[0])
    ours["seconds"] = seconds
    theirs = None
    if shutil.which("yade") is not None:
        start = time.perf_counter()
        out = run_yade(
            fraction * length[None, :],
            radius,
            length,
            PRESSURE,
            test.shear_rate(inertial_number),
            strain,
            test.dt,
            NORMAL_STIFFNESS,
            FRICTION_DEG,
            density=DENSITY,
            tangential_ratio=TANGENTIAL_STIFFNESS / NORMAL_STIFFNESS,
            damping=DAMPING,
            record_every=200,
        )
        shear = out["shear"]
        # YADE's strains are logarithmic; membrax's engineering (1 − L/L0): compare on membrax's measure.
        theirs = summary(
            1.0 - np.exp(-shear["axial_strain"]),
            friction_angle_deg(shear["stress"]),
            1.0 - np.exp(-shear["volumetric_strain"]),
        )
        theirs["solid_fraction"] = float(shear["solid_fraction"][0])
        theirs["seconds"] = time.perf_counter() - start
        theirs["consolidated"] = out["consolidated"]
    return {"membrax": ours, "yade": theirs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spheres", type=int, default=500)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--states", default="dense,loose")
    parser.add_argument("--strain", type=float, default=0.1)
    parser.add_argument("--inertial-number", type=float, default=1e-3)
    parser.add_argument("--out", default=None, help="also write the table as CSV here")
    args = parser.parse_args()
    if shutil.which("yade") is None:
        print("YADE is not installed (Debian: apt-get install yade); membrax only.")
    rows = []
    header = (
        f"{'state':<7}{'seed':>5}{'φ0 ours':>9}{'φ0 YADE':>9}{'peak ours':>10}{'peak YADE':>10}"
        f"{'late ours':>10}{'late YADE':>10}{'εv ours':>9}{'εv YADE':>9}"
    )
    print(header)
    for state in args.states.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            case = run_case(args.spheres, seed, state, args.strain, args.inertial_number)
            ours, theirs = case["membrax"], case["yade"] or {}
            row = {"state": state, "seed": seed, "spheres": args.spheres}
            for code, values in (("membrax", ours), ("yade", theirs)):
                for key in (
                    "solid_fraction",
                    "peak_deg",
                    "large_strain_deg",
                    "final_volumetric_strain",
                    "seconds",
                ):
                    row[f"{code}_{key}"] = values.get(key, float("nan"))
            rows.append(row)
            print(
                f"{state:<7}{seed:>5}{row['membrax_solid_fraction']:>9.4f}{row['yade_solid_fraction']:>9.4f}"
                f"{row['membrax_peak_deg']:>10.2f}{row['yade_peak_deg']:>10.2f}"
                f"{row['membrax_large_strain_deg']:>10.2f}{row['yade_large_strain_deg']:>10.2f}"
                f"{row['membrax_final_volumetric_strain']:>9.4f}{row['yade_final_volumetric_strain']:>9.4f}",
                flush=True,
            )
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
