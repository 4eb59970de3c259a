"""The periodic triaxial element test in YADE: the independent code beside :mod:`membrax.triaxial.periodic`.

Runs YADE (the Debian package ``yade``; ``apt-get install yade``) on a packing given as centres and radii in
a cuboid periodic cell, with membrax's contact law and protocol:

- contact law: linear springs k_n, k_t = ``tangential_ratio`` k_n and Coulomb friction μ = tan φ_μ
  (``Law2_ScGeom_FrictPhys_CundallStrack``). YADE's ``Ip2_FrictMat_FrictMat_FrictPhys`` makes
  k_n = 2 E₁R₁E₂R₂/(E₁R₁ + E₂R₂) and k_t = ν k_n from each material's E ("young") and ν ("poisson", a
  stiffness ratio there, not Poisson's ratio); for equal spheres of radius R, E = k_n/R gives membrax's
  k_n exactly. For a graded packing YADE's k_n varies with the radii while membrax's is one constant: the
  script uses E = k_n/R̄ (R̄ the mean radius) and says so in its output.
- damping: Cundall's local non-viscous damping α (``NewtonIntegrator(damping=α)``), which YADE applies in a
  periodic cell to the velocity's fluctuation about the cell's homogeneous deformation: membrax's
  ``"affine"`` frame;
- protocol (``PeriTriaxController``, goals negative in compression): isotropic consolidation to σc on all
  three axes (``stressMask`` 7) until the unbalanced force ratio is below ``consolidation_tolerance`` and
  each axis is within ``relStressTol`` of σc; then drained compression: axis z at the strain rate ε̇ (to
  ``target_axial_strain``), axes x and y held at σc (``stressMask`` 3);
- records every ``record_every`` steps: axial strain ε_a = −ln(L_z/L_z0), volumetric strain
  ε_v = −ln(V/V0) (both compression positive, logarithmic), the Love–Weber stress of the cell
  (``utils.getStress``: σ = (1/V) Σ f ⊗ l over the contacts, compression positive here), the mean
  coordination number Z = 2 N_c/N and the rattler-free z* (spheres with fewer than 2 contacts dropped
  once, ``utils.avgNumInteractions(skipFree=True)``), the unbalanced-force ratio.

Call :func:`run_yade` from Python (it writes a script and a JSON input to a temporary folder, runs
``yade -n -x`` and reads the records back) or run this file for a quick check on a random periodic packing
that YADE makes itself: ``python examples/yade_periodic.py [--spheres 300] [--strain 0.05]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

#: The script YADE runs: reads ``input.json`` beside it, writes ``records.json``.
YADE_SCRIPT = r"""
import json, math, sys
from yade import utils
from yade.wrapper import *
folder = sys.argv[-1] if sys.argv[-1].endswith("/") else "./"
spec = json.load(open(folder + "input.json"))
O.periodic = True
O.cell.setBox(*spec["box"])
radius = spec["radius"]
mean_radius = sum(radius) / len(radius)
young = spec["normal_stiffness"] / mean_radius
friction = math.radians(spec["friction_deg"])
material = O.materials.append(FrictMat(young=young, poisson=spec["tangential_ratio"], frictionAngle=friction,
                                       density=spec["density"]))
for centre, r in zip(spec["position"], radius):
    O.bodies.append(utils.sphere(centre, r, material=material))
sigma = spec["cell_pressure"]
records = []
phase = {"name": "consolidation", "done": False}
O.engines = [
    ForceResetter(),
    InsertionSortCollider([Bo1_Sphere_Aabb()]),
    InteractionLoop([Ig2_Sphere_Sphere_ScGeom()], [Ip2_FrictMat_FrictMat_FrictPhys()],
                    [Law2_ScGeom_FrictPhys_CundallStrack()]),
    PeriTriaxController(label="triax", goal=(-sigma, -sigma, -sigma), stressMask=7, dynCell=True,
                        maxStrainRate=(spec["max_servo_rate"],) * 3,
                        maxUnbalanced=spec["consolidation_tolerance"], relStressTol=spec["stress_tolerance"],
                        doneHook="phase['done'] = True"),
    NewtonIntegrator(damping=spec["damping"]),
    PyRunner(command="record()", iterPeriod=spec["record_every"]),
]
O.dt = spec["time_step"]
size0 = None
def record():
    global size0
    size = O.cell.size
    if size0 is None:
        size0 = (size[0], size[1], size[2])
    stress = utils.getStress()
    records.append({
        "phase": phase["name"], "step": O.iter,
        "axial_strain": -math.log(size[2] / size0[2]),
        "volumetric_strain": -math.log(size[0] * size[1] * size[2] / (size0[0] * size0[1] * size0[2])),
        "stress": [-stress[0, 0], -stress[1, 1], -stress[2, 2]],
        "coordination": utils.avgNumInteractions(),
        "coordination_no_rattlers": utils.avgNumInteractions(skipFree=True),
        "unbalanced_force_ratio": utils.unbalancedForce(),
        "solid_fraction": sum(4.0 / 3.0 * math.pi * r ** 3 for r in radius) / O.cell.volume,
    })
while not phase["done"] and O.iter < spec["consolidation_max_steps"]:
    O.run(spec["record_every"], True)
consolidated = phase["done"]
record()  # the end of consolidation (the recorder may not have run: a packing already at rest)
phase["name"] = "shear"
size0 = None
record()
rate = spec["strain_rate"]
triax.stressMask = 3
# The controller's strains count from the start of the run: aim beyond the target so that z moves at the
# rate for the whole shear, which the step count ends.
triax.goal = (-sigma, -sigma, triax.strain[2] - 2.0 * spec["target_axial_strain"])
triax.maxStrainRate = (spec["max_servo_rate"], spec["max_servo_rate"], rate)
triax.doneHook = ""
# the box shortens at L̇/L = −ε̇: the steps to the engineering strain 1 − L/L0 = target
steps = int(math.ceil(-math.log(1.0 - spec["target_axial_strain"]) / (rate * O.dt)))
O.run(steps, True)
json.dump({"consolidated": consolidated, "records": records}, open(folder + "records.json", "w"))
"""


def run_yade(
    position,
    radius,
    box,
    cell_pressure: float,
    strain_rate: float,
    target_axial_strain: float,
    time_step: float,
    normal_stiffness: float,
    friction_deg: float,
    density: float = 2650.0,
    tangential_ratio: float = 0.5,
    damping: float = 0.3,
    record_every: int = 1000,
    consolidation_tolerance: float = 1e-3,
    stress_tolerance: float = 1e-3,
    consolidation_max_steps: int = 400_000,
    max_servo_rate: float = 1.0,
) -> dict:
    """Run the periodic element test in YADE; the records as arrays by phase.

    Args:
      position: (N, 3) sphere centres in the cell [0, box), m.
      radius: (N,) radii, m.
      box: (Lx, Ly, Lz), m.
      cell_pressure: σc, Pa (> 0, compression).
      strain_rate: ε̇ of the axial shortening, 1/s.
      target_axial_strain: ε_a = 1 − L_z/L_z0 at the end of shearing.
      time_step: Δt, s (membrax's, so both codes take the same steps).
      normal_stiffness: k_n, N/m.
      friction_deg: φ_μ, degrees.
      density: kg/m³.
      tangential_ratio: k_t/k_n.
      damping: Cundall's α.
      record_every: steps between records.
      consolidation_tolerance: YADE's ``maxUnbalanced`` for the end of consolidation.
      stress_tolerance: ``relStressTol``: each axis within this fraction of σc at its end.
      consolidation_max_steps: steps after which shearing starts whether or not consolidated.
      max_servo_rate: ``maxStrainRate`` of the stress-held axes, 1/s.

    Returns:
      {"consolidated": bool, "consolidation": {field: array}, "shear": {field: array}}; stress (R, 3) Pa.

    Raises:
      FileNotFoundError: no ``yade`` executable on the PATH.
      subprocess.CalledProcessError: YADE failed (its output is in the exception).
    """
    if shutil.which("yade") is None:
        raise FileNotFoundError("yade is not installed: apt-get install yade (Debian).")
    spec = {
        "position": np.asarray(position, float).tolist(),
        "radius": np.asarray(radius, float).tolist(),
        "box": [float(b) for b in box],
        "cell_pressure": float(cell_pressure),
        "strain_rate": float(strain_rate),
        "target_axial_strain": float(target_axial_strain),
        "time_step": float(time_step),
        "normal_stiffness": float(normal_stiffness),
        "friction_deg": float(friction_deg),
        "density": float(density),
        "tangential_ratio": float(tangential_ratio),
        "damping": float(damping),
        "record_every": int(record_every),
        "consolidation_tolerance": float(consolidation_tolerance),
        "stress_tolerance": float(stress_tolerance),
        "consolidation_max_steps": int(consolidation_max_steps),
        "max_servo_rate": float(max_servo_rate),
    }
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "input.json").write_text(json.dumps(spec))
        (folder / "run.py").write_text(YADE_SCRIPT)
        subprocess.run(
            ["yade", "-n", "-x", str(folder / "run.py"), f"{folder}/"],
            check=True,
            capture_output=True,
            text=True,
            cwd=folder,
        )
        result = json.loads((folder / "records.json").read_text())
    phases = {}
    for name in ("consolidation", "shear"):
        rows = [row for row in result["records"] if row["phase"] == name]
        phases[name] = {key: np.asarray([row[key] for row in rows]) for key in rows[0] if key != "phase"}
    return {"consolidated": result["consolidated"], **phases}


def friction_angle_deg(stress) -> np.ndarray:
    """φ' = asin((σ1 − σ3)/(σ1 + σ3)) of (R, 3) stresses, σ1 the axial (z), σ3 the lateral mean, degrees."""
    from membrax.theory import mobilised_friction_angle_deg

    stress = np.asarray(stress)
    axial, lateral = stress[:, 2], 0.5 * (stress[:, 0] + stress[:, 1])
    return np.asarray(mobilised_friction_angle_deg(axial, lateral))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spheres", type=int, default=300)
    parser.add_argument("--strain", type=float, default=0.05)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    # A gas the consolidation compresses (random sequential addition jams near 0.38)
    diameter, solid = 0.025, 0.3
    side = (args.spheres * np.pi / 6 * diameter**3 / solid) ** (1 / 3)
    # Non-overlapping random centres by rejection (a loose gas: few tries per sphere).
    centres = []
    while len(centres) < args.spheres:
        trial = rng.uniform(0.0, side, 3)
        if all(np.linalg.norm((trial - c + 0.5 * side) % side - 0.5 * side) >= diameter for c in centres):
            centres.append(trial)
    stiffness, pressure, density = 1e6, 1e4, 2650.0
    mass = density * np.pi / 6 * diameter**3
    time_step = 0.3 * np.sqrt(mass / stiffness)
    inertial_number = 1e-3
    rate = inertial_number / diameter * np.sqrt(pressure / density)
    out = run_yade(
        centres,
        np.full(args.spheres, 0.5 * diameter),
        (side, side, side),
        pressure,
        rate,
        args.strain,
        time_step,
        stiffness,
        25.0,
    )
    shear = out["shear"]
    angle = friction_angle_deg(shear["stress"])
    print(f"consolidated: {out['consolidated']}; {len(shear['step'])} shear records")
    print(f"{'ε_a':>8}{'ε_v':>9}{'σ1 kPa':>9}{'σ3 kPa':>9}{'φ deg':>8}{'Z':>7}{'z*':>7}")
    for k in range(0, len(angle), max(1, len(angle) // 12)):
        s = shear["stress"][k]
        print(
            f"{shear['axial_strain'][k]:8.4f}{shear['volumetric_strain'][k]:9.4f}{s[2] / 1e3:9.2f}"
            f"{0.5 * (s[0] + s[1]) / 1e3:9.2f}{angle[k]:8.2f}{shear['coordination'][k]:7.2f}"
            f"{shear['coordination_no_rattlers'][k]:7.2f}"
        )
    print(f"peak φ' {np.max(angle):.2f}°, last {angle[-1]:.2f}°")


if __name__ == "__main__":
    main()
