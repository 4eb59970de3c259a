"""A dense and a loose random specimen sheared to 15 %: peak and dilation against contraction.

Both are the random demo's specimen (``DEMO_RANDOM_CONFIG``: equal 25 mm spheres in a 150 × 250 mm mould,
313 spheres, 10 kPa, a 5 mm membrane, I = 5e-3), compacted without friction (dense) or with an
inter-particle friction of tan⁻¹ 0.5 = 26.57° during compaction (loose), then sheared to
``--strain`` (default 15 %) with the test's friction (25°). Prints, for each: the solid fraction, the
peak internal and Love–Weber φ' and where they occur, their mean over the last 3 % of strain (the
large-strain angle), the largest contraction and the volumetric strain at the end (compression
positive), and Rowe's bound for FCC at the same φμ (:func:`membrax.theory.rowe_peak_friction_angle_deg`).

Expected of granular physics: the dense specimen peaks above its large-strain angle and dilates; the
loose one has no marked peak and contracts; both stay below Rowe's FCC bound.

Run: ``python examples/random_dense_loose.py [--strain 0.15] [--out results/random_dense_loose]`` (about
4 + 2 min on 2 CPU cores).
"""

import argparse
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strain", type=float, default=0.15)
    parser.add_argument("--out", default="results/random_dense_loose")
    args = parser.parse_args()

    import numpy as np

    from membrax import theory
    from membrax.config import DEMO_RANDOM_CONFIG, TriaxialConfig
    from membrax.defaults import COMPACTION_FRICTION_DEG
    from membrax.io.results import dataset_attrs_to_python
    from membrax.run import run_test
    from membrax.triaxial import analysis

    rows = []
    for state, friction in COMPACTION_FRICTION_DEG.items():
        config = TriaxialConfig(
            **{
                **DEMO_RANDOM_CONFIG,
                "name": f"random_{state}",
                "target_axial_strain": args.strain,
                "compaction_friction_deg": friction,
            }
        )
        start = time.perf_counter()
        results = run_test(config, Path(args.out) / state, progress=False).results
        axial = analysis.record(results, "axial_strain")
        volumetric = analysis.record(results, "volumetric_strain")
        row = {
            "state": state,
            "solid_fraction": dataset_attrs_to_python(results)["specimen"]["solid_fraction"],
            "seconds": time.perf_counter() - start,
            "largest_contraction": float(np.max(volumetric)),
            "end_volumetric": float(volumetric[-1]),
        }
        for name in ("internal_friction_angle_deg", "love_weber_friction_angle_deg"):
            angle = np.asarray(results[name]).ravel()
            peak = int(np.nanargmax(angle))
            row[name] = (
                float(angle[peak]),
                float(axial[peak]),
                float(np.nanmean(angle[axial > args.strain - 0.03])),
            )
        rows.append(row)
    bound = theory.rowe_peak_friction_angle_deg(TriaxialConfig().friction_angle_deg, theory.FCC)
    print(f"Rowe's FCC bound at φμ = {TriaxialConfig().friction_angle_deg:g}°: {bound:.2f}°")
    print("state | φ     | φ' int peak (ε_a) / large strain | φ'_LW peak (ε_a) / large strain | ε_v max, end")
    for row in rows:
        internal, love_weber = row["internal_friction_angle_deg"], row["love_weber_friction_angle_deg"]
        print(
            f"{row['state']:<6}| {row['solid_fraction']:.3f} "
            f"| {internal[0]:6.2f} ({100 * internal[1]:5.2f} %) / {internal[2]:6.2f} "
            f"| {love_weber[0]:6.2f} ({100 * love_weber[1]:5.2f} %) / {love_weber[2]:6.2f} "
            f"| {100 * row['largest_contraction']:5.2f} %, {100 * row['end_volumetric']:5.2f} % "
            f"({row['seconds']:.0f} s)"
        )


if __name__ == "__main__":
    main()
