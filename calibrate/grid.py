"""The calibration grid: the membrax sweeps the shipped correction is fitted on, and the held-out tests.

Contract. :data:`CALIBRATION` and :data:`HELD_OUT` are the designs (one source for both): each maps a group
name to ``(specimen, grid)``, the specimen fields over :func:`base_fields` and the ``membrax sweep`` grid
of that specimen. :func:`run_grid` runs each group with :func:`membrax.sweep.run_sweep` (exactly what
``membrax sweep`` runs) into ``folder/<group>/sweep.nc``, resuming a group interrupted part-way and
skipping one that is done; :func:`sweep_commands` prints the equivalent ``membrax sweep`` command lines.

Why these sizes. The particle-to-specimen diameter ratio D/D_s is set by the number of spheres across the
FCC specimen: 6, 8 and 10 across give D/D_s = 1/5.7, 1/7.4 and 1/10 (D_s = √(4A/π) of the platen area),
spanning the issue's 1/6–1/10. Heights keep H/D_s ≈ 1.25 (10, 13 and 17 layers). Every group uses the
small preset of ``membrax reproduce`` (:data:`membrax.reproduce.SIZES` ``"small"``: a membrane of edge D/3,
inertial number 5e-3, float64, consolidation to an unbalanced-force ratio ≤ 1e-3). At paper size the
same nine Table 1 cases take 22 min on 2 cores; this grid's 36 members take a fraction of that, and the extra
stresses depend on the groups the models use (t_m/D, E_m t_m/(σc D), D/D_s, the strains), which the grid
spans, rather than on the specimen's height. The held-out members lie off every grid line: σc 25 and 70
kPa, t_m 2 and 4 mm, E_m 1000 and 2000 kPa, 7 spheres across (D/D_s = 1/7).

Run: ``python -m calibrate.grid OUT [--held-out]`` (one JAX CPU device per core, as ``membrax sweep``), or
``python -m calibrate.grid OUT --scheduler local|ADDRESS`` to send every group's members to Dask workers at
once (:mod:`membrax.campaign`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["base_fields", "CALIBRATION", "HELD_OUT", "run_grid", "sweep_commands"]

#: Cell pressures (kPa), membrane thicknesses (mm) and moduli (kPa) of the calibration grid.
_PRESSURES = (10.0, 40.0, 100.0)

#: group → (specimen fields, sweep grid). D/D_s = 1/5.7, 1/7.4, 1/10 (module docstring).
CALIBRATION = {
    "d6": (
        {"particles_across": 6, "layers": 10},
        {
            "cell_pressure_kpa": _PRESSURES,
            "membrane_thickness_mm": (1.0, 3.0, 5.0),
            "membrane_modulus_kpa": (1400.0, 2800.0),
        },
    ),
    # The softest membrane without its thinnest: at 100 kPa a 1 mm sheet of 700 kPa is above its inflation
    # limit over the lattice's windows (82.7 kPa, membrax.config.inflation_ratio) and is refused.
    "d6_soft": (
        {"particles_across": 6, "layers": 10},
        {
            "cell_pressure_kpa": _PRESSURES,
            "membrane_thickness_mm": (3.0, 5.0),
            "membrane_modulus_kpa": (700.0,),
        },
    ),
    # 2 mm rather than 1 mm: at 100 kPa a 1 mm sheet of 1400 kPa (α/D = 0.38, 0.60 of its inflation limit)
    # went non-finite in shearing on the 8-across specimen as the lattice's windows opened (docs/model.md).
    "d8": (
        {"particles_across": 8, "layers": 13},
        {
            "cell_pressure_kpa": _PRESSURES,
            "membrane_thickness_mm": (2.0, 5.0),
            "membrane_modulus_kpa": (1400.0,),
        },
    ),
    "d10": (
        {"particles_across": 10, "layers": 17},
        {
            "cell_pressure_kpa": _PRESSURES,
            "membrane_thickness_mm": (2.0, 5.0),
            "membrane_modulus_kpa": (1400.0,),
        },
    ),
}

#: Members off every grid line, for the held-out comparison (module docstring).
HELD_OUT = {
    "d7": (
        {"particles_across": 7, "layers": 12},
        {
            "cell_pressure_kpa": (25.0, 70.0),
            "membrane_thickness_mm": (2.0, 4.0),
            "membrane_modulus_kpa": (1000.0, 2000.0),
        },
    ),
}


def base_fields() -> dict:
    """The configuration fields every group shares: the small preset of ``membrax reproduce``.

    A function, not a constant, so that importing this module does not import JAX (``split_cpu_devices``
    must run first).
    """
    from membrax.reproduce import SIZES

    return dict(SIZES["small"])


def sweep_commands(groups=None, folder: str = "calibration") -> list[str]:
    """The ``membrax sweep`` command line of each group (the base written as ``--set`` overrides)."""
    groups = CALIBRATION if groups is None else groups
    lines = []
    for name, (specimen, grid) in groups.items():
        sets = " ".join(f"--set {key}={value}" for key, value in {**base_fields(), **specimen}.items())
        grids = " ".join(f"--grid {key}={','.join(f'{v:g}' for v in values)}" for key, values in grid.items())
        lines.append(f"membrax sweep base.toml {sets} {grids} --out {folder}/{name}")
    return lines


def run_grid(folder, groups=None, progress: bool = True, scheduler=None) -> list[Path]:
    """Run every group of ``groups`` (default :data:`CALIBRATION`) into ``folder/<group>/``.

    A group whose ``sweep.nc`` exists is skipped; one with a checkpoint resumes. With ``scheduler``
    (:func:`membrax.campaign.connect`: ``"local"``, an address or a scheduler file) every group's tasks go
    to one Dask client at once, the groups' sweeps side by side (one thread each waits for its tasks).

    Returns:
      The ``sweep.nc`` paths, in the order of ``groups``.

    Raises:
      RunError: naming each group whose sweep failed, after the others finished.
    """
    from concurrent.futures import ThreadPoolExecutor

    from membrax import campaign
    from membrax.config import TriaxialConfig
    from membrax.errors import RunError
    from membrax.sweep import run_sweep

    groups = CALIBRATION if groups is None else groups
    paths = [Path(folder) / name / "sweep.nc" for name in groups]
    todo = {name: item for (name, item), path in zip(groups.items(), paths, strict=True) if not path.exists()}

    def one(name, client=None):
        specimen, grid = todo[name]
        out = Path(folder) / name
        base = TriaxialConfig(name=f"calibration_{name}", **{**base_fields(), **specimen})
        grid = {k: list(v) for k, v in grid.items()}
        alone = client is None  # side by side, the groups' bars would overwrite each other
        run_sweep(base, grid, out, resume=out.exists(), progress=progress and alone, scheduler=client)

    if scheduler is None:
        for name in todo:
            one(name)
        return paths
    client, cluster, owned = campaign.connect(scheduler)
    try:
        with ThreadPoolExecutor(max_workers=max(1, len(todo))) as pool:
            futures = {name: pool.submit(one, name, client) for name in todo}
        errors = {name: future.exception() for name, future in futures.items() if future.exception()}
    finally:
        if owned:
            client.close()
        if cluster is not None:
            cluster.close()
    if errors:
        raise RunError("\n".join(f"calibration group {name}: {error}" for name, error in errors.items()))
    return paths


def main(argv=None) -> int:
    """``python -m calibrate.grid FOLDER [--held-out] [--commands]``: run (or print) the calibration sweeps.

    Returns the exit status (0).
    """
    parser = argparse.ArgumentParser(prog="python -m calibrate.grid", description=__doc__.split("\n")[0])
    parser.add_argument("folder", help="where each group's sweep folder is written")
    parser.add_argument("--held-out", action="store_true", help="run the held-out members instead")
    parser.add_argument("--commands", action="store_true", help="print the membrax sweep commands only")
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS|local",
        help="run the groups' members as tasks on Dask ('local' or a scheduler's address or file)",
    )
    args = parser.parse_args(argv)
    groups = HELD_OUT if args.held_out else CALIBRATION
    if args.commands:
        print("\n".join(sweep_commands(groups, args.folder)))
        return 0
    if args.scheduler is None:
        from membrax.devices import split_cpu_devices

        split_cpu_devices()
    for path in run_grid(args.folder, groups, scheduler=args.scheduler):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
