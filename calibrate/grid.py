"""Running a calibration design (:mod:`calibrate.designs`): ``python -m calibrate.grid OUT --design NAME``.

Contract. :func:`run_grid` runs each group of a design with :func:`membrax.sweep.run_sweep` (exactly what
``membrax sweep`` runs) into ``folder/<group>/sweep.nc``, resuming a group interrupted part-way and
skipping one that is done; :func:`sweep_commands` prints the equivalent ``membrax sweep`` command lines.

Archive. A campaign longer than one machine's life (the lab design: about 12 h on 2 cores) keeps each
finished group as ``archive/<group>.nc.gz`` (:func:`membrax.io.write_compressed_copy`; the repository's
``data/sweeps/<design>/``): a group found there is done, on any machine, and its archived sweep is what
:func:`run_grid` returns for it (``membrax fit`` and :func:`membrax.io.read_results` read it as the
``sweep.nc``).

Run: ``python -m calibrate.grid OUT [--design random|random_held_out|protocol_check|fcc|fcc_held_out|lab|
lab_held_out|lab_thin|contact_check] [--groups NAME,NAME] [--archive data/sweeps/lab]``
(one JAX CPU device per core, as ``membrax sweep``), or ``python -m calibrate.grid OUT --scheduler
local|ADDRESS`` to send every group's members to Dask workers at once (:mod:`membrax.campaign`). The lab
design is meant to run so: it is resumable, group by group and member by member.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from calibrate.designs import CALIBRATION, DESIGNS, HELD_OUT, specimen_fields

__all__ = ["find_sweep", "main", "run_grid", "sweep_commands"]


def sweep_commands(groups=None, folder: str = "calibration") -> list[str]:
    """The ``membrax sweep`` command line of each group (the base written as ``--set`` overrides)."""
    from membrax.config import toml_value

    groups = CALIBRATION if groups is None else groups
    lines = []
    for name, (specimen, grid) in groups.items():
        sets = " ".join(
            f"--set {shlex.quote(f'{key}={toml_value(value)}')}"
            for key, value in specimen_fields(specimen).items()
        )
        grids = " ".join(f"--grid {key}={','.join(f'{v:g}' for v in values)}" for key, values in grid.items())
        lines.append(f"membrax sweep base.toml {sets} {grids} --out {folder}/{name}")
    return lines


def run_grid(folder, groups=None, progress: bool = True, scheduler=None, archive=None) -> list[Path]:
    """Run every group of ``groups`` (default :data:`CALIBRATION`) into ``folder/<group>/``.

    A group whose ``sweep.nc`` exists is skipped; one with a checkpoint resumes. With ``scheduler``
    (:func:`membrax.campaign.connect`: ``"local"``, an address or a scheduler file) every group's tasks go
    to one Dask client at once, the groups' sweeps side by side (one thread each waits for its tasks);
    without one the groups run one after another, so each is finished (and archived) before the next.

    With ``archive`` (a folder, module docstring) a group whose ``archive/<group>.nc.gz`` exists is done,
    and each group finished here (or found finished in ``folder``) is copied there compressed.

    Returns:
      The sweep paths, in the order of ``groups``: the archived copy where there is one, else
      ``folder/<group>/sweep.nc``.

    Raises:
      RunError: naming each group whose sweep failed, after the others finished.
    """
    from concurrent.futures import ThreadPoolExecutor

    from membrax import campaign
    from membrax.config import TriaxialConfig
    from membrax.errors import RunError
    from membrax.io.results import write_compressed_copy
    from membrax.sweep import run_sweep

    groups = CALIBRATION if groups is None else groups
    paths = [_sweep_path(folder, archive, name) for name in groups]
    todo = {name: item for (name, item), path in zip(groups.items(), paths, strict=True) if not path.exists()}
    for name, path in zip(groups, paths, strict=True):
        if archive is not None and path == _archived(archive, name):
            _check_archived(path, name, *groups[name])

    def one(name, client=None):
        specimen, grid = todo[name]
        out = Path(folder) / name
        base = TriaxialConfig(name=f"calibration_{name}", **specimen_fields(specimen))
        grid = {k: list(v) for k, v in grid.items()}
        alone = client is None  # side by side, the groups' bars would overwrite each other
        run_sweep(base, grid, out, resume=out.exists(), progress=progress and alone, scheduler=client)
        if archive is not None:
            write_compressed_copy(out / "sweep.nc", _archived(archive, name))

    if archive is not None:  # finished here before an archive was named
        for name in groups:
            finished = Path(folder) / name / "sweep.nc"
            if finished.exists() and not _archived(archive, name).exists():
                write_compressed_copy(finished, _archived(archive, name))
    if scheduler is None:
        for name in todo:
            one(name)
        return [_sweep_path(folder, archive, name) for name in groups]
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
    return [_sweep_path(folder, archive, name) for name in groups]


def find_sweep(folder, name: str) -> Path | None:
    """Group ``name``'s sweep in ``folder`` (an archive or a run folder), or None where it has not run.

    The archived copy ``<name>.nc.gz`` first, else the run's ``<name>/sweep.nc``.
    """
    for path in (_archived(folder, name), Path(folder) / name / "sweep.nc"):
        if path.exists():
            return path
    return None


def _check_archived(path: Path, name: str, specimen: dict, grid: dict) -> None:
    """Refuse an archived sweep that the design no longer describes (its configuration or grid changed).

    The archived configuration is read back through :class:`membrax.config.TriaxialConfig`, so a field
    added to membrax since the group ran counts at its default, as it ran.

    Raises:
      ValueError: naming the group, the fields that differ and the fix.
    """
    from membrax.config import TriaxialConfig, config_to_dict
    from membrax.io.results import dataset_attrs_to_python, read_results

    attrs = dataset_attrs_to_python(read_results(path))
    expected = config_to_dict(TriaxialConfig(name=f"calibration_{name}", **specimen_fields(specimen)))
    archived = config_to_dict(TriaxialConfig(**attrs["base_config"]))
    fields = sorted(key for key in expected if expected[key] != archived.get(key))
    expected_grid = {key: [float(v) for v in values] for key, values in grid.items()}
    archived_grid = {key: [float(v) for v in values] for key, values in attrs["grid"].items()}
    if archived_grid != expected_grid:
        fields.append("the grid")
    if fields:
        raise ValueError(
            f"{path}: the archived sweep of group {name!r} differs from the design in {', '.join(fields)}; "
            "delete the file to run the group again with the design as it is, or restore the design."
        )


def _archived(archive, name: str) -> Path:
    """The compressed copy of group ``name``'s sweep in the folder ``archive``."""
    return Path(archive) / f"{name}.nc.gz"


def _sweep_path(folder, archive, name: str) -> Path:
    """Group ``name``'s sweep: its archived copy if there is one, else ``folder/<name>/sweep.nc``."""
    if archive is not None and _archived(archive, name).exists():
        return _archived(archive, name)
    return Path(folder) / name / "sweep.nc"


def main(argv=None) -> int:
    """``python -m calibrate.grid FOLDER [--design NAME] [--commands]``: run (or print) a design's sweeps.

    Returns the exit status (0).
    """
    parser = argparse.ArgumentParser(prog="python -m calibrate.grid", description=__doc__.split("\n")[0])
    parser.add_argument("folder", help="where each group's sweep folder is written")
    parser.add_argument(
        "--design",
        choices=sorted(DESIGNS),
        default="fcc",
        help="fcc: the FCC calibration grid (the first shipped correction's); random: the random-specimen "
        "grid the previous correction was fitted on; lab: random members at a laboratory's H/D and the "
        "paper's protocol (the shipped correction's); *_held_out: their held-out members; lab_thin: the thin "
        "soft corner at the laboratory's geometry; protocol_check: "
        "random members at the paper's rate and membrane resolution; contact_check: lab members with "
        "the thin membranes' law and face contact",
    )
    parser.add_argument(
        "--held-out", action="store_true", help="the FCC held-out members (--design fcc_held_out)"
    )
    parser.add_argument("--commands", action="store_true", help="print the membrax sweep commands only")
    parser.add_argument(
        "--groups",
        default=None,
        metavar="NAME,NAME",
        help="run only these groups of the design, in this order (default: all, in the design's order)",
    )
    parser.add_argument(
        "--archive",
        default=None,
        metavar="FOLDER",
        help="keep each finished group as FOLDER/<group>.nc.gz, and count a group found there as done "
        "(e.g. data/sweeps/lab)",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS|local",
        help="run the groups' members as tasks on Dask ('local' or a scheduler's address or file)",
    )
    args = parser.parse_args(argv)
    groups = HELD_OUT if args.held_out else DESIGNS[args.design]
    if args.groups is not None:
        names = [name.strip() for name in args.groups.split(",") if name.strip()]
        unknown = [name for name in names if name not in groups]
        if unknown or not names:
            parser.error(
                f"--groups {args.groups!r}: {', '.join(unknown) or 'no names'} not in the design "
                f"{args.design!r}; choose among {', '.join(groups)}"
            )
        groups = {name: groups[name] for name in names}
    if args.commands:
        print("\n".join(sweep_commands(groups, args.folder)))
        return 0
    if args.scheduler is None:
        from membrax.devices import split_cpu_devices

        split_cpu_devices()
    for path in run_grid(args.folder, groups, scheduler=args.scheduler, archive=args.archive):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
