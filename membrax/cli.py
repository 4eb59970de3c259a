"""The ``membrax`` command.

Contract: ``main(argv)`` parses ``argv`` (default ``sys.argv[1:]``), runs one sub-command, prints its
report on standard output and returns a process exit code (0 on success).

Sub-commands:
  theory   the closed-form reference table (Rowe, Bolton, Molenkamp & Luger, ASTM shell correction)
  demo     the main job on a small default: the theory table, then a membrane triaxial test of a small
           FCC specimen (6 spheres across, 10 layers) at 10 kPa in a 5 mm membrane to 10 % axial strain
           (:data:`membrax.config.DEMO_CONFIG`), written to ``results_demo/`` (:mod:`membrax.run`)
  run      ``membrax run config.toml [--out DIR] [--set key=value] [--resume]``: the test of a TOML
           configuration (:mod:`membrax.config`) into a results folder
  sweep    ``membrax sweep config.toml --grid cell_pressure_kpa=10,40,100 --grid membrane_thickness_mm=2.5,5
           [--out DIR] [--set key=value] [--resume] [--devices N] [--scheduler ADDRESS|local]``: the grid
           as one batched compiled simulation, or as tasks on Dask workers (:mod:`membrax.sweep`)
  reproduce ``membrax reproduce [--size small|paper]``: the paper's Table 1, then its Tables 2–3 and
           Figs 5–9 (:mod:`membrax.reproduce`)
  sensitivity ``membrax sensitivity config.toml [--wrt membrane_modulus_kpa,membrane_thickness_mm]
           [--outputs internal_axial_stress,...] [--no-check]``: the consolidated equilibrium's derivatives
           by implicit differentiation, each beside its finite-difference check and its elasticity
           (:mod:`membrax.sensitivities`)
  fit      ``membrax fit sweep.nc [more.nc] [--out corrections.json] [--model paper|rich]``: a membrane
           correction fitted on sweeps (:mod:`calibrate.workflow`)
  correct  ``membrax correct lab.csv --specimen-diameter-mm 150 --particle-size-mm 20
           --membrane-thickness-mm 2 --membrane-modulus-kpa 1400 [--specimen-height-mm 300]
           [--model corrections.json] [--out X.csv]``:
           a laboratory record corrected by none, the classical three and the fitted correction, as a CSV
           and a plot (:mod:`calibrate.correct`)

``fit``, ``correct`` and ``serve`` (their options, help and handlers) are in :mod:`membrax.cli_calibrate`;
it and this module are the one place membrax reaches :mod:`calibrate`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from membrax import __version__, cli_calibrate, paper, theory
from membrax.config import DEMO_CONFIG


def _rule(title: str) -> str:
    return f"\n{title}\n{'-' * len(title)}"


def theory_report() -> str:
    """The closed-form reference table as text (what ``membrax theory`` prints)."""
    lines = [f"membrax {__version__}: closed-form theory (membrax.theory)"]

    lines.append(
        _rule(f"Rowe (1962), FCC, cube axis vertical, phi_mu = {paper.INTERPARTICLE_FRICTION_DEG:g} deg")
    )
    lines.append(f"{'convention':<34}{'tan(alpha)':>11}{'R':>9}{'phi_peak (deg)':>16}")
    for label, packing in (
        ("exact: tan(alpha) = 2, beta = 45", theory.FCC),
        ("paper: alpha = 63.5, beta = 45", theory.FCC_PAPER),
    ):
        friction = np.deg2rad(paper.INTERPARTICLE_FRICTION_DEG)
        ratio = float(theory.rowe_stress_ratio(friction, packing))
        phi = float(theory.rowe_peak_friction_angle_deg(paper.INTERPARTICLE_FRICTION_DEG, packing))
        lines.append(f"{label:<34}{packing.tan_alpha:>11.4f}{ratio:>9.4f}{phi:>16.2f}")

    density = float(
        theory.relative_density(
            paper.BALLAST_VOID_RATIO, paper.BALLAST_VOID_RATIO_MIN, paper.BALLAST_VOID_RATIO_MAX
        )
    )
    lines.append(
        _rule(
            f"Bolton (1986) and the paper's Eq. 1: phi_crit = {paper.BALLAST_CRITICAL_FRICTION_DEG:g} deg, "
            f"e_min = {paper.BALLAST_VOID_RATIO_MIN:g}, e_max = {paper.BALLAST_VOID_RATIO_MAX:g}, "
            f"e = {paper.BALLAST_VOID_RATIO:g} "
            f"(I_D = {density:.4f})"
        )
    )
    lines.append(
        f"{'p (kPa)':>8}{'I_R':>9}{'Bolton':>9}{'clipped I_R<=4':>16}{'Eq. 1':>9}{'I_R=5I_D-1':>15}   (deg)"
    )
    for pressure in paper.PAPER_CELL_PRESSURES_KPA:
        index = float(theory.relative_dilatancy_index(density, pressure))
        bolton = float(
            theory.bolton_peak_friction_angle_deg(paper.BALLAST_CRITICAL_FRICTION_DEG, density, pressure)
        )
        clipped = float(
            theory.bolton_peak_friction_angle_deg(
                paper.BALLAST_CRITICAL_FRICTION_DEG, density, pressure, clip=True
            )
        )
        floored = float(
            theory.bolton_peak_friction_angle_deg(
                paper.BALLAST_CRITICAL_FRICTION_DEG, density, pressure, low_pressure_rule=True
            )
        )
        eq1 = float(
            theory.paper_eq1_peak_friction_angle_deg(paper.BALLAST_CRITICAL_FRICTION_DEG, density, pressure)
        )
        lines.append(f"{pressure:>8g}{index:>9.4f}{bolton:>9.2f}{clipped:>16.2f}{eq1:>9.2f}{floored:>15.2f}")
    lines.append("Eq. 1 is Bolton's form + 2 deg (it subtracts 1 where Bolton subtracts 3), with no I_R cap.")
    lines.append("I_R=5I_D-1: the post-publication advice for p' < 150 kPa (low_pressure_rule=True).")

    lines.append(
        _rule(
            f"Molenkamp & Luger indentation ratio alpha/D, C = 0.275, D = {paper.PARTICLE_DIAMETER_MM:g} mm, "
            f"E_m = {paper.MEMBRANE_MODULUS_KPA:g} kPa, FCC e = {theory.FCC_VOID_RATIO:.4f}"
        )
    )
    header = "".join(f"{f't_m = {t:.2f} mm':>16}" for t in paper.PAPER_THICKNESSES_MM)
    lines.append(f"{'p (kPa)':>8}{header}")
    any_invalid = False
    for pressure in paper.PAPER_CELL_PRESSURES_KPA:
        cells = []
        for thickness in paper.PAPER_THICKNESSES_MM:
            args = (
                theory.FCC_VOID_RATIO,
                paper.PARTICLE_DIAMETER_MM,
                thickness,
                pressure,
                paper.MEMBRANE_MODULUS_KPA,
            )
            ratio = float(theory.molenkamp_luger_indentation_ratio(*args))
            valid = bool(theory.molenkamp_luger_validity(*args).valid)
            any_invalid |= not valid
            cells.append(f"{ratio:>15.4f}{'' if valid else '*'}")
        lines.append(f"{pressure:>8g}" + "".join(f"{c:>16}" for c in cells))
    if any_invalid:
        lines.append("* outside the stated validity (t_m/D < 0.2 and alpha/D > 0.2).")

    from membrax.defaults import GENT_LOCKING_JM

    aperture_mm = 0.5 * theory.SQUARE_WINDOW_RATIO * paper.PARTICLE_DIAMETER_MM
    soft_jm = 0.5 * theory.GENT_MONOTONIC_LOCKING_JM
    lines.append(
        _rule(
            f"Inflation limit over the square window of {paper.PARTICLE_DIAMETER_MM:g} mm spheres, "
            f"a = {aperture_mm:.2f} mm (kPa; none: the pressure-bulge curve has no maximum)"
        )
    )
    lines.append(
        f"{'t_m (mm)':>9}{'E_m (kPa)':>11}{'neo-Hookean':>13}{f'Gent J_m={GENT_LOCKING_JM:g}':>18}"
        f"{f'Gent J_m={soft_jm:.3g}':>18}"
    )
    # The calibration grid's thin corners, then the paper's membranes.
    paper_membranes = tuple((t, paper.MEMBRANE_MODULUS_KPA) for t in paper.PAPER_THICKNESSES_MM)
    membranes = ((1.0, 700.0), (1.0, 1400.0), *paper_membranes)
    for thickness, modulus in membranes:
        cells = [theory.membrane_limit_pressure(modulus, thickness, aperture_mm)]
        for locking in (GENT_LOCKING_JM, soft_jm):
            cells.append(theory.gent_membrane_limit_pressure(modulus, thickness, aperture_mm, locking))
        shown = "".join(
            f"{(f'{float(c):.1f}' if np.isfinite(float(c)) else 'none'):>{w}}"
            for c, w in zip(cells, (13, 18, 18), strict=True)
        )
        lines.append(f"{thickness:>9.2f}{modulus:>11g}{shown}")

    strain = 0.05
    lines.append(
        _rule(
            f"ASTM D4767/D7181 shell correction 4 E_m t_m eps_a / D at eps_a = {strain:.0%}, "
            f"D = {paper.SPECIMEN_DIAMETER_MM:g} mm, E_m = {paper.MEMBRANE_MODULUS_KPA:g} kPa"
        )
    )
    lines.append(f"{'t_m (mm)':>9}{'delta sigma_1 (kPa)':>21}")
    for thickness in paper.PAPER_THICKNESSES_MM:
        correction = theory.astm_shell_correction(
            paper.MEMBRANE_MODULUS_KPA, thickness / 1000.0, paper.SPECIMEN_DIAMETER_MM / 1000.0, strain
        )
        lines.append(f"{thickness:>9.2f}{float(correction.axial_stress):>21.4f}")
    return "\n".join(lines)


def _theory(_: argparse.Namespace) -> int:
    print(theory_report())
    return 0


def _run_config(config, out, resume: bool, progress: bool) -> int:
    from membrax.errors import RunError
    from membrax.run import run_test

    try:
        result = run_test(config, out, resume=resume, progress=progress)
    except (RunError, FileNotFoundError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    print(result.summary)
    print(f"\nresults in {result.folder}: " + ", ".join(sorted(p.name for p in result.folder.iterdir())))
    return 0


def _load_config(args: argparse.Namespace):
    """The TOML configuration of ``args.config`` with the ``--set key=value`` overrides applied."""
    from membrax.config import load_config, parse_overrides, with_overrides

    config = load_config(args.config)
    return with_overrides(config, **parse_overrides(args.set)) if args.set else config


def _run(args: argparse.Namespace) -> int:
    from membrax.errors import ConfigError
    from membrax.run import default_folder

    try:
        config = _load_config(args)
    except (ConfigError, FileNotFoundError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    out = args.out if args.out is not None else default_folder(config)
    args.folder_in_use = out  # for main's word on an interrupted run
    return _run_config(config, out, args.resume, not args.no_progress)


def _split_cpu(args: argparse.Namespace) -> bool:
    """One CPU device per core (or ``--devices``) before anything starts JAX; False on a bad count."""
    from membrax.devices import split_cpu_devices

    try:
        split_cpu_devices(args.devices)
    except ValueError as error:
        print(f"membrax: --devices: {error}", file=sys.stderr)
        return False
    return True


def _campaign_options(args: argparse.Namespace) -> dict:
    """The options ``sweep`` and ``reproduce`` share (resume, progress, devices, Dask), as keywords."""
    return dict(
        resume=args.resume,
        progress=not args.no_progress,
        num_devices=args.devices,
        scheduler=args.scheduler,
        members_per_task=args.task_members,
    )


def _sweep(args: argparse.Namespace) -> int:
    if not _split_cpu(args):
        return 2
    from membrax.errors import ConfigError, RunError
    from membrax.sweep import default_folder, parse_grid, run_sweep

    try:
        config = _load_config(args)
        grid = parse_grid(args.grid) if args.grid else None
        args.folder_in_use = args.out if args.out is not None else default_folder(config)
        result = run_sweep(
            config,
            grid,
            args.folder_in_use,
            **_campaign_options(args),
        )
    except (ConfigError, FileNotFoundError, ValueError, RunError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    print((result.folder / "summary.csv").read_text())
    print(f"{result.seconds:.0f} s; results in {result.folder}: " + ", ".join(sorted(result.files)))
    failed = [str(status) for status in result.dataset["status"].values.ravel() if status != "completed"]
    if failed:
        print(
            f"membrax: {len(failed)} member(s) failed; see the status column of summary.csv", file=sys.stderr
        )
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    if not _split_cpu(args):
        return 2
    from membrax.config import parse_overrides
    from membrax.errors import ConfigError, RunError
    from membrax.reproduce import default_folder, reproduce

    args.folder_in_use = args.out or default_folder(args.size, args.packing, args.grading, args.state)
    try:
        done = reproduce(
            args.size,
            args.out,
            **_campaign_options(args),
            overrides=parse_overrides(args.set),
            packing=args.packing,
            seeds=args.seeds,
            reference_folder=args.reference,
            grading=args.grading,
            state=args.state,
        )
    except (ConfigError, ValueError, RunError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    print(done["files"]["report"].read_text())
    if args.packing == "random":
        cli_calibrate.random_correlations(done)
    print(f"results in {done['folder']}")
    return 0


def _sensitivity(args: argparse.Namespace) -> int:
    from membrax.errors import ConfigError
    from membrax.sensitivities import OUTPUTS, PARAMETERS, format_table, sensitivity

    try:
        config = _load_config(args)
        wrt = tuple(args.wrt.split(",")) if args.wrt else tuple(PARAMETERS)
        outputs = tuple(args.outputs.split(",")) if args.outputs else OUTPUTS
        table = sensitivity(config, outputs, wrt, finite_differences=not args.no_check)
    except (FileNotFoundError, ValueError, ConfigError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    print(format_table(table))
    return 0


def _demo(args: argparse.Namespace) -> int:
    from membrax.config import DEMO_RANDOM_CONFIG, TriaxialConfig

    print(theory_report())
    preset = dict(DEMO_CONFIG, **DEMO_RANDOM_CONFIG) if args.packing == "random" else DEMO_CONFIG
    out = args.out if args.out is not None else f"results_{preset['name']}"
    args.folder_in_use = out
    return _run_config(TriaxialConfig(**preset), out, args.resume, not args.no_progress)


#: Each sub-command's ``--help``: what it does (description) and examples (epilog), printed as written.
SUBCOMMAND_HELP = {
    "theory": (
        "Print the closed-form reference table: Rowe's FCC peak friction angle (both alpha conventions),\n"
        "Bolton and the paper's Eq. 1 for its ballast, Molenkamp & Luger's indentation ratio over the\n"
        "paper's 3 x 3 grid, and the ASTM shell correction for its three membranes. No simulation.",
        "example:\n  membrax theory",
    ),
    "demo": (
        "Print the theory table, then run the membrane triaxial test on a small FCC specimen (6 spheres\n"
        "across, 10 layers, membrane edge D/3) at 10 kPa in a 5 mm membrane: consolidation, then drained\n"
        "shearing to 10 % axial strain (about a minute on 2 CPU cores). Writes results.nc/.csv,\n"
        "consolidation.nc/.csv, the Figs 5-8 PNGs, summary.md and a checkpoint into --out.",
        "examples:\n"
        "  membrax demo\n"
        "  membrax demo --out my_demo --no-progress\n"
        "  membrax demo --out my_demo --resume      # continue an interrupted demo from its checkpoint\n"
        "  membrax demo --packing random            # the same test on a random packing of equal spheres",
    ),
    "run": (
        "Run the membrane triaxial test of a TOML configuration (membrax.config.TriaxialConfig: each\n"
        "field named with its unit, e.g. cell_pressure_kpa, membrane_thickness_mm; keys left out take the\n"
        "paper's values; bad values are refused before anything compiles) into a results folder:\n"
        "results.nc/.csv, consolidation.nc/.csv, Figs 5-8, summary.md, config.toml, checkpoint.npz.",
        "example:\n"
        "  $ cat test.toml\n"
        '  name = "test40"\n'
        "  cell_pressure_kpa = 40.0\n"
        "  membrane_thickness_mm = 2.5\n"
        "  particles_across = 6\n"
        "  layers = 10\n"
        "  $ membrax run test.toml --set target_axial_strain=0.05      # writes results_test40/\n"
        "  $ membrax run test.toml --resume                            # after an interruption",
    ),
    "sweep": (
        "Run every combination of the --grid values over a base configuration as one batched, compiled\n"
        "simulation (one JAX device per CPU core, members sharded over the devices), and write sweep.nc\n"
        "(dimensions: the grid's fields and record), sweep_consolidation.nc, summary.csv, sweep.toml.",
        "examples:\n"
        "  membrax sweep test.toml --grid cell_pressure_kpa=10,40,100 \\\n"
        "      --grid membrane_thickness_mm=2.5,3.33,5\n"
        "  membrax sweep test.toml --grid membrane_modulus_kpa=700,1400,2800 --out study --devices 2\n"
        "  membrax sweep test.toml --scheduler local             # a Dask worker process per core\n"
        "  membrax sweep test.toml --scheduler tcp://head:8786 --out /shared/study  # a cluster\n"
        "  membrax sweep test.toml --scheduler local --resume    # after an interruption",
    ),
    "reproduce": (
        "Run the paper's Table 1 (10, 40, 100 kPa x 2.5, 3.33, 5 mm) as one sweep, then write its Tables\n"
        "2-3 beside the paper's (table2/table3 .csv and .md), Figs 5-9 and reproduction.md.",
        "examples:\n"
        "  membrax reproduce --size small                        # about 3 min on 2 CPU cores\n"
        "  membrax reproduce --size small --packing random       # 3 seeds per case, 5 min; beside the\n"
        "                                                        # FCC run in results_reproduce_small\n"
        "  membrax reproduce --size paper --out paper_run        # 14–18 min on 2 CPU cores\n"
        "  membrax reproduce --size paper --scheduler tcp://head:8786 --out /shared/paper_run",
    ),
}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``membrax`` command."""
    parser = argparse.ArgumentParser(
        prog="membrax",
        description="Differentiable triaxial-test simulator for membrane corrections.",
        epilog="examples:\n"
        "  membrax demo                      # a small membrane triaxial test, about a minute\n"
        "  membrax theory                    # the closed-form reference table\n"
        "  membrax run --help                # each sub-command's own help, with examples",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"membrax {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("theory", help="print the closed-form reference table").set_defaults(func=_theory)
    demo = commands.add_parser(
        "demo", help="the main job on a small default: a 6 × 10-layer membrane triaxial test to 10 %% strain"
    )
    demo.add_argument(
        "--out", default=None, help="results folder (default: results_demo, or results_demo_random)"
    )
    demo.add_argument(
        "--packing",
        choices=("fcc", "random"),
        default="fcc",
        help="fcc: the 6 × 10-layer lattice; random: equal spheres compacted in a 150 × 250 mm mould",
    )
    run = commands.add_parser("run", help="run the membrane triaxial test of a TOML configuration")
    run.add_argument("config", help="TOML configuration file (see membrax.config)")
    run.add_argument("--out", default=None, help="results folder (default: results_<name>)")
    run.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a configuration field"
    )
    sweep = commands.add_parser("sweep", help="a grid of tests as one batched compiled simulation")
    sweep.add_argument("config", help="TOML configuration file: the base of every member")
    sweep.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="FIELD=V1,V2,...",
        help="a field and its values (repeat per field; default the paper's Table 1: "
        "cell_pressure_kpa=10,40,100 and membrane_thickness_mm=2.5,3.33,5)",
    )
    sweep.add_argument("--out", default=None, help="results folder (default: results_<name>_sweep)")
    sweep.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a base configuration field"
    )
    reproduce = commands.add_parser(
        "reproduce", help="the paper's Table 1 sweep, then its Tables 2–3 and Figs 5–9"
    )
    reproduce.add_argument(
        "--size",
        choices=("small", "paper"),
        default="small",
        help=(
            "small: 6 × 10 specimen, ≈ 3 min on 2 CPU cores; "
            "paper: 10 × 25, 14–18 min on 2 CPU cores (13 min 46 s and 18 min 13 s measured on two machines; "
            "--set coarse_inertial_number=5e-3 nearly halves it but moves φ' after 1 %%); "
            "add --scheduler to share it"
        ),
    )
    reproduce.add_argument("--out", default=None, help="results folder (default: results_reproduce_<size>)")
    reproduce.add_argument(
        "--packing",
        choices=("fcc", "random"),
        default="fcc",
        help="fcc: the paper's lattice; random: every case on --seeds random specimens of equal spheres "
        "(compacted without friction), Tables 2-3 as mean ± s.d. (min…max) beside the FCC reproduction "
        "in --reference, and the paper's correlations for both (default results_<...>_random)",
    )
    reproduce.add_argument("--seeds", type=int, default=3, help="with --packing random: seeds per case")
    reproduce.add_argument(
        "--grading",
        choices=("equal", "ballast", "narrow"),
        default="equal",
        help="with --packing random: equal 25 mm spheres, railway ballast's grading scaled so that its "
        "largest sieve is 1/6 of the specimen's diameter (25 mm small, 41.7 mm paper), or a uniform narrow "
        "grading (0.8–1 of that sieve)",
    )
    reproduce.add_argument(
        "--state",
        choices=("dense", "medium", "loose"),
        default="dense",
        help="with --packing random: compacted without friction (dense), with 10° (medium) or with tan⁻¹ 0.5 "
        "(loose)",
    )
    reproduce.add_argument(
        "--reference",
        default=None,
        metavar="FOLDER",
        help="with --packing random: an FCC reproduction of the same size for the FCC columns "
        "(default results_reproduce_<size>)",
    )
    reproduce.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a field of the size's configuration, e.g. coarse_inertial_number=5e-3 (I = 5e-3 "
        "after 1 %% strain: Tables 2-3 unchanged, the curves after 1 %% are not; docs/loading_rate.md)",
    )
    for command in (sweep, reproduce):
        command.add_argument(
            "--devices",
            type=int,
            default=None,
            help="devices to shard over (default all; on a CPU one device per core)",
        )
        command.add_argument(
            "--scheduler",
            default=None,
            metavar="ADDRESS|local",
            help="run the members as tasks on Dask: 'local' (a worker process per core or GPU here), a "
            "scheduler's tcp://host:port or its scheduler file (a cluster; the output folder must be on a "
            "filesystem every worker sees); default: in this process",
        )
        command.add_argument(
            "--task-members",
            type=int,
            default=None,
            metavar="N",
            help="with --scheduler: members per task (default: each group shared evenly over the workers)",
        )
    for command in (demo, run, sweep, reproduce):
        command.add_argument("--resume", action="store_true", help="continue from the folder's checkpoint")
        command.add_argument("--no-progress", action="store_true", help="no progress bar")
    cli_calibrate.add_fit(commands)
    sensitivity = commands.add_parser(
        "sensitivity",
        help="derivatives of the consolidated stresses by implicit differentiation, checked by differences",
        description="Consolidate the configuration's test (float64) and print, for each output and "
        "parameter, the value, dy/dx by the implicit function theorem, dy/dx by central differences of "
        "the simulator continued from the equilibrium, and d ln y/d ln x. Example: membrax sensitivity "
        "small.toml --wrt membrane_modulus_kpa,membrane_thickness_mm",
    )
    sensitivity.add_argument("config", help="TOML configuration file (a small specimen: the solve is dense)")
    sensitivity.add_argument("--wrt", default=None, help="parameters, comma-separated (default: all six)")
    sensitivity.add_argument("--outputs", default=None, help="outputs, comma-separated (default: all six)")
    sensitivity.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a configuration field"
    )
    sensitivity.add_argument("--no-check", action="store_true", help="skip the finite differences")
    sensitivity.set_defaults(func=_sensitivity)
    cli_calibrate.add_correct(commands)
    demo.set_defaults(func=_demo)
    run.set_defaults(func=_run)
    sweep.set_defaults(func=_sweep)
    reproduce.set_defaults(func=_reproduce)
    for name, (description, epilog) in {**SUBCOMMAND_HELP, **cli_calibrate.HELP}.items():
        command = commands.choices[name]
        command.description, command.epilog = description, epilog
        command.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``membrax`` console script.

    Ctrl-C ends any command in one line and exit status 130, saying whether a checkpoint lets ``--resume``
    continue; a file or folder that cannot be read or written (permissions, a full disk, a file that
    vanished) in one line and exit status 1.
    """
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    use_compilation_cache()
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print(f"membrax: interrupted{_resume_words(getattr(args, 'folder_in_use', None))}", file=sys.stderr)
        return 130
    except OSError as error:
        print(f"membrax: {_os_error_words(error)}", file=sys.stderr)
        return 1


def use_compilation_cache() -> Path | None:
    """Keep the command's longer compilations in JAX's persistent cache, so the next command loads them.

    The folder is ``$JAX_COMPILATION_CACHE_DIR`` where set (JAX reads it itself), else ``jax/`` in membrax's
    cache folder (:func:`membrax.native.cache_dir`, the folder a Dask campaign's workers share,
    :func:`membrax.campaign.local_cluster`); ``MEMBRAX_COMPILATION_CACHE=0`` leaves JAX's cache off. JAX
    keeps the programs that took ``jax_persistent_cache_min_compile_time_secs`` (1 s by default) or more to
    compile: the chunks of a run and the membrane's stiffness product, not the small operations of building
    a specimen. The command-line entry point sets this, not the library's import.

    Returns:
      The cache folder, or None where the cache stays off.
    """
    if os.environ.get("MEMBRAX_COMPILATION_CACHE", "1") == "0":
        return None
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    import jax

    from membrax import native

    folder = native.cache_dir() / "jax"
    jax.config.update("jax_compilation_cache_dir", str(folder))
    return folder


def _resume_words(folder) -> str:
    """What an interrupted command left to resume from, for its one line."""
    if folder is None:
        return ""
    from membrax.runner import CHECKPOINT_NAME

    folder = Path(folder)
    if folder.is_dir() and any(folder.rglob(CHECKPOINT_NAME)):
        return f"; the checkpoint in {folder} is kept: run the same command with --resume to continue"
    return f"; no checkpoint was written to {folder} yet, so it starts afresh next time"


def _os_error_words(error: OSError) -> str:
    """An operating-system error in a line: what could not be done, to which file, and the fix."""
    import errno

    where = error.filename if error.filename is not None else "a file"
    if isinstance(error, PermissionError):
        return f"{where}: permission denied; choose a folder you can write (--out) or change its permissions."
    if error.errno == errno.ENOSPC:
        return f"{where}: no space left on the device; free some space or write elsewhere (--out)."
    if isinstance(error, FileNotFoundError):
        return f"{where}: no such file or folder (moved or deleted while membrax ran?)."
    return f"{where}: {error.strerror or error}."


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
