"""A laboratory's test series: several records corrected at once, and the strength envelope by every method.

Contract. :func:`read_series_sheet` reads a *series sheet*, a TOML file listing the tests of a series
(each a record, with the specimen's sizes shared or per test), into :class:`SeriesTest` entries;
:func:`series_of_files` makes the same entries from record files (or a folder of them) that share one
specimen. :func:`correct_series` corrects every test by the five methods of :mod:`calibrate.correct` and
returns a :class:`SeriesResult`: per test and method the peak (σ1, σ3, φ') and φ' at stated strains, and per
method the envelopes through the series' peaks. :func:`write_series` writes them as CSV, one figure and a
one-page HTML report (inputs, warnings, tables, figure; it prints to one A4 page).

The series sheet (TOML; lengths in mm, stresses in kPa, as ``membrax correct``'s options)::

    # shared by every test unless a test gives its own
    specimen_diameter_mm = 150
    particle_size_mm = 20
    membrane_thickness_mm = 2
    membrane_modulus_kpa = 1400

    [[test]]
    record = "test_25kpa.csv"        # relative to the sheet
    [[test]]
    record = "series.xlsx"
    sheet = "60 kPa"                 # one workbook, a sheet per test
    void_ratio = 0.7

Envelopes, per method, through the peak points of the tests (at least two):

- **Mohr–Coulomb**, c' and φ', by least squares on the peak (s, t) points, s = (σ1 + σ3)/2,
  t = (σ1 − σ3)/2: t = a + s tan α, sin φ' = tan α, c' = a / cos φ'  [C, standard; e.g. Lambe & Whitman
  1969, Soil Mechanics, ch. 10], with standard errors from the regression's covariance (n − 2 degrees of
  freedom; none for two tests) propagated by the delta method. The c' a method leaves is the apparent
  cohesion: the uncorrected series of a coarse material at low pressure shows one that is partly the
  membrane's.
- **Curved**: the secant φ' of each test's peak (through the origin, sin φ'_s = t/s) against σ'3,
  φ'_s = φ0 − Δφ log10(σ'3/p_a), p_a = 101.325 kPa, the form used for rockfill and gravels (Duncan, Byrne,
  Wong & Mabry 1980, Report UCB/GT/80-01, after Leps 1970), by least squares with standard errors.
"""

from __future__ import annotations

import base64
import io
import math
import tomllib
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from calibrate import correct, lab, report

__all__ = [
    "ATMOSPHERIC_PRESSURE",
    "REPORT_STRAINS",
    "SPECIMEN_FIELDS",
    "CurvedEnvelope",
    "Envelope",
    "SeriesResult",
    "SeriesTest",
    "correct_series",
    "curved_envelope",
    "mohr_coulomb_envelope",
    "read_series_sheet",
    "series_of_files",
    "write_series",
]

#: p_a of the curved envelope, Pa.
ATMOSPHERIC_PRESSURE = 101_325.0
#: The axial strains φ' is reported at besides the peak (fractions).
REPORT_STRAINS = correct.REPORT_STRAINS
#: The specimen's fields of a series sheet, in :meth:`calibrate.correct.LabSpecimen.from_mm_kpa`'s order.
SPECIMEN_FIELDS = (
    "specimen_diameter_mm",
    "particle_size_mm",
    "membrane_thickness_mm",
    "membrane_modulus_kpa",
    "void_ratio",
    "specimen_height_mm",
)
_REQUIRED = SPECIMEN_FIELDS[:4]
_TEST_FIELDS = {"record", "sheet", "name", "dilation_positive", *SPECIMEN_FIELDS}
#: The record files a folder's series is made of.
RECORD_SUFFIXES = (".csv", ".txt", ".xlsx")


class SeriesTest(NamedTuple):
    """One test of a series: its record, the sheet of a workbook (or None), its specimen and its name."""

    record: Path
    specimen: correct.LabSpecimen
    name: str
    sheet: str | None = None
    dilation_positive: bool = False


class Envelope(NamedTuple):
    """A Mohr–Coulomb envelope: c' (Pa) and φ' (degrees), their standard errors (NaN when not defined)."""

    cohesion: float
    friction_angle: float
    cohesion_std: float
    friction_angle_std: float
    points: int


class CurvedEnvelope(NamedTuple):
    """φ'_s = φ0 − Δφ log10(σ'3/p_a), degrees, with standard errors (NaN when not defined)."""

    phi0: float
    delta_phi: float
    phi0_std: float
    delta_phi_std: float
    points: int


class SeriesResult(NamedTuple):
    """The corrected series (module docstring).

    Attributes:
      tests: the :class:`SeriesTest` entries, in order.
      corrected: their :class:`calibrate.correct.CorrectedRecord`.
      peaks: {method: array (tests, 3)} of σ1 (Pa), σ3 (Pa) and φ' (degrees) at each test's peak φ'.
      at_strains: {method: array (tests, len(REPORT_STRAINS))} of φ' (degrees) at the records nearest
        :data:`REPORT_STRAINS` (NaN beyond a record's last strain).
      envelopes: {method: :class:`Envelope`}.
      curved: {method: :class:`CurvedEnvelope`}.
    """

    tests: tuple
    corrected: tuple
    peaks: dict
    at_strains: dict
    envelopes: dict
    curved: dict


def _specimen(fields: dict, where: str) -> correct.LabSpecimen:
    missing = [name for name in _REQUIRED if fields.get(name) is None]
    if missing:
        raise ValueError(f"{where}: no {', '.join(missing)}; give it for the test or for the whole sheet.")
    try:
        return correct.LabSpecimen.from_mm_kpa(*(fields.get(name) for name in SPECIMEN_FIELDS))
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None


def read_series_sheet(path) -> list[SeriesTest]:
    """The tests of a series sheet (module docstring), each specimen checked as ``membrax correct`` does.

    Raises:
      FileNotFoundError: no sheet, or a record it names is missing. ValueError: not TOML (line and column),
        no ``[[test]]``, an unknown key or a missing or bad specimen field, naming the test and the fix.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no series sheet at '{path}'.")
    try:
        content = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path} is not a TOML series sheet: {error}.") from None
    shared = {key: value for key, value in content.items() if key != "test"}
    unknown = sorted(set(shared) - set(SPECIMEN_FIELDS) - {"dilation_positive"})
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown}; the shared keys are {list(SPECIMEN_FIELDS)}.")
    entries = content.get("test")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f'{path}: no tests; list each as a [[test]] table with its record = "file.csv".')
    tests = []
    for number, entry in enumerate(entries, start=1):
        where = f"{path}, test {number}"
        unknown = sorted(set(entry) - _TEST_FIELDS)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; a test's keys are {sorted(_TEST_FIELDS)}.")
        if "record" not in entry:
            raise ValueError(f'{where}: no record; give record = "file.csv" (relative to the sheet).')
        record = (path.parent / entry["record"]).resolve()
        if not record.is_file():
            raise FileNotFoundError(f"{where}: no record at '{record}'.")
        fields = {**shared, **entry}
        sheet = entry.get("sheet")
        name = str(entry.get("name") or (f"{record.stem} {sheet}" if sheet is not None else record.stem))
        tests.append(
            SeriesTest(
                record,
                _specimen(fields, where),
                name,
                None if sheet is None else str(sheet),
                bool(fields.get("dilation_positive", False)),
            )
        )
    return tests


def series_of_files(
    paths, specimen: correct.LabSpecimen, dilation_positive: bool = False
) -> list[SeriesTest]:
    """The tests of record files (a folder stands for its :data:`RECORD_SUFFIXES` files) sharing a specimen.

    Raises:
      FileNotFoundError: a path that does not exist, or a folder without records.
    """
    files = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in RECORD_SUFFIXES and p.is_file())
            if not found:
                raise FileNotFoundError(f"no records ({', '.join(RECORD_SUFFIXES)}) in the folder '{path}'.")
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise FileNotFoundError(f"no laboratory record at '{path}'.")
    return [SeriesTest(p, specimen, p.stem, None, dilation_positive) for p in files]


def mohr_coulomb_envelope(sigma_1, sigma_3) -> Envelope:
    """The Mohr–Coulomb c', φ' by least squares on the peak (s, t) points (module docstring), NaN left out.

    Args:
      sigma_1: the peak axial stresses, Pa.
      sigma_3: the radial stresses at the same records, Pa.
    """
    sigma_1, sigma_3 = np.asarray(sigma_1, dtype=np.float64), np.asarray(sigma_3, dtype=np.float64)
    keep = np.isfinite(sigma_1) & np.isfinite(sigma_3)
    s, t = 0.5 * (sigma_1 + sigma_3)[keep], 0.5 * (sigma_1 - sigma_3)[keep]
    count = int(s.size)
    if count < 2 or np.ptp(s) == 0.0:
        return Envelope(math.nan, math.nan, math.nan, math.nan, count)
    design = np.stack([np.ones_like(s), s], axis=1)
    (intercept, slope), *_ = np.linalg.lstsq(design, t, rcond=None)
    if not abs(slope) < 1.0:
        return Envelope(math.nan, math.nan, math.nan, math.nan, count)
    cosine = math.sqrt(1.0 - slope**2)
    friction, cohesion = math.degrees(math.asin(slope)), intercept / cosine
    cohesion_std = friction_std = math.nan
    if count > 2:
        residual = t - design @ np.array([intercept, slope])
        covariance = float(residual @ residual) / (count - 2) * np.linalg.inv(design.T @ design)
        # Delta method: ∂φ/∂m = 1/√(1 − m²); ∂c/∂a = 1/cos φ, ∂c/∂m = a m/(1 − m²)^(3/2).
        friction_std = math.degrees(math.sqrt(covariance[1, 1]) / cosine)
        gradient = np.array([1.0 / cosine, intercept * slope / cosine**3])
        cohesion_std = math.sqrt(float(gradient @ covariance @ gradient))
    return Envelope(cohesion, friction, cohesion_std, friction_std, count)


def curved_envelope(sigma_1, sigma_3) -> CurvedEnvelope:
    """The curved envelope φ'_s = φ0 − Δφ log10(σ'3/p_a) of the peaks (module docstring), Pa in, ° out."""
    sigma_1, sigma_3 = np.asarray(sigma_1, dtype=np.float64), np.asarray(sigma_3, dtype=np.float64)
    keep = np.isfinite(sigma_1) & np.isfinite(sigma_3) & (sigma_3 > 0.0)
    secant = np.degrees(np.arcsin((sigma_1 - sigma_3)[keep] / (sigma_1 + sigma_3)[keep]))
    pressure = np.log10(sigma_3[keep] / ATMOSPHERIC_PRESSURE)
    count = int(secant.size)
    if count < 2 or np.ptp(pressure) == 0.0:
        return CurvedEnvelope(math.nan, math.nan, math.nan, math.nan, count)
    design = np.stack([np.ones_like(pressure), -pressure], axis=1)
    (phi0, delta), *_ = np.linalg.lstsq(design, secant, rcond=None)
    phi0_std = delta_std = math.nan
    if count > 2:
        residual = secant - design @ np.array([phi0, delta])
        covariance = float(residual @ residual) / (count - 2) * np.linalg.inv(design.T @ design)
        phi0_std, delta_std = (math.sqrt(v) for v in np.diag(covariance))
    return CurvedEnvelope(float(phi0), float(delta), phi0_std, delta_std, count)


def correct_series(tests, corrections=None, progress=None) -> SeriesResult:
    """Correct every test of a series and fit each method's envelopes (module docstring).

    Args:
      tests: :class:`SeriesTest` entries (:func:`read_series_sheet`, :func:`series_of_files`).
      corrections: the fitted correction (default the shipped one).
      progress: called with a line before each test (e.g. ``print``), or None.

    Raises:
      FileNotFoundError, calibrate.lab.LabRecordError: a record that cannot be read, named.
    """
    corrections = correct.default_corrections() if corrections is None else corrections
    corrected = []
    for number, test in enumerate(tests, start=1):
        if progress is not None:
            progress(f"correcting test {number} of {len(tests)}: {test.name}")
        record = lab.read_lab_record(test.record, dilation_positive=test.dilation_positive, sheet=test.sheet)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # carried in each result
            corrected.append(correct.correct_record(record, test.specimen, corrections))
    peaks, at_strains = {}, {}
    for method in correct.METHODS:
        rows, strains = [], []
        for result in corrected:
            angle = result.friction_angle[method]
            if np.any(np.isfinite(angle)):
                i = int(np.nanargmax(angle))
                rows.append((result.sigma_1[method][i], result.sigma_3[method][i], angle[i]))
            else:
                rows.append((math.nan, math.nan, math.nan))
            axial = result.record.axial_strain
            strains.append(
                [
                    angle[int(np.argmin(np.abs(axial - target)))] if target <= axial[-1] + 1e-12 else math.nan
                    for target in REPORT_STRAINS
                ]
            )
        peaks[method] = np.asarray(rows, dtype=np.float64)
        at_strains[method] = np.asarray(strains, dtype=np.float64)
    envelopes = {m: mohr_coulomb_envelope(peaks[m][:, 0], peaks[m][:, 1]) for m in correct.METHODS}
    curved = {m: curved_envelope(peaks[m][:, 0], peaks[m][:, 1]) for m in correct.METHODS}
    return SeriesResult(tuple(tests), tuple(corrected), peaks, at_strains, envelopes, curved)


def _tables(result: SeriesResult) -> tuple[str, str]:
    """The tests' CSV (one row per test and method) and the envelopes' CSV (one row per method)."""
    out = io.StringIO()
    strain_names = [f"friction_angle_at_{100 * s:g}pct [deg]" for s in REPORT_STRAINS]
    out.write(
        "test,method,cell_pressure [kPa],peak_sigma_1 [kPa],peak_sigma_3 [kPa],peak_friction_angle [deg],"
        + ",".join(strain_names)
        + "\n"
    )
    for index, (test, corrected) in enumerate(zip(result.tests, result.corrected, strict=True)):
        cell = 1e-3 * float(np.median(corrected.record.cell_pressure))
        for method in correct.METHODS:
            sigma_1, sigma_3, angle = result.peaks[method][index]
            values = [cell, 1e-3 * sigma_1, 1e-3 * sigma_3, angle, *result.at_strains[method][index]]
            out.write(f'"{test.name}",{method},' + ",".join(f"{v:.6g}" for v in values) + "\n")
    envelope = io.StringIO()
    envelope.write(
        "method,cohesion [kPa],cohesion_std [kPa],friction_angle [deg],friction_angle_std [deg],"
        "phi0 [deg],phi0_std [deg],delta_phi [deg],delta_phi_std [deg],tests\n"
    )
    for method in correct.METHODS:
        line, curve = result.envelopes[method], result.curved[method]
        values = [
            1e-3 * line.cohesion,
            1e-3 * line.cohesion_std,
            line.friction_angle,
            line.friction_angle_std,
            curve.phi0,
            curve.phi0_std,
            curve.delta_phi,
            curve.delta_phi_std,
        ]
        envelope.write(f"{method}," + ",".join(f"{v:.6g}" for v in values) + f",{line.points}\n")
    return out.getvalue(), envelope.getvalue()


#: (colour, line style) of each method in the envelope panel (the curves' colour is the test's).
_STYLES = {
    "uncorrected": ("k", "-"),
    "astm": ("C0", "--"),
    "henkel_gilbert": ("C1", "-."),
    "kuerbis_vaid": ("C2", ":"),
    "fitted": ("C3", "-"),
}


def plot_series(result: SeriesResult, title: str = ""):
    """One figure: the tests' stress–strain curves, and the (s, t) peaks with each method's envelope.

    The curves are each test's deviator against axial strain, uncorrected and by the fitted correction.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 4.6), constrained_layout=True)
    curves, envelope = figure.subplots(1, 2)
    for number, corrected in enumerate(result.corrected):
        strain = 100.0 * corrected.record.axial_strain
        for method, style in (("uncorrected", "-"), ("fitted", "--")):
            deviator = 1e-3 * (corrected.sigma_1[method] - corrected.sigma_3[method])
            label = f"{result.tests[number].name}, {correct.LABELS[method]}"
            curves.plot(strain, deviator, linestyle=style, color=f"C{number}", lw=1.2, label=label)
    curves.set(xlabel="axial strain (%)", ylabel="deviator stress σ1 − σ3 (kPa)", title="stress–strain")
    curves.legend(fontsize=7)
    for method in correct.METHODS:
        sigma_1, sigma_3 = result.peaks[method][:, 0], result.peaks[method][:, 1]
        s, t = 0.5e-3 * (sigma_1 + sigma_3), 0.5e-3 * (sigma_1 - sigma_3)
        line = result.envelopes[method]
        colour, style = _STYLES[method]
        envelope.plot(s, t, "o", color=colour, ms=4)
        if math.isfinite(line.friction_angle):
            span = np.linspace(0.0, 1.1 * np.nanmax(s), 50)
            fitted = 1e-3 * line.cohesion * math.cos(math.radians(line.friction_angle)) + span * math.sin(
                math.radians(line.friction_angle)
            )
            label = (
                f"{correct.LABELS[method]}: c' {1e-3 * line.cohesion:.1f} kPa, φ' {line.friction_angle:.1f}°"
            )
            envelope.plot(span, fitted, linestyle=style, color=colour, label=label)
    envelope.set(
        xlabel="s = (σ1 + σ3)/2 (kPa)", ylabel="t = (σ1 − σ3)/2 (kPa)", title="peak strength envelopes"
    )
    envelope.set_xlim(left=0.0)
    envelope.set_ylim(bottom=0.0)
    envelope.legend(fontsize=7)
    if title:
        figure.suptitle(title)
    return figure


def _report_html(result: SeriesResult, tests_csv: str, envelopes_csv: str, image: bytes, title: str) -> str:
    """A one-page HTML report: inputs, warnings, the envelopes' and tests' tables and the figure."""
    import html

    def table(text: str) -> str:
        lines = [line for line in text.strip().splitlines()]
        head = "".join(f"<th>{html.escape(cell)}</th>" for cell in lines[0].split(","))
        body = "".join(
            "<tr>"
            + "".join(f"<td>{html.escape(cell.strip(chr(34)))}</td>" for cell in line.split(","))
            + "</tr>"
            for line in lines[1:]
        )
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    inputs = "".join(
        f"<li>{html.escape(test.name)}: {html.escape(test.record.name)}"
        + (f" (sheet {html.escape(test.sheet)})" if test.sheet else "")
        + f"; D_s {1e3 * test.specimen.specimen_diameter:g} mm, d50 {1e3 * test.specimen.particle_diameter:g}"
        f" mm, membrane {1e3 * test.specimen.membrane_thickness:g} mm of"
        f" {1e-3 * test.specimen.membrane_modulus:g} kPa</li>"
        for test in result.tests
    )
    notes = "".join(
        f"<li>{html.escape(test.name)}: {html.escape(message)}</li>"
        for test, corrected in zip(result.tests, result.corrected, strict=True)
        for message in corrected.warnings
    )
    picture = base64.b64encode(image).decode()
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
@page {{ size: A4 landscape; margin: 10mm; }}
body {{ font-family: sans-serif; font-size: 9pt; margin: 0 auto; max-width: 277mm; }}
h1 {{ font-size: 13pt; }} h2 {{ font-size: 10pt; margin: 6px 0 2px; }}
table {{ border-collapse: collapse; font-size: 8pt; }} td, th {{ border: 1px solid #bbb; padding: 1px 4px; }}
img {{ width: 100%; }} ul {{ margin: 2px 0; }}
</style></head><body>
<h1>{html.escape(title)}</h1>
<h2>Tests</h2><ul id="inputs">{inputs}</ul>
<h2>Envelopes by method (Mohr–Coulomb c', φ' on the peak s–t points;
curved φ'_s = φ0 − Δφ log10(σ'3/p_a))</h2>
<div id="envelopes">{table(envelopes_csv)}</div>
<h2>Peaks and φ' at stated strains</h2><div id="tests">{table(tests_csv)}</div>
<img id="figure" alt="stress-strain curves and envelopes" src="data:image/png;base64,{picture}">
<h2>Warnings</h2><ul id="warnings">{notes or "<li>none</li>"}</ul>
<p>membrax correct, a series of {len(result.tests)} tests. The fitted correction's numbers are
simulations'; the classical ones are ASTM D4767/D7181, Henkel &amp; Gilbert and Kuerbis &amp; Vaid.</p>
</body></html>
"""


def write_series(result: SeriesResult, folder, title: str = "membrane corrections of a test series") -> dict:
    """Write ``series.csv``, ``envelopes.csv``, ``series.png``, ``series.html`` and each test's corrected CSV.

    Each file is written atomically; the tests' CSVs are ``<name>_corrected.csv``.

    Returns:
      {"tests", "envelopes", "figure", "report": path, "records": [paths]}.
    """
    from membrax.io.files import atomic_write_bytes

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tests_csv, envelopes_csv = _tables(result)
    figure = plot_series(result, title)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    image = buffer.getvalue()
    written = {
        "tests": folder / "series.csv",
        "envelopes": folder / "envelopes.csv",
        "figure": folder / "series.png",
        "report": folder / "series.html",
    }
    atomic_write_bytes(written["tests"], tests_csv.encode())
    atomic_write_bytes(written["envelopes"], envelopes_csv.encode())
    atomic_write_bytes(written["figure"], image)
    atomic_write_bytes(
        written["report"], _report_html(result, tests_csv, envelopes_csv, image, title).encode()
    )
    records = []
    for test, corrected in zip(result.tests, result.corrected, strict=True):
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in test.name)
        records += report.write_correction(corrected, folder / f"{name}_corrected.csv", None, [test.name])
    written["records"] = records
    return written
