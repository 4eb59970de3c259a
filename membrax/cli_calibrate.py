"""The ``membrax`` command's calibrate half: ``fit``, ``correct`` and ``serve``.

Contract: :func:`add_fit` and :func:`add_correct` add these sub-commands (their options, ``--help`` texts
in :data:`HELP` and handlers) to :func:`membrax.cli.build_parser`'s sub-parsers; each handler takes the
parsed arguments, prints its report and returns an exit code, as :func:`membrax.cli.main` expects.
:func:`random_correlations` prints the paper's correlations after ``membrax reproduce --packing random``.
This module and :mod:`membrax.cli` are the one place membrax reaches :mod:`calibrate`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

__all__ = ["HELP", "add_correct", "add_fit", "random_correlations"]

#: ``fit`` and ``correct``'s ``--help``: what each does (description) and examples (epilog).
HELP = {
    "fit": (
        "Fit a membrane correction (calibrate.models: 'paper' or 'rich') on the records of one or more\n"
        "sweeps by weighted least squares (optax Adam, then L-BFGS), score it by leave-one-case-out\n"
        "cross-validation and write it as JSON with provenance, for membrax correct --model.",
        "example:\n"
        "  membrax fit calibration/*/sweep.nc --model rich --out corrections.json --table table.npz",
    ),
    "correct": (
        "Correct a drained laboratory record for the membrane by five methods: uncorrected, ASTM\n"
        "D4767/D7181, Henkel & Gilbert, Kuerbis & Vaid, and the fitted DEM-based correction with a band\n"
        "of one standard deviation. Writes a CSV and a plot of sigma_1, sigma_3 and phi' by method\n"
        "(default <record>_corrected.csv/.png in the working folder; never over the record itself).\n"
        "\n"
        "The record: a CSV (UTF-8, with or without a byte-order mark; commas, or semicolons with decimal\n"
        "commas) or an .xlsx sheet; '#' comment lines, then a header naming each column and its unit:\n"
        "  axial_strain [% or -]; volumetric_strain or radial_strain [% or -];\n"
        "  deviator_stress or axial_stress [Pa, kPa or MPa]; cell_pressure [Pa, kPa or MPa].\n"
        "Conventions: compression positive (the volumetric strain grows while the specimen contracts,\n"
        "a bulging specimen has a negative radial strain); strains in the header's unit. A record that\n"
        "looks otherwise is refused with the likely mistake named; --dilation-positive reads a record\n"
        "whose volumetric or radial strain is written dilation positive. Readings repeating the axial\n"
        "strain before them are averaged. Outside the range the correction was fitted on, each quantity\n"
        "is warned about with its value and the range, the fitted band widens by 1 + (distance outside,\n"
        "in range widths), and beyond one width the fitted column is withheld. --specimen-height-mm has\n"
        "H/D checked too (outside its fitted range it widens the band, never withholds). Where shrinking\n"
        "the fitted correction toward none lowered its cross-validated error (by E_m t_m/(sigma_c D)),\n"
        "it is shrunk, said in a warning and in the CSV's fitted_shrink_* columns.\n"
        "\n"
        "A series: several records (or a folder of them) sharing the specimen options, or --series with a\n"
        "TOML sheet listing each test's record and specimen. Each test is corrected, and each method's\n"
        "Mohr-Coulomb envelope (c', phi' through the peaks) and curved envelope (phi'_s = phi0 - dphi\n"
        "log10(sigma'3/p_a)) are fitted; --out is then a folder (series.html, envelopes.csv, series.csv,\n"
        "series.png and each test's corrected CSV).",
        "examples:\n"
        "  membrax correct lab.csv --specimen-diameter-mm 150 --particle-size-mm 20 \\\n"
        "      --membrane-thickness-mm 2 --membrane-modulus-kpa 1400\n"
        "  membrax correct lab.xlsx --specimen-diameter-mm 300 --particle-size-mm 40 \\\n"
        "      --membrane-thickness-mm 4 --membrane-modulus-kpa 1400 --dilation-positive --out test7.csv\n"
        "  membrax correct lab.csv --specimen-diameter-mm 150 --specimen-height-mm 300 \\\n"
        "      --particle-size-mm 20 --membrane-thickness-mm 2 --membrane-modulus-kpa 1400\n"
        "  membrax correct --series calibrate/data/example_series/series.toml --out series_corrected\n"
        "  membrax correct t25.csv t50.csv t80.csv --specimen-diameter-mm 150 --particle-size-mm 20 \\\n"
        "      --membrane-thickness-mm 2 --membrane-modulus-kpa 1400\n"
        "where the record's header gives each column's unit, e.g.\n"
        "  axial_strain [%],volumetric_strain [%],deviator_stress [kPa],cell_pressure [kPa]",
    ),
}


def add_fit(commands) -> None:
    """Add ``membrax fit`` to the sub-parsers ``commands``."""
    from calibrate.datasets import DEFAULT_RADIAL_TARGET, RADIAL_TARGETS

    fit = commands.add_parser("fit", help="fit a membrane correction on sweep results (calibrate)")
    fit.add_argument(
        "sweeps", nargs="+", help="sweep.nc files of membrax sweep or reproduce (or their .nc.gz copies)"
    )
    fit.add_argument(
        "--out", default="corrections.json", help="JSON file to write (default corrections.json)"
    )
    fit.add_argument(
        "--model",
        default="rich",
        choices=("paper", "rich"),
        help="correction model (default rich: the shipped one, chosen by cross-validation)",
    )
    fit.add_argument("--no-cross-validation", action="store_true", help="skip leave-one-case-out")
    fit.add_argument("--table", default=None, help="also write the fitting table (.npz)")
    fit.add_argument(
        "--radial-target",
        choices=sorted(RADIAL_TARGETS),
        default=DEFAULT_RADIAL_TARGET,
        help="the internal radial stress the correction reproduces: received (the spheres' and clamps' "
        "radial load over the membrane's projected area, σc when the membrane carries nothing; the "
        "default) or section_4_3 (the paper's); the other is fitted beside when the sweeps record it "
        "(docs/model.md)",
    )
    fit.set_defaults(func=_fit)


def add_correct(commands) -> None:
    """Add ``membrax correct`` and ``membrax serve`` to the sub-parsers ``commands``."""
    correct = commands.add_parser(
        "correct", help="correct a laboratory record for the membrane (classical and fitted corrections)"
    )
    correct.add_argument(
        "record",
        nargs="*",
        help="CSV or .xlsx: axial_strain, volumetric_ or radial_strain, deviator_ or "
        "axial_stress, cell_pressure, each 'name [unit]' in the header; compression positive. Several "
        "records (or a folder of them) are a series sharing the specimen options: their envelopes too",
    )
    correct.add_argument(
        "--series",
        default=None,
        metavar="SHEET.toml",
        help="a series sheet listing the tests and their specimens (calibrate.series; README)",
    )
    for name, unit, what in (
        ("specimen-diameter-mm", "mm", "specimen diameter after consolidation"),
        ("particle-size-mm", "mm", "particle size d50: the sieve size half the mass passes"),
        ("membrane-thickness-mm", "mm", "membrane thickness"),
        ("membrane-modulus-kpa", "kPa", "membrane Young's modulus (latex ≈ 1400 kPa)"),
    ):
        correct.add_argument(f"--{name}", type=float, default=None, help=f"{what} ({unit}); required")
    correct.add_argument(
        "--void-ratio",
        type=float,
        default=None,
        help="the specimen's void ratio e after consolidation (optional): checked against the densities "
        "the correction was fitted on",
    )
    correct.add_argument(
        "--specimen-height-mm",
        type=float,
        default=None,
        help="specimen height after consolidation (mm, optional): H/D_s is checked against the heights the "
        "correction was fitted on (laboratories test at H/D 2-2.5)",
    )
    correct.add_argument("--model", default=None, help="corrections.json of membrax fit (default: shipped)")
    correct.add_argument(
        "--out",
        default=None,
        help="CSV to write (default <record>_corrected.csv in the working folder); for a series, the folder "
        "(default series_corrected)",
    )
    correct.add_argument(
        "--dilation-positive",
        action="store_true",
        help="the record's volumetric or radial strain is written dilation positive (membrax negates it)",
    )
    correct.add_argument("--no-plot", action="store_true", help="write the CSV only")
    correct.add_argument(
        "--sheet", default=None, metavar="NAME|NUMBER", help="a workbook's sheet to read (default the first)"
    )
    correct.set_defaults(func=_correct)
    serve = commands.add_parser("serve", help="a local web page for correcting records (localhost only)")
    serve.add_argument("--port", type=int, default=8765, help="the port on 127.0.0.1 (default 8765)")
    serve.add_argument("--no-browser", action="store_true", help="do not open a browser")
    serve.set_defaults(func=_serve)


def random_correlations(done: dict) -> None:
    """The paper's correlations on the random members beside the FCC reference (calibrate.correlations)."""
    from calibrate.correlations import write_correlations
    from calibrate.datasets import fitting_table

    tables = {}
    reference = done.get("reference_dataset")
    if reference is not None:
        tables["FCC"] = fitting_table(reference, "section_4_3")  # the paper's correlations: its §4.3 stresses
    tables["random"] = fitting_table(done["sweep"].dataset, "section_4_3")
    written = write_correlations(tables, done["folder"])
    print(written["files"]["correlations.md"].read_text())


def _fit(args: argparse.Namespace) -> int:
    from calibrate.workflow import fit_sweeps

    try:
        report, _ = fit_sweeps(
            args.sweeps, args.out, args.model, not args.no_cross_validation, args.table, args.radial_target
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    print(report)
    return 0


def _specimen_of(args: argparse.Namespace):
    """The specimen of `membrax correct`'s options, checked by `calibrate.correct.LabSpecimen.from_mm_kpa`."""
    from calibrate.correct import LabSpecimen

    return LabSpecimen.from_mm_kpa(
        args.specimen_diameter_mm,
        args.particle_size_mm,
        args.membrane_thickness_mm,
        args.membrane_modulus_kpa,
        void_ratio=args.void_ratio,
        specimen_height_mm=args.specimen_height_mm,
    )


def _correct(args: argparse.Namespace) -> int:
    from calibrate.correct import METHODS, REPORT_STRAINS
    from calibrate.report import correct_file

    series = args.series is not None or len(args.record) > 1 or any(Path(r).is_dir() for r in args.record)
    if not args.record and args.series is None:
        print("membrax: give a record (or several, or --series SHEET.toml) to correct.", file=sys.stderr)
        return 2
    if args.series is not None and args.record:
        print("membrax: give either records or --series, not both.", file=sys.stderr)
        return 2
    missing = [
        f"--{name.replace('_', '-')}"
        for name in (
            "specimen_diameter_mm",
            "particle_size_mm",
            "membrane_thickness_mm",
            "membrane_modulus_kpa",
        )
        if getattr(args, name) is None
    ]
    if missing and args.series is None:
        print(f"membrax: correct needs {', '.join(missing)} (the specimen; see --help).", file=sys.stderr)
        return 2
    if series:
        return _correct_series(args)
    (args.record,) = args.record
    try:
        specimen = _specimen_of(args)
        result, paths = correct_file(
            args.record,
            specimen,
            args.model,
            args.out,
            not args.no_plot,
            args.dilation_positive,
            progress=lambda text: print(f"membrax: {text}", file=sys.stderr, flush=True),
            sheet=args.sheet,
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    for message in result.warnings:
        print(f"membrax: warning: {message}", file=sys.stderr)
    strain = result.record.axial_strain
    lines = [f"read {args.record}: {line}" for line in result.record.notes]
    # The fitted method with each radial target it carries: the chosen one, then its alternate's.
    fitted = [(f"fitted σ3 {result.radial_target}", result)]
    if result.alternate is not None:
        fitted.append((f"σ3 {result.alternate.radial_target}", result.alternate))
    names = [*METHODS[:-1], *(name for name, _ in fitted)]
    lines += ["mobilised φ' (°) by method", f"{'ε_a %':>6} " + " ".join(f"{m:>15}" for m in names)]
    for target in REPORT_STRAINS:
        if target > strain[-1] + 1e-12:
            continue
        i = int(np.argmin(np.abs(strain - target)))
        cells = [f"{result.friction_angle[m][i]:15.2f}" for m in METHODS[:-1]]
        for _, corrected in fitted:
            value, spread = corrected.friction_angle["fitted"][i], corrected.std["friction_angle"][i]
            cells.append(f"{value:9.2f} ±{spread:4.2f}" if np.isfinite(value) else f"{'withheld':>15}")
        lines.append(f"{100 * strain[i]:6.2f} " + " ".join(cells))
    lines.append("written: " + ", ".join(str(p) for p in paths))
    print("\n".join(lines))
    return 0


def _correct_series(args: argparse.Namespace) -> int:
    """``membrax correct a.csv b.csv ...`` or ``--series SHEET``: every test, then the envelopes by method."""
    from calibrate import series
    from calibrate.correct import LABELS, METHODS
    from calibrate.persistence import load_corrections

    say = lambda text: print(f"membrax: {text}", file=sys.stderr, flush=True)  # noqa: E731
    try:
        if args.series is not None:
            tests = series.read_series_sheet(args.series)
        else:
            specimen = _specimen_of(args)
            tests = series.series_of_files(args.record, specimen, args.dilation_positive)
        corrections = None if args.model is None else load_corrections(args.model)
        result = series.correct_series(tests, corrections, progress=say)
        out = Path(args.out) if args.out is not None else Path.cwd() / "series_corrected"
        written = series.write_series(result, out)
    except (FileNotFoundError, ValueError) as error:
        print(f"membrax: {error}", file=sys.stderr)
        return 2
    for test, corrected in zip(result.tests, result.corrected, strict=True):
        for message in corrected.warnings:
            print(f"membrax: warning: {test.name}: {message}", file=sys.stderr)
    lines = [
        f"{len(result.tests)} tests; peak φ' (°) by method",
        f"{'test':>24} " + " ".join(f"{m:>15}" for m in METHODS),
    ]
    for index, test in enumerate(result.tests):
        lines.append(f"{test.name:>24} " + " ".join(f"{result.peaks[m][index, 2]:15.2f}" for m in METHODS))
    lines.append("envelopes (Mohr–Coulomb on the peaks; curved φ'_s = φ0 − Δφ log10(σ'3/p_a)):")
    for method in METHODS:
        line, curve = result.envelopes[method], result.curved[method]
        lines.append(
            f"  {LABELS[method]:>24}: c' {1e-3 * line.cohesion:.1f} kPa, φ' {line.friction_angle:.2f}°"
            f"; φ0 {curve.phi0:.2f}°, Δφ {curve.delta_phi:.2f}°"
        )
    lines.append(
        f"written to {written['report'].parent}: series.html (the report), series.csv, envelopes.csv, "
        "series.png and each test's corrected CSV"
    )
    print("\n".join(lines))
    return 0


def _serve(args: argparse.Namespace) -> int:
    from calibrate.web import serve

    serve(args.port, open_browser=not args.no_browser)
    return 0
