"""Spheres only, side by side with a peer: the same confined FCC block stepped by LIGGGHTS and by membrax.

The block: 25 mm spheres (2,650 kg/m³) on a cubic FCC lattice of 15 × 15 × 15 sites (1,688 spheres, faces
{100}), in a box of six smooth planes touching its outer spheres; the radii are grown by 0.1 % so that every
lattice and wall contact is closed (overlaps of 25 µm, ~250 N). Uniformly compressed in a rigid box the
lattice is in equilibrium, so the contacts stay closed through the run and both codes do the full contact
work every step (a free block would fly apart within a few hundred steps). The contact law is the linear
one in both: k_n = 1e7 N/m, k_t = 5e6 N/m (spheres and walls), Coulomb friction tan 25° between spheres, no
contact damping (LIGGGHTS ``gran model hooke/stiffness tangential history`` and ``fix wall/gran`` planes;
membrax's :mod:`membrax.spheres.contact` with its platens and four lateral planes, Cundall damping off). The
time step is membrax's for the block, the same in both; no gravity.

Prints, for each: steps/s and particle-steps/s (best of ``--repeats`` runs of ``--steps`` steps; LIGGGHTS's
own "Loop time", which leaves out its set-up), and membrax's figure over each LIGGGHTS one. LIGGGHTS runs
on one MPI process and on ``--processes`` (default 2); membrax in float32 and float64, each in a fresh
process, on one CPU device (XLA's threads use the cores).

LIGGGHTS: the Debian package (``apt-get install liggghts``; ``mpirun`` comes with it). Without a
``liggghts`` executable on the PATH the script says so and measures membrax only.

Run: ``python benchmarks/bench_liggghts.py [--steps 2000] [--processes 2]`` (about 3 min on 2 cores).
"""

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from harness import benchmark_parser, benchmark_rows, best_of, print_table, timed

DIAMETER, DENSITY = 0.025, 2650.0
NORMAL_STIFFNESS, TANGENTIAL_STIFFNESS, FRICTION_DEG = 1e7, 5e6, 25.0
GROWTH = 1.001  # closes every lattice contact


SITES = 15  # lattice sites along each edge


def block():
    """(centres (N, 3) m, grown radius m, half width of the box m, box height m) of the confined block.

    Sites (i, j, k) with i + j + k even on a cubic grid of spacing R√2 (nearest neighbours 2R apart), centred
    on the z axis and standing on z = 0; the box's planes touch the outer spheres of radius R.
    """
    import numpy as np

    radius = 0.5 * DIAMETER
    spacing = radius * np.sqrt(2.0)
    sites = np.stack(np.meshgrid(*[np.arange(SITES)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    sites = sites[sites.sum(axis=1) % 2 == 0]
    position = spacing * sites.astype(float)
    position[:, :2] -= 0.5 * spacing * (SITES - 1)
    position[:, 2] += radius
    half_width = 0.5 * spacing * (SITES - 1) + radius
    return position, radius * GROWTH, half_width, spacing * (SITES - 1) + 2 * radius


def measure_membrax(dtype: str, steps: int, repeats: int) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from membrax import native
    from membrax.spheres.contact import ContactParams
    from membrax.spheres.integrate import DampingParams, DEMParams, make_particles, sphere_dem
    from membrax.spheres.neighbors import pair_neighbor_fn
    from membrax.spheres.stability import critical_time_step
    from membrax.spheres.walls import triaxial_walls

    position, radius, half_width, height = block()
    radii = jnp.full(position.shape[0], radius)
    particles = make_particles(radii, DENSITY)
    lower, upper = position.min(axis=0) - 2 * DIAMETER, position.max(axis=0) + 2 * DIAMETER
    frame = pair_neighbor_fn(lower, upper, cutoff=2 * radius, skin=0.2 * DIAMETER, margin=DIAMETER)
    normals = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])  # counter-clockwise
    walls = triaxial_walls(normals, np.full(4, half_width), height)
    contact = ContactParams.paper(
        friction_angle_deg=FRICTION_DEG,
        normal_stiffness=NORMAL_STIFFNESS,
        tangential_stiffness=TANGENTIAL_STIFFNESS,
    )
    params = DEMParams(contact=contact, damping=DampingParams.none())
    x = jnp.asarray(position)
    init_fn, _ = sphere_dem(particles, frame, 1.0, wall_friction=False)
    state = init_fn(x, walls, frame.allocate(x))
    dt = 0.5 * critical_time_step(state, particles, params)
    _, step_fn = sphere_dem(particles, frame, dt, wall_friction=False)
    run = jax.jit(  # compiled as membrax compiles a run's chunks
        lambda s: jax.lax.fori_loop(0, steps, lambda _, y: step_fn(y, params), s),
        compiler_options=native.compiler_options(),
    )
    _, first = timed(run, state)
    total = best_of(run, state, runs=repeats)
    return {
        "code": f"membrax {dtype}",
        "dtype": dtype,
        "spheres": int(position.shape[0]),
        "dt": dt,
        "compile_s": first - total,
        "steps_per_s": steps / total,
        "particle_steps_per_s": steps * position.shape[0] / total,
    }


LIGGGHTS_INPUT = """\
atom_style granular
atom_modify map array
boundary f f f
newton off
communicate single vel yes
units si
region domain block {xlo} {xhi} {ylo} {yhi} {zlo} {zhi} units box
create_box 1 domain
neighbor {skin} bin
neigh_modify delay 0
fix m1 all property/global kn peratomtypepair 1 {kn}
fix m2 all property/global kt peratomtypepair 1 {kt}
fix m3 all property/global gamman peratomtypepair 1 0.0
fix m4 all property/global gammat peratomtypepair 1 0.0
fix m5 all property/global coefficientFriction peratomtypepair 1 {friction}
pair_style gran model hooke/stiffness tangential history
pair_coeff * *
fix xlow all wall/gran model hooke/stiffness tangential history primitive type 1 xplane {wlo}
fix xhigh all wall/gran model hooke/stiffness tangential history primitive type 1 xplane {whi}
fix ylow all wall/gran model hooke/stiffness tangential history primitive type 1 yplane {wlo}
fix yhigh all wall/gran model hooke/stiffness tangential history primitive type 1 yplane {whi}
fix zlow all wall/gran model hooke/stiffness tangential history primitive type 1 zplane 0.0
fix zhigh all wall/gran model hooke/stiffness tangential history primitive type 1 zplane {height}
{atoms}
set group all diameter {diameter} density {density}
timestep {dt}
fix integrate all nve/sphere
thermo {steps}
run {steps}
"""


def measure_liggghts(processes: int, steps: int, repeats: int, dt: float) -> dict:
    import math

    position, radius, half_width, height = block()
    lower, upper = position.min(axis=0) - 2 * DIAMETER, position.max(axis=0) + 2 * DIAMETER
    text = LIGGGHTS_INPUT.format(
        xlo=lower[0], xhi=upper[0], ylo=lower[1], yhi=upper[1], zlo=lower[2], zhi=upper[2],
        skin=0.2 * DIAMETER, kn=NORMAL_STIFFNESS, kt=TANGENTIAL_STIFFNESS,
        friction=math.tan(math.radians(FRICTION_DEG)),
        atoms="\n".join(f"create_atoms 1 single {x:.9g} {y:.9g} {z:.9g} units box" for x, y, z in position),
        diameter=2 * radius, density=DENSITY, dt=dt, steps=steps, wlo=-half_width, whi=half_width,
        height=height,
    )  # fmt: skip
    folder = Path(tempfile.mkdtemp(prefix="membrax_liggghts_"))
    (folder / "in.block").write_text(text)
    command = ["liggghts", "-in", "in.block", "-log", "none", "-echo", "none"]
    if processes > 1:
        command = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(processes), *command]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    loops = []
    for _ in range(repeats):
        done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, check=False)
        pattern = r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms"
        found = re.search(pattern, done.stdout)
        if done.returncode != 0 or found is None:
            raise RuntimeError(f"LIGGGHTS failed ({done.returncode}): {(done.stdout + done.stderr)[-2000:]}")
        if int(found[4]) != position.shape[0]:
            raise RuntimeError(f"LIGGGHTS ran {found[4]} atoms, not {position.shape[0]}")
        loops.append(float(found[1]))
    shutil.rmtree(folder, ignore_errors=True)
    seconds = min(loops)
    return {
        "code": f"LIGGGHTS {processes} proc",
        "dtype": "float64",
        "spheres": int(position.shape[0]),
        "dt": dt,
        "compile_s": 0.0,
        "steps_per_s": steps / seconds,
        "particle_steps_per_s": steps * position.shape[0] / seconds,
    }


def main():
    parser = benchmark_parser(__doc__)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--processes", type=int, default=2)
    args, rows = benchmark_rows(__file__, parser, measure_membrax, flags=("steps", "repeats"))
    if rows is None:
        return
    peers = []
    if shutil.which("liggghts") is None:
        print("LIGGGHTS is not installed (Debian: apt-get install liggghts); membrax only.")
    else:
        for processes in sorted({1, args.processes}):
            peers.append(measure_liggghts(processes, args.steps, args.repeats, rows[0]["dt"]))
    print(
        f"{rows[0]['spheres']} spheres, Hooke contacts k_n {NORMAL_STIFFNESS:g} N/m, "
        f"k_t {TANGENTIAL_STIFFNESS:g} N/m, friction tan {FRICTION_DEG:g}°, dt {rows[0]['dt']:.3g} s, "
        f"{args.steps} steps"
    )
    for row in rows + peers:
        ratios = [row["particle_steps_per_s"] / peer["particle_steps_per_s"] for peer in peers]
        row["versus"] = " ".join(f"{ratio:5.2f}" for ratio in ratios) or "-"
    print_table(
        rows + peers,
        "code|compile s|steps/s|particle-steps/s|÷ " + (" / ".join(p["code"] for p in peers) or "peer"),
        "{code:>18}{compile_s:>10.1f}{steps_per_s:>9.0f}{particle_steps_per_s:>17.3g}{versus:>36}",
    )


if __name__ == "__main__":
    main()
