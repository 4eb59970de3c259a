"""Paper-size FCC specimen in a rigid-wall cell at 40 kPa, sheared to 10 % axial strain at two loading rates.

The reference test of the membrane study: 25 mm spheres, 10 across (octagon), 25 layers (1,816 spheres),
φμ = 25°, k_n = 1e7 N/m, k_s = 5e6 N/m, frictionless platens and servo walls held at 40 kPa, local damping
0.3. It consolidates once, then shears from the same consolidated state at inertial numbers 1e-3 and
2.5e-4, recording every 25 steps below 1 % strain (the FCC peak is a spike at 0.01–0.1 %), every 250 after.

Prints, for each rate: the peak mobilised φ' from the Love–Weber (contact) stress and from the walls, the
strain at the peak, the steps and the wall time; writes a CSV per rate and a plot of φ' against strain.

Run: ``python examples/fcc_rigid_walls.py [--out DIR] [--strain 0.10] [--x64] [--width 10 --layers 25]``
(≈ 10 minutes in float32 on a 2-core CPU).
"""

import argparse
import csv
import pathlib
import time

import jax

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="results/fcc_rigid_walls", help="output folder")
parser.add_argument("--strain", type=float, default=0.10, help="target axial strain (fraction)")
parser.add_argument("--rates", type=float, nargs="+", default=[1e-3, 2.5e-4], help="inertial numbers")
parser.add_argument("--width", type=int, default=10, help="spheres across")
parser.add_argument("--layers", type=int, default=25, help="layers")
parser.add_argument("--cell-pressure-kpa", type=float, default=40.0)
parser.add_argument("--x64", action="store_true", help="run in float64")
args = parser.parse_args()
if args.x64:
    jax.config.update("jax_enable_x64", True)

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from membrax import theory  # noqa: E402
from membrax.spheres import fcc  # noqa: E402
from membrax.triaxial import rigid as triaxial  # noqa: E402

out = pathlib.Path(args.out)
out.mkdir(parents=True, exist_ok=True)
cell_pressure = args.cell_pressure_kpa * 1e3
specimen = fcc.fcc_specimen(0.025, args.width, args.layers)
print(specimen.summary())
start = time.perf_counter()
test = triaxial.rigid_wall_test(specimen, cell_pressure)
print(f"critical time step {test.critical_dt:.3e} s (rotation included), dt = {test.dt:.3e} s")


def progress(total_steps, label):
    bar = tqdm(total=total_steps, desc=label, unit="step", mininterval=5.0)

    def on_chunk(state, records):
        bar.n = min(int(state.step) - bar_start[0], total_steps)
        strain = float(records.axial_strain[-1, 0])
        phi = float(records.love_weber_friction_angle[-1, 0])
        bar.set_postfix(strain=f"{100 * strain:.3f}%", phi=f"{phi:.1f}")
        bar.refresh()

    bar_start = [0]
    return bar, bar_start, on_chunk


bar, bar_start, on_chunk = progress(200_000, "consolidation")
consolidated, consolidation = test.consolidate(on_chunk=on_chunk)
bar.close()
consolidation_steps = int(consolidated.step)
print(
    f"consolidation: {consolidation_steps} steps, {time.perf_counter() - start:.0f} s, "
    f"unbalanced force ratio {consolidation.unbalanced_force_ratio[-1, 0]:.2e}, "
    f"walls {consolidation.wall_axial_stress[-1, 0] / 1e3:.2f} / "
    f"{consolidation.wall_radial_stress[-1, 0] / 1e3:.2f} kPa"
)

rowe = float(theory.rowe_peak_friction_angle_deg(25.0))
fig, ax = plt.subplots(figsize=(7, 4.5))
summary = []
for inertial_number in args.rates:
    rate = triaxial.strain_rate_from_inertial_number(inertial_number, 0.025, test.density, cell_pressure)
    steps_expected = int(args.strain / (rate * test.dt))
    bar, bar_start, on_chunk = progress(steps_expected, f"shear I={inertial_number:g}")
    bar_start[0] = consolidation_steps
    t0 = time.perf_counter()
    state, records = test.shear(
        consolidated, target_axial_strain=args.strain, inertial_number=inertial_number, on_chunk=on_chunk
    )
    bar.close()
    wall_time = time.perf_counter() - t0
    steps = int(state.step) - consolidation_steps
    lw_peak, lw_strain = triaxial.peak(records)
    wall_peak, wall_strain = triaxial.peak(records, "wall_friction_angle")
    summary.append((inertial_number, lw_peak, lw_strain, wall_peak, wall_strain, steps, wall_time))
    print(
        f"I = {inertial_number:g}: peak φ' Love–Weber {lw_peak:.2f}° at {100 * lw_strain:.3f} %, "
        f"walls {wall_peak:.2f}° at {100 * wall_strain:.3f} %; {steps} steps in {wall_time:.0f} s "
        f"({steps / wall_time:.0f} steps/s)"
    )
    name = out / f"shear_I{inertial_number:g}.csv"
    fields = [
        "step",
        "axial_strain",
        "volumetric_strain",
        "wall_axial_stress",
        "wall_radial_stress",
        "love_weber_axial_stress",
        "love_weber_radial_stress",
        "wall_friction_angle",
        "love_weber_friction_angle",
        "unbalanced_force_ratio",
        "coordination_number",
    ]
    with open(name, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(fields)
        for k in range(records.step.shape[0]):
            writer.writerow([float(np.asarray(getattr(records, f))[k, 0]) for f in fields])
    strain = 100 * np.asarray(records.axial_strain)[:, 0]
    ax.plot(
        strain,
        np.asarray(records.love_weber_friction_angle)[:, 0],
        label=f"Love–Weber, I = {inertial_number:g}",
    )
    ax.plot(
        strain, np.asarray(records.wall_friction_angle)[:, 0], "--", label=f"walls, I = {inertial_number:g}"
    )

ax.axhline(rowe, color="grey", lw=0.8, label=f"Rowe (tan α = 2): {rowe:.2f}°")
ax.set(
    xscale="symlog",
    xlabel="axial strain (%)",
    ylabel="mobilised φ' (°)",
    title=f"FCC, {specimen.num_particles} spheres, rigid walls, {args.cell_pressure_kpa:g} kPa",
)
ax.legend(fontsize=8)
fig.savefig(out / "phi_vs_strain.png", dpi=130, bbox_inches="tight")
print(f"\n{'I':>8}{'LW peak':>9}{'at %':>8}{'wall peak':>11}{'at %':>8}{'steps':>9}{'wall s':>8}")
for row in summary:
    i_num, lw, lws, wp, wps, steps, secs = row
    print(f"{i_num:>8g}{lw:>9.2f}{100 * lws:>8.3f}{wp:>11.2f}{100 * wps:>8.3f}{steps:>9d}{secs:>8.0f}")
print(f"results in {out}/ (total {time.perf_counter() - start:.0f} s)")
