"""The calibration grid's two blown-up corners: thin, soft membranes at 100 kPa, and why they blew up.

Runs, on the small preset of ``membrax reproduce`` (membrane edge D/3, I = 5e-3, float64), the four cases
1 mm of 700 kPa and 1 mm of 1400 kPa at σc = 100 kPa on the 6-across (6 × 10) and 8-across (8 × 13) FCC
specimens, consolidation then shearing to 10 % axial strain, in chunks of ``--chunk-steps``. After every
chunk it prints the deepest reach of a membrane node into a sphere off the specimen's lateral boundary
(an "inner" sphere): min over nodes n and inner spheres i of |x_n − x_i| − (R_i + t_m/2), negative when the
node's mid-surface lies inside it. A code that lets a node touch only the lateral-boundary spheres (as
membrax did before the cell-list search) cannot stop such a node: it slips between two boundary spheres
into the voids behind them. membrax now finds node–sphere candidates among all spheres
(:func:`membrax.membrane.contact.build_candidates`), so an inner sphere pushes the node back with the same
penalty as any other (overlap k_n δ, a few µm at these loads).

Prints one line per chunk (phase, strain, deepest inner reach in mm, nodes within an inner sphere, the
membrane's contacts) and, per case, the outcome: completed with its peak φ' (external, internal), or the
error that stopped it and the chunk.

Run: ``python examples/thin_membrane_corners.py [--cases all|d6_700,d8_1400,...] [--chunk-steps 1000]``
(about 1–3 min per case on 2 CPU cores).
"""

import argparse
import tempfile
import time
from pathlib import Path

#: name → (particles across, layers, membrane modulus kPa); all at 100 kPa with a 1 mm membrane.
CASES = {
    "d6_700": (6, 10, 700.0),
    "d6_1400": (6, 10, 1400.0),
    "d8_700": (8, 13, 700.0),
    "d8_1400": (8, 13, 1400.0),
}


def inner_reach(states, test) -> tuple[float, int]:
    """(deepest reach of a node into an inner sphere, m (negative: inside); nodes inside one)."""
    import numpy as np

    nodes = np.asarray(states.membrane.position)[0]
    spheres = np.asarray(states.dem.position)[0]
    radius = np.asarray(test.particles.radius)
    inner = ~np.asarray(test.specimen.is_lateral_boundary)
    half = 0.5 * float(np.asarray(test.params.membrane.contact_thickness))
    gap = np.full(nodes.shape[0], np.inf)
    for start in range(0, nodes.shape[0], 2048):
        block = nodes[start : start + 2048]
        distance = np.linalg.norm(block[:, None, :] - spheres[None, inner, :], axis=-1)
        gap[start : start + 2048] = np.min(distance - (radius[inner] + half)[None, :], axis=1)
    return float(np.min(gap)), int(np.sum(gap < 0.0))


def inward_displacement(states, test) -> float:
    """The largest inward radial displacement of a membrane node from its rest position, m."""
    import numpy as np

    def radius(position):
        return np.hypot(position[:, 0], position[:, 1])

    rest = radius(np.asarray(test.mesh.reference_position))
    return float(np.max(rest - radius(np.asarray(states.membrane.position)[0])))


def run_case(name: str, chunk_steps: int, edges_per_diameter: float) -> dict:
    import jax
    import numpy as np

    from membrax import runner
    from membrax.config import TriaxialConfig
    from membrax.errors import RunError, SimulationError
    from membrax.reproduce import SIZES
    from membrax.triaxial import analysis

    across, layers, modulus = CASES[name]
    config = TriaxialConfig(
        **{
            **SIZES["small"],
            "name": name,
            "particles_across": across,
            "layers": layers,
            "cell_pressure_kpa": 100.0,
            "membrane_thickness_mm": 1.0,
            "membrane_modulus_kpa": modulus,
            "chunk_steps": chunk_steps,
            "membrane_edges_per_diameter": edges_per_diameter,
        }
    )
    jax.config.update("jax_enable_x64", True)
    batch = runner.build_batch([config])
    test = batch.tests[0]
    start = time.perf_counter()
    deepest = [np.inf]

    def after_chunk(states, phase):
        reach, inside = inner_reach(states, test)
        deepest[0] = min(deepest[0], reach)
        print(
            f"  {name} {phase:<13} step {int(np.asarray(states.dem.step)[0]):>7}  deepest inner reach "
            f"{1e3 * reach:+7.3f} mm  nodes inside {inside:>4}  largest inward node displacement "
            f"{1e3 * inward_displacement(states, test):7.2f} mm",
            flush=True,
        )

    outcome = {"name": name, "spheres": int(test.particles.num_particles), "nodes": int(test.mesh.num_nodes)}
    try:
        records, shear_start, _ = runner.run_group(
            batch, Path(tempfile.mkdtemp(prefix=f"corner_{name}_")), progress=False, after_chunk=after_chunk
        )
        mine = runner.member_chunk_records(records, 0)
        metadata = runner.run_metadata(config, test, mine, 0.0, 0.0, runner.consolidation_tolerance(config))
        shear, _ = runner.results_datasets(mine, shear_start[0], metadata)
        peak = analysis.peak(shear)
        angles = {key: float(value) for key, value in peak.items() if "index" not in key}
        outcome.update(status="completed", **angles)
    except (RunError, SimulationError) as error:
        outcome.update(status=f"stopped: {str(error).splitlines()[0][:160]}")
    outcome.update(seconds=time.perf_counter() - start, deepest_inner_reach_mm=1e3 * deepest[0])
    return outcome


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="all", help=f"comma-separated of {', '.join(CASES)}, or all")
    parser.add_argument("--chunk-steps", type=int, default=1000)
    parser.add_argument("--edges-per-diameter", type=float, default=3.0, help="membrane edge D/n (preset: 3)")
    args = parser.parse_args()
    names = list(CASES) if args.cases == "all" else args.cases.split(",")
    outcomes = [run_case(name, args.chunk_steps, args.edges_per_diameter) for name in names]
    print("\ncase     | spheres | nodes | deepest inner reach mm |    s | outcome")
    shown = ("name", "spheres", "nodes", "status", "seconds", "deepest_inner_reach_mm")
    for o in outcomes:
        print(
            f"{o['name']:<9}| {o['spheres']:>7} | {o['nodes']:>5} | {o['deepest_inner_reach_mm']:>+22.3f} |"
            f" {o['seconds']:>4.0f} | {o['status']}"
        )
        peaks = {key: value for key, value in o.items() if key not in shown}
        if peaks:
            print("         ", ", ".join(f"{key} {value:.4g}" for key, value in peaks.items()))


if __name__ == "__main__":
    main()
