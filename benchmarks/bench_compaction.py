"""Random specimen generation: a loose cloud compacted in a mould (membrax.spheres.compaction).

For each dtype, in a fresh process, builds a random packing of equal 25 mm spheres (default: the paper-like
specimen, 250 mm across and 500 mm high, frictionless compaction to 10 kPa; with these defaults and
``--seed k`` it is the specimen ``membrax reproduce --size paper --packing random`` builds for packing seed
k, whose configuration's contact law and density are compact's defaults) and prints: the number of
spheres, the steps run, the wall-clock time (compiling included) and steps/s, whether the stop test held
(``converged``), the unbalanced-force ratio, the final stress and how it was reached (``window``: ``yes``
within ±2 % of the target, ``jump`` the nearest state at a stress jump, with the relaxed stresses on either
side of it, ``no`` out of steps), the solid fractions (whole and core), the core's coordination number
without rattlers, and the specimen's diameter.

Targets: a paper-like specimen in under one minute on 2 cores; every seed ends.

Run: ``python benchmarks/bench_compaction.py [--across 10 --high 20 --friction 0 --max-steps 400000
--seed 0]``.
"""

import time

from harness import benchmark_parser, benchmark_rows, print_table


def measure(dtype: str, across: float, high: float, friction: float, max_steps: int, seed: int) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    from membrax.spheres.compaction import random_packing
    from membrax.spheres.grading import Grading

    diameter = 0.025
    start = time.perf_counter()
    packing = random_packing(
        Grading.equal(diameter),
        across * diameter,
        high * diameter,
        seed=seed,
        friction_coefficient=friction,
        max_steps=max_steps,
    )
    seconds = time.perf_counter() - start
    measures = packing.measures
    jump = packing.stress_jump
    return {
        "dtype": dtype,
        "spheres": measures["num_spheres"],
        "steps": packing.steps,
        "seconds": seconds,
        "steps_per_s": packing.steps / packing.seconds,
        "converged": "yes" if packing.converged else "no",
        "ratio": packing.unbalanced_force_ratio,
        "stress_kpa": packing.stress * 1e-3,
        "window": "jump" if jump else "yes" if packing.converged else "no",
        "below_kpa": f"{jump['stress_below'] * 1e-3:.3f}" if jump else "–",
        "above_kpa": f"{jump['stress_above'] * 1e-3:.3f}" if jump else "–",
        "solid": measures["solid_fraction"],
        "core": measures["core_solid_fraction"],
        "coordination": measures["coordination_number"],
        "diameter_mm": packing.diameter * 1e3,
    }


def main():
    parser = benchmark_parser(__doc__)
    parser.add_argument("--across", type=float, default=10.0, help="specimen diameter in sphere diameters")
    parser.add_argument("--high", type=float, default=20.0, help="specimen height in sphere diameters")
    parser.add_argument("--friction", type=float, default=0.0, help="μ between spheres during compaction")
    parser.add_argument("--max-steps", type=int, default=400_000)
    parser.add_argument("--seed", type=int, default=0, help="the packing seed (the loose cloud's)")
    args, rows = benchmark_rows(__file__, parser, measure)
    if rows is None:
        return
    print(
        f"Compaction: {args.across:g} × {args.high:g} sphere diameters, μ = {args.friction:g}, to 10 kPa, "
        f"seed {args.seed}"
    )
    print_table(
        rows,
        "spheres|steps|s|steps/s|converged|ufr|σ kPa|window|below kPa|above kPa|φ whole|φ core|Z core|D mm",
        "{spheres:>8d}{steps:>8d}{seconds:>7.1f}{steps_per_s:>9.0f}{converged:>10}{ratio:>9.1e}"
        "{stress_kpa:>8.3f}{window:>7}{below_kpa:>10}{above_kpa:>10}{solid:>9.3f}{core:>8.3f}"
        "{coordination:>8.2f}{diameter_mm:>7.1f}",
    )


if __name__ == "__main__":
    main()
