"""One member of the thin soft corner (:data:`calibrate.designs.LAB_THIN`) run alone, law by law and contact
by contact: does any of them go non-finite at the start of consolidation?

The member is rebuilt from its group's design at the Δt and mesh its sweep ran with (read from the archived
sweep, ``data/sweeps/lab_thin/<group>.nc.gz``; a batch's members share both) and consolidated for
``--steps`` steps with Gent's law (J_m 97.2 and 1e8, where it is neo-Hookean to 1e-6) and the neo-Hookean
law, each with face and with node contact. Prints one line per variant: finite, or the run's error.

Gent at J_m 97.2 with face contact used to go non-finite here: its candidate table overflowed within a
chunk, the chunk's later steps ran without the dropped contacts, the sheet ran away, and the chunk loop took
an overflow beside a runaway for a runaway. It now grows the tables and reruns such a chunk once
(:func:`membrax.driver.drive`), and every variant runs.

Run: ``python examples/thin_corner_probe.py [--group e6_thin_soft_s2] [--pressure 40] [--steps 5000]``
(about 6 min on 2 CPU cores).
"""

import argparse
import tempfile
import time
import warnings
from pathlib import Path

from calibrate import designs
from membrax.config import TriaxialConfig
from membrax.errors import RunError
from membrax.io import read_results
from membrax.run import run_test

#: (law, contact, J_m): the group's own choice first, then one change at a time.
VARIANTS = (
    ("gent", "faces", 97.2),
    ("gent", "faces", 1e8),
    ("neo-hookean", "faces", 97.2),
    ("gent", "nodes", 97.2),
    ("neo-hookean", "nodes", 97.2),
)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--group", default="e6_thin_soft_s2", choices=sorted(designs.LAB_THIN))
    parser.add_argument("--pressure", type=float, default=40.0, help="σc, kPa")
    parser.add_argument("--steps", type=int, default=5000, help="consolidation steps")
    parser.add_argument(
        "--archive", default=str(Path(__file__).resolve().parents[1] / "data" / "sweeps" / "lab_thin")
    )
    args = parser.parse_args(argv)
    specimen, grid = designs.LAB_THIN[args.group]
    if args.pressure not in grid["cell_pressure_kpa"]:
        parser.error(
            f"--pressure {args.pressure:g}: the group's cell pressures are {grid['cell_pressure_kpa']}"
        )
    sweep = read_results(Path(args.archive) / f"{args.group}.nc.gz").squeeze()
    member = sweep.sel(cell_pressure_kpa=args.pressure)
    # A failed member's variables are NaN; its batch's completed member ran at the same Δt and mesh.
    completed = next(
        sweep.sel(cell_pressure_kpa=p)
        for p in grid["cell_pressure_kpa"]
        if str(sweep.sel(cell_pressure_kpa=p).status.values) == "completed"
    )
    time_step, nodes_around = float(completed.dt_s), int(completed.nodes_around)
    print(
        f"{args.group}, σc = {args.pressure:g} kPa, Δt = {time_step:.4g} s, {nodes_around} nodes around; "
        f"in its sweep: {member.status.values}"
    )
    for law, contact, locking in VARIANTS:
        fields = {**designs.specimen_fields(specimen), "membrane_law": law, "membrane_contact_model": contact}
        config = TriaxialConfig(
            name="probe",
            **{**fields, "membrane_locking_jm": locking},
            cell_pressure_kpa=args.pressure,
            membrane_thickness_mm=grid["membrane_thickness_mm"][0],
            membrane_modulus_kpa=grid["membrane_modulus_kpa"][0],
            consolidation_max_steps=args.steps,
            target_axial_strain=5e-4,
        )
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the inflation warning, expected here
                run_test(
                    config,
                    tempfile.mkdtemp(prefix="probe_"),
                    progress=False,
                    time_step=time_step,
                    nodes_around=nodes_around,
                )
            outcome = "finite"
        except RunError as error:
            outcome = str(error).splitlines()[0]
        jm = f"J_m {locking:g}" if law == "gent" else ""
        print(f"{law:12s} {contact:6s} {jm:10s} {outcome} ({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
