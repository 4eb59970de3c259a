"""Cost of the coupled step as the specimen grows: a quarter to four times the paper's, on this machine.

FCC specimens of 25 mm spheres with about the paper's slenderness (layers ≈ 2.5 × across), from 7 × 14
(483 spheres, 0.27 × the paper's) through the paper's 10 × 25 (1,816) to 16 × 38 (7,239, 3.99 ×), each in a
5 mm membrane of edge D/5 consolidating at 10 kPa (the paper's mesh and its thickest membrane). For each
dtype and size, in a fresh process, prints: spheres, membrane nodes, the coupled step's compile time,
steps/s, and the time per step per particle (spheres + nodes), which stays flat where the cost is linear
in the work; the last column is that figure over the paper size's.

Rates are the best of three timed runs of ``--repeats`` steps in one compiled loop (after a compiling one).

Run: ``python benchmarks/bench_scaling.py [--dtypes float32] [--repeats 50]`` (about 10 min on 2 cores).
"""

import argparse
import json
import resource

from harness import print_table, run_child, time_coupled_steps

#: (spheres across, layers): 0.27, 0.51, 1, 1.99 and 3.99 times the paper specimen's 1,816 spheres.
SIZES = ((7, 14), (8, 24), (10, 25), (13, 29), (16, 38))
PAPER = (10, 25)


def measure(dtype: str, across: int, layers: int, repeats: int) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    from membrax.spheres import fcc
    from membrax.triaxial import membrane_cell

    specimen = fcc.fcc_specimen(0.025, across, layers)
    test = membrane_cell.membrane_test(specimen, cell_pressure=1e4, membrane_thickness=0.005)
    first, total = time_coupled_steps(test, repeats)
    particles = specimen.num_particles + test.mesh.num_nodes
    return {
        "dtype": dtype,
        "size": f"{across} x {layers}",
        "spheres": specimen.num_particles,
        "nodes": int(test.mesh.num_nodes),
        "compile_s": first - total,
        "steps_per_s": repeats / total,
        "us_per_particle_step": 1e6 * total / (repeats * particles),
        "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--dtypes", default="float32,float64")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        dtype, across, layers = args.child
        print(json.dumps(measure(dtype, int(across), int(layers), args.repeats)))
        return
    rows = []
    for dtype in args.dtypes.split(","):
        measured = [
            run_child(__file__, [dtype, str(across), str(layers)], {"repeats": args.repeats})
            for across, layers in SIZES
        ]
        paper = measured[SIZES.index(PAPER)]["us_per_particle_step"]
        for row in measured:
            rows.append({**row, "relative": row["us_per_particle_step"] / paper})
    print_table(
        rows,
        "size|spheres|nodes|compile s|steps/s|µs/particle-step|vs paper|peak MB",
        "{size:>8}{spheres:>8}{nodes:>7}{compile_s:>10.1f}{steps_per_s:>8.1f}{us_per_particle_step:>17.4f}"
        "{relative:>9.2f}{peak_memory_mb:>8.0f}",
    )


if __name__ == "__main__":
    main()
