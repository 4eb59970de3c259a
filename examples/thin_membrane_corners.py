"""The calibration grid's two blown-up corners, thin soft membranes at 100 kPa, and why they blow up.

The mechanism is the membrane law's inflation limit (docs/model.md): a neo-Hookean sheet of thickness t_m
and modulus E_m spanning an opening of radius a holds at most p_max = 1.8353 (E_m/3) t_m/a
(:func:`membrax.theory.membrane_limit_pressure`); above it the sheet balloons through. Over the square
windows between four touching 25 mm spheres (a = (√2 − 1) R = 5.18 mm), 1 mm of 700 kPa holds 82.7 kPa and
1 mm of 1400 kPa 165 kPa. membrax refuses a configuration whose cell pressure exceeds that limit
(:func:`membrax.config.inflation_ratio`) and warns from 0.33 of it.

Default: runs the four cases 1 mm of 700 kPa and 1 mm of 1400 kPa at σc = 100 kPa on the 6-across (6 × 10)
and 8-across (8 × 13) FCC specimens on the small preset of ``membrax reproduce`` (membrane edge D/3,
I = 5e-3, float64), consolidation then shearing to 10 % axial strain in chunks of ``--chunk-steps``. The
700 kPa cases are refused (their message is printed). After every chunk it prints the deepest reach of a
membrane node into a sphere off the specimen's lateral boundary (an "inner" sphere; negative: inside it)
and the largest inward displacement of a node from the mesh's rest radius; per case, the outcome.

``--ramp``: the evidence. The 700 kPa membrane on both specimens, built at 50 kPa (accepted), with the
membrane's cell pressure and the platens' target raised from 0 to 100 kPa over ``--ramp-steps`` steps
(quasi-static: the membrane follows its equilibrium until it loses it); every 100 steps it prints the
pressure, the largest inward node displacement and the fastest node. The runaway starts where the
membrane's equilibrium ends, near the predicted limit; ``--law svk`` (St Venant–Kirchhoff, whose tension
grows without a maximum) holds the full 100 kPa; ``--law gent`` (Gent, J_m = 97.2) has its limit 2.6 % above
the neo-Hookean one.

``--law gent --contact faces`` runs the cases with Gent's law and the sphere–face contact
(:mod:`membrax.membrane.face_contact`: the sheet cannot pass between its nodes through a sphere). Each case
reports α/D at the end of consolidation, the largest inward displacement of a node from the mesh's rest
surface (which rests on the outer spheres) over D, beside Molenkamp & Luger's eq. 2 for C = 0.15–0.4
(:func:`membrax.theory.molenkamp_luger_indentation_ratio`; their range is for a triangular grid of
spheres, the FCC faces here are square).

Run: ``python examples/thin_membrane_corners.py [--cases all|d6_1400,...] [--chunk-steps 1000]
[--law gent] [--contact faces]`` (about 1 min per case on 2 CPU cores with node contact),
``python examples/thin_membrane_corners.py --ramp [--law svk|gent]`` (about
1 min per specimen).
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


def molenkamp_luger_range(diameter: float, thickness: float, pressure: float, modulus: float):
    """α/D of Molenkamp & Luger's eq. 2 (the paper's) at the FCC void ratio for C = 0.15 and 0.4."""
    from membrax import theory

    return tuple(
        float(
            theory.molenkamp_luger_indentation_ratio(
                theory.FCC_VOID_RATIO, diameter, thickness, pressure, modulus, constant
            )
        )
        for constant in (0.15, 0.4)
    )


def run_case(
    name: str, chunk_steps: int, edges_per_diameter: float, law: str = "neo-hookean", contact: str = "nodes"
) -> dict:
    import jax
    import numpy as np

    from membrax import executor, run_records, runner
    from membrax.config import ConfigError, TriaxialConfig
    from membrax.errors import RunError, SimulationError
    from membrax.reproduce import SIZES
    from membrax.triaxial import analysis

    across, layers, modulus = CASES[name]
    fields = dict(
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
            "membrane_law": law,
            "membrane_contact_model": contact,
        }
    )
    try:
        config = TriaxialConfig(**fields)
    except ConfigError as error:
        return {
            "name": name,
            "status": f"refused: {error}",
            "spheres": 0,
            "nodes": 0,
            "seconds": 0.0,
            "deepest_inner_reach_mm": float("nan"),
            "alpha_over_d": float("nan"),
        }
    jax.config.update("jax_enable_x64", True)
    batch = executor.build_batch([config])
    test = batch.tests[0]
    start = time.perf_counter()
    deepest, consolidated_indentation = [np.inf], [float("nan")]

    def after_chunk(states, phase):
        reach, inside = inner_reach(states, test)
        deepest[0] = min(deepest[0], reach)
        if phase == "consolidation":  # the last one is the end of consolidation
            consolidated_indentation[0] = inward_displacement(states, test)
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
        mine = run_records.member_chunk_records(records, 0)
        metadata = run_records.run_metadata(batch.settings[0], test, mine, 0.0, 0.0)
        shear, _ = run_records.results_datasets(mine, shear_start[0], metadata)
        peak = analysis.peak(shear)
        angles = {key: float(value) for key, value in peak.items() if "index" not in key}
        outcome.update(status="completed", **angles)
    except (RunError, SimulationError) as error:
        outcome.update(status=f"stopped: {str(error).splitlines()[0][:160]}")
    diameter = float(config.particle_diameter)
    outcome.update(
        seconds=time.perf_counter() - start,
        deepest_inner_reach_mm=1e3 * deepest[0],
        alpha_over_d=consolidated_indentation[0] / diameter,
    )
    return outcome


def ramp_case(across: int, ramp_steps: int, law: str, contact: str = "nodes") -> None:
    """Raise the cell pressure on 1 mm of 700 kPa slowly to 100 kPa; print where the membrane runs away."""
    import math

    import jax
    import numpy as np

    from membrax import assemble
    from membrax.config import TriaxialConfig, config_to_dict, inflation_ratio
    from membrax.errors import SimulationError
    from membrax.reproduce import SIZES

    jax.config.update("jax_enable_x64", True)
    layers = {6: 10, 8: 13}[across]
    fields = {**SIZES["small"], "particles_across": across, "layers": layers, "membrane_thickness_mm": 1.0}
    config = TriaxialConfig(
        **fields,
        cell_pressure_kpa=50.0,
        membrane_modulus_kpa=700.0,
        membrane_law=law,
        membrane_contact_model=contact,
    )
    test = assemble.build_test(config)
    ratio = inflation_ratio(config_to_dict(config))  # the law's limit over the square windows; 0: none
    limit = config.cell_pressure / ratio if ratio > 0.0 else math.inf
    print(
        f"{across} across, {law}, {contact} contact: predicted limit over the square windows "
        f"{limit / 1e3:.1f} kPa",
        flush=True,
    )
    rest = np.hypot(*np.asarray(test.mesh.reference_position)[:, :2].T)
    state, final, chunk = test.initial_state, 1e5, 100
    for step in range(0, ramp_steps + 3000, chunk):
        pressure = final * min(1.0, (step + chunk) / ramp_steps)
        membrane = test.params.membrane.set(cell_pressure=jax.numpy.asarray(pressure))
        state = test.set_platens(state, True, 0.0, pressure)
        try:
            state, _ = test.runner.run(state, test.params.set(membrane=membrane), chunk, chunk, chunk)
        except SimulationError as error:
            print(f"  {pressure / 1e3:5.1f} kPa: {str(error).splitlines()[0][:90]}")
            return
        position = np.asarray(state.membrane.position)
        inward = np.max(rest - np.hypot(position[:, 0], position[:, 1]))
        speed = np.max(np.linalg.norm(np.asarray(state.membrane.velocity), axis=1))
        print(
            f"  step {step + chunk:5d}  {pressure / 1e3:5.1f} kPa  inward {1e3 * inward:6.2f} mm  "
            f"fastest node {speed:8.3f} m/s",
            flush=True,
        )
    print(f"  held {final / 1e3:.0f} kPa for 3000 steps")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="all", help=f"comma-separated of {', '.join(CASES)}, or all")
    parser.add_argument("--chunk-steps", type=int, default=1000)
    parser.add_argument("--edges-per-diameter", type=float, default=3.0, help="membrane edge D/n (preset: 3)")
    parser.add_argument("--ramp", action="store_true", help="the ramp study of 1 mm of 700 kPa (docstring)")
    parser.add_argument("--ramp-steps", type=int, default=2000)
    parser.add_argument("--law", default="neo-hookean", choices=("neo-hookean", "gent", "svk"))
    parser.add_argument("--contact", default="nodes", choices=("nodes", "faces"), help="contact model")
    args = parser.parse_args()
    if args.ramp:
        for across in (6, 8):
            ramp_case(across, args.ramp_steps, args.law, args.contact)
        return
    names = list(CASES) if args.cases == "all" else args.cases.split(",")
    outcomes = [
        run_case(name, args.chunk_steps, args.edges_per_diameter, args.law, args.contact) for name in names
    ]
    print(f"\n{args.law} law, {args.contact} contact; α/D at the end of consolidation (largest inward node")
    print("displacement / D) beside Molenkamp & Luger's eq. 2 for C = 0.15–0.4 (FCC void ratio)")
    print("case     | spheres | nodes | deepest inner reach mm |  α/D  | M&L α/D   |    s | outcome")
    shown = ("name", "spheres", "nodes", "status", "seconds", "deepest_inner_reach_mm", "alpha_over_d")
    for o in outcomes:
        low, high = molenkamp_luger_range(0.025, 1e-3, 1e5, 1e3 * CASES[o["name"]][2])
        print(
            f"{o['name']:<9}| {o['spheres']:>7} | {o['nodes']:>5} | {o['deepest_inner_reach_mm']:>+22.3f} |"
            f" {o['alpha_over_d']:.3f} | {low:.2f}–{high:.2f} | {o['seconds']:>4.0f} | {o['status']}"
        )
        peaks = {key: value for key, value in o.items() if key not in shown}
        if peaks:
            print("         ", ", ".join(f"{key} {value:.4g}" for key, value in peaks.items()))


if __name__ == "__main__":
    main()
