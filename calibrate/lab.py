"""Laboratory test records: a table with units in its header, read and checked before anything is computed.

Contract. :func:`read_lab_record` reads a drained triaxial test record and returns a :class:`LabRecord` in
SI units (Pa, strains as fractions, compression positive), or raises :class:`LabRecordError` naming the
file, the line, the column and the fix. Nothing is guessed silently: what the reader did to a file
(averaged repeated readings, read decimal commas, flipped a sign on request) is said in ``notes``.

The file:

- a text CSV, UTF-8 with or without a byte-order mark (a spreadsheet's "CSV UTF-8"), or UTF-16 with one;
  columns separated by commas, or by semicolons or tabs, which may then carry decimal commas
  (``0,25``); or an Excel workbook (``.xlsx``, read with openpyxl: its first sheet, or the one ``sheet``
  names or numbers; a workbook whose sheet lacks the columns is told which sheets have them);
- may start with comment lines beginning with ``#`` (e.g. ``# synthetic: produced by membrax``);
- has one header line of columns, each a name and its unit in brackets or parentheses, the name's case,
  spaces and hyphens aside (``Axial strain (%)`` is ``axial_strain [%]``, :func:`column_key`), the unit's
  case aside (``KPA`` is ``kPa``); every problem of the header is reported at once;
- then one row per reading, in loading order.

Columns (other columns are ignored whatever their form, so true internal stresses, times or remarks may
sit beside them):

- ``axial_strain``: unit ``-`` (a fraction) or ``%``;
- ``volumetric_strain`` or ``radial_strain``: ``-`` or ``%`` (one of the two; ε_r = 1 − √((1 − ε_v)/(1 −
  ε_a)) and its inverse, :func:`membrax.theory.radial_strain`);
- ``deviator_stress`` (q = σ1 − σ3) or ``axial_stress`` (σ1): ``Pa``, ``kPa`` or ``MPa``;
- ``cell_pressure`` (σ3): ``Pa``, ``kPa`` or ``MPa``.

Conventions: compression positive (a compressed specimen has ε_a > 0 and, while it contracts, ε_v > 0; a
bulging one has ε_r < 0), strains in the unit its header names. A record written dilation (extension)
positive is read with ``dilation_positive=True`` (``membrax correct --dilation-positive``), which negates
the volumetric or radial strain.

Checks, each with the line and column: a missing column; an unknown or missing unit; a value that is not a
finite number; a strain in ``-`` whose magnitude exceeds 1 (percent written as a fraction); an axial strain
that falls from row to row (unsorted, or an unloading branch) or below zero (extension positive); a
negative cell pressure, or one that moves from its first reading by more than
:data:`CELL_PRESSURE_TOLERANCE` of it (or :data:`CELL_PRESSURE_FLOOR_PA`). Of the whole record: an axial
strain under ``[%]`` that never exceeds :data:`SMALLEST_PERCENT_STRAIN` % (a fraction under a percent
header), or under ``[-]`` that exceeds
:data:`LARGEST_FRACTION_STRAIN` (percent under a fraction header); a volumetric strain that falls, or a
radial strain that grows, over the first :data:`EARLY_READINGS` readings (a record written dilation
positive: drained loading from an isotropic state starts by contracting, dε_v/dε_a = 1 − 2ν > 0).
Readings that repeat the axial strain of the row before (a logger holding its reading) are averaged into
one row, and the notes say how many.
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["LabRecord", "LabRecordError", "column_key", "read_lab_record"]

_STRESS_UNITS = {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6}
_STRAIN_UNITS = {"-": 1.0, "%": 1e-2}
# A header cell: a name, then optionally its unit in brackets or parentheses ("Axial strain (%)").
_HEADER = re.compile(r"^\s*([^\[\]()]*?)\s*(?:[\[(]\s*([^\])]*?)\s*[\])])?\s*$")
#: The columns read, each with its units (other columns are ignored): one of each group is needed.
_COLUMN_GROUPS = (
    ("axial_strain",),
    ("volumetric_strain", "radial_strain"),
    ("deviator_stress", "axial_stress"),
    ("cell_pressure",),
)
#: An axial strain under a ``[%]`` header that never exceeds this many percent is taken for a fraction: a
#: triaxial test to failure runs to several percent.
SMALLEST_PERCENT_STRAIN = 0.2
#: An axial strain under a ``[-]`` header above this (50 %) is taken for percent.
LARGEST_FRACTION_STRAIN = 0.5
#: How far the cell pressure may move from its first reading during a record: 5 % of it, or 1 kPa at the
#: lowest pressures (a pressure controller holds its set point to about 1 kPa; a larger change is a new
#: stage of a multistage test, whose membrane correction is another test's).
CELL_PRESSURE_TOLERANCE = 0.05
CELL_PRESSURE_FLOOR_PA = 1e3
#: The readings, the first of them the start, over which the sign of dε_v/dε_a (or dε_r/dε_a) is checked:
#: the contraction at the start of a dense specimen can be short (0.02 % of axial strain in an FCC
#: packing), so the check looks at the first readings rather than a strain window.
EARLY_READINGS = 4
#: The fix every unreadable file is told.
SAVE_AS = "save it from the spreadsheet as 'CSV UTF-8' (or as .xlsx)"
_ZIP_MAGIC = b"PK\x03\x04"
_OLE_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"


class LabRecordError(ValueError):
    """A laboratory record that cannot be read: the message names the line, the column and the fix."""


class LabRecord(NamedTuple):
    """A drained triaxial record in SI units (module docstring); every field a float64 array over rows.

    ``comments`` are the file's ``#`` lines; ``notes`` say what the reader did to the file (module
    docstring), for the user to see.
    """

    axial_strain: np.ndarray
    volumetric_strain: np.ndarray
    radial_strain: np.ndarray
    axial_stress: np.ndarray
    cell_pressure: np.ndarray
    comments: tuple
    notes: tuple = ()


class _Table(NamedTuple):
    """A file's cells: ``rows`` are (place number, [cell text]); ``place`` is "line" or "sheet 'X', row"."""

    rows: list
    place: str
    decimal_comma: bool
    notes: list
    sheets: tuple = ()  # a workbook's sheet names, in order


def _where(path, place, line, column=None, name=None) -> str:
    where = f"{path}, {place} {line}"
    if column is not None:
        where += f", column {column}"
    if name is not None:
        where += f" ({name})"
    return where


def _text_of(path: Path, data: bytes) -> str:
    """The file's text (module docstring's encodings), or a :class:`LabRecordError` saying what it is."""
    if data.startswith(_OLE_MAGIC):
        raise LabRecordError(f"{path} is an Excel 97-2003 workbook (.xls), not a text CSV; {SAVE_AS}.")
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError as error:
            raise LabRecordError(
                f"{path} has a UTF-16 mark but is not UTF-16 text ({error}); {SAVE_AS}."
            ) from None
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark, if any, is dropped
    except UnicodeDecodeError as error:
        binary = b"\x00" in data[:4096]
        what = "not a text CSV (it holds binary data)" if binary else "not UTF-8 text"
        raise LabRecordError(
            f"{path} is {what}: byte 0x{data[error.start]:02x} at offset {error.start} cannot be read; "
            f"{SAVE_AS}."
        ) from None
    if "\x00" in text:
        raise LabRecordError(f"{path} is not a text CSV (it holds NUL bytes); {SAVE_AS}.")
    return text


def _csv_table(path: Path, text: str) -> _Table:
    lines = text.splitlines()
    start = 0
    while start < len(lines) and (lines[start].startswith("#") or not lines[start].strip()):
        start += 1
    header = lines[start] if start < len(lines) else ""
    # The header names the separator: a spreadsheet in a decimal-comma locale writes semicolons.
    delimiter = ";" if ";" in header else "\t" if "\t" in header else ","
    notes = []
    if delimiter != ",":
        name = "semicolons" if delimiter == ";" else "tabs"
        notes.append(f"columns separated by {name}; decimal commas read as points")
    rows = [
        (number, next(csv.reader([line], delimiter=delimiter)) if not line.startswith("#") else [line])
        for number, line in enumerate(lines, start=1)
        if line.strip()
    ]
    return _Table(rows, "line", delimiter != ",", notes)


def _cell_text(value) -> str:
    """A worksheet cell as the text a CSV would hold (floats exactly, by ``repr``)."""
    if value is None:
        return ""
    return repr(value) if isinstance(value, float) else str(value)


def _workbook(path: Path, data: bytes):
    try:
        import openpyxl
    except ImportError:  # pragma: no cover - a dependency of membrax
        raise LabRecordError(
            f"{path} is an Excel workbook; install openpyxl to read it, or {SAVE_AS}."
        ) from None
    try:
        # From bytes: openpyxl refuses a path by its suffix, and a workbook may be named anything.
        return openpyxl.load_workbook(io.BytesIO(data), read_only=True, data_only=True)
    except Exception as error:  # openpyxl raises several kinds for a damaged or foreign zip
        raise LabRecordError(
            f"{path} is a zip file but not a readable .xlsx workbook ({type(error).__name__}: {error}); "
            f"{SAVE_AS}."
        ) from None


def _sheet_rows(sheet) -> list:
    rows = []
    for number, values in enumerate(sheet.iter_rows(values_only=True), start=1):
        cells = [_cell_text(value) for value in values]
        while cells and not cells[-1].strip():
            cells.pop()
        if cells:
            rows.append((number, cells))
    return rows


def _choose_sheet(path: Path, names: list, sheet) -> int:
    """The index of ``sheet`` (a name, or a number counted from 1) among ``names``."""
    if sheet is None:
        return 0
    text = str(sheet).strip()
    if text in names:
        return names.index(text)
    if text.isdigit() and 1 <= int(text) <= len(names):
        return int(text) - 1
    listed = ", ".join(f"{i} '{name}'" for i, name in enumerate(names, start=1))
    raise LabRecordError(
        f"{path}: no sheet {text!r}; the workbook's sheets are {listed} (--sheet NAME or NUMBER)."
    )


def _xlsx_table(path: Path, data: bytes, sheet=None) -> _Table:
    workbook = _workbook(path, data)
    names = [worksheet.title for worksheet in workbook.worksheets]
    index = _choose_sheet(path, names, sheet)
    chosen = workbook.worksheets[index]
    rows = _sheet_rows(chosen)
    workbook.close()
    which = "the first sheet" if index == 0 else f"sheet {index + 1}"
    notes = [f"read {which}, '{chosen.title}', of the workbook"]
    return _Table(rows, f"sheet '{chosen.title}', row", False, notes, tuple(names))


def _sheets_with_columns(path: Path, names) -> list:
    """The sheets of a workbook whose header has every needed column (for a message naming them)."""
    data = path.read_bytes()
    fitting = []
    for name in names:
        rows = _xlsx_table(path, data, name).rows
        header = next((cells for _, cells in rows if not cells[0].lstrip().startswith("#")), None)
        if header is None:
            continue
        try:
            _header_columns(path, "row", 0, header)
        except LabRecordError:
            continue
        fitting.append(name)
    return fitting


def _table(path: Path, sheet=None) -> _Table:
    data = path.read_bytes()
    if data.startswith(_ZIP_MAGIC):
        return _xlsx_table(path, data, sheet)
    if sheet is not None:
        raise LabRecordError(f"{path} is a text file, not a workbook: leave out --sheet {sheet}.")
    return _csv_table(path, _text_of(path, data))


def read_lab_record(path, dilation_positive: bool = False, sheet=None) -> LabRecord:
    """Read and check a laboratory record (module docstring).

    Args:
      path: the record: a CSV or an ``.xlsx`` workbook.
      dilation_positive: the volumetric (or radial) strain is written dilation (extension) positive; it is
        negated to membrax's compression-positive convention.
      sheet: a workbook's sheet to read, by name or by number counted from 1 (default the first).

    Raises:
      FileNotFoundError: no such file. LabRecordError: the file breaks a rule of the module docstring.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no laboratory record at '{path}'.")
    table = _table(path, sheet)
    place = table.place
    comments = []
    position = 0
    while position < len(table.rows) and table.rows[position][1][0].lstrip().startswith("#"):
        comments.append(table.rows[position][1][0].strip()[1:].strip())
        position += 1
    if position >= len(table.rows):
        raise LabRecordError(f"{path}: no header line; write one such as 'axial_strain [-],...'.")
    header_line, header = table.rows[position]
    try:
        wanted, strain_name, stress_name = _header_columns(path, place, header_line, header)
    except LabRecordError as error:
        if len(table.sheets) < 2:
            raise
        listed = ", ".join(f"'{name}'" for name in table.sheets)
        fitting = _sheets_with_columns(
            path, [name for name in table.sheets if place != f"sheet '{name}', row"]
        )
        hint = (
            f" Sheet {', '.join(repr(name) for name in fitting)} has them: pass --sheet {fitting[0]!r} "
            f"(sheet={fitting[0]!r})."
            if fitting
            else " No other sheet has them either."
        )
        raise LabRecordError(f"{error} The workbook's sheets: {listed}.{hint}") from None
    values = {name: [] for name in wanted}
    for line_number, row in table.rows[position + 1 :]:
        if row[0].lstrip().startswith("#"):
            continue
        for name, (index, scale, unit) in wanted.items():
            text = row[index - 1].strip() if index - 1 < len(row) else ""
            try:
                value = float(text.replace(",", ".") if table.decimal_comma else text)
            except ValueError:
                value = math.nan
            where = _where(path, place, line_number, index, name)
            if not math.isfinite(value):
                raise LabRecordError(
                    f"{where}: {text!r} is not a finite number; give a value or remove the row."
                )
            if unit == "-" and abs(value) > 1.0:
                raise LabRecordError(
                    f"{where}: {value:g} as a fraction is over 100 % strain; if the column is in percent, "
                    f"write '{name} [%]' in the header."
                )
            if name == "cell_pressure" and value < 0.0:
                raise LabRecordError(
                    f"{where}: {value:g} {unit}; a cell pressure is >= 0 (compression positive)."
                )
            if name == "cell_pressure" and values[name]:
                first = values[name][0]
                allowed = max(CELL_PRESSURE_TOLERANCE * first, CELL_PRESSURE_FLOOR_PA)
                if abs(value * scale - first) > allowed:
                    raise LabRecordError(
                        f"{where}: {value:g} {unit} against {first / scale:g} {unit} at the first reading; "
                        f"the cell pressure changes by more than {100 * CELL_PRESSURE_TOLERANCE:g} % (or "
                        f"{CELL_PRESSURE_FLOOR_PA / 1e3:g} kPa) during the record. membrax corrects a test "
                        "sheared at one cell pressure: split the record where the pressure changes and "
                        "correct each stage as its own test."
                    )
            if name == "axial_strain" and values[name] and value * scale < values[name][-1]:
                if value < 0.0 and max(values[name]) <= 0.0:
                    raise LabRecordError(
                        f"{where}: {value:g} after {values[name][-1] / scale:g}; the axial strain falls "
                        "below zero as the specimen is compressed. membrax takes compression positive: write "
                        "the axial strain of a compression test positive (flip the column's sign)."
                    )
                raise LabRecordError(
                    f"{where}: {value:g} after {values[name][-1] / scale:g}; the axial strain must not fall "
                    "from row to row: sort the record by time, or cut the unloading branch."
                )
            values[name].append(value * scale)
    data = {name: np.asarray(v, dtype=np.float64) for name, v in values.items()}
    notes = list(table.notes)
    data, notes = _average_repeats(data, notes)
    if data["axial_strain"].size < 2:
        raise LabRecordError(f"{path}: fewer than 2 rows of readings; give the whole record.")
    _check_strain_units(path, place, header_line, data["axial_strain"], wanted["axial_strain"])
    if dilation_positive:
        data[strain_name] = -data[strain_name]
        notes.append(f"{strain_name} negated (--dilation-positive): membrax takes compression positive")
    else:
        _check_strain_sign(path, place, header_line, data, strain_name, wanted[strain_name][0])
    axial, cell = data["axial_strain"], data["cell_pressure"]
    if strain_name == "volumetric_strain":
        volumetric = data["volumetric_strain"]
        radial = 1.0 - np.sqrt((1.0 - volumetric) / (1.0 - axial))
    else:
        radial = data["radial_strain"]
        volumetric = 1.0 - (1.0 - axial) * (1.0 - radial) ** 2
    axial_stress = data[stress_name] + (cell if stress_name == "deviator_stress" else 0.0)
    return LabRecord(axial, volumetric, radial, axial_stress, cell, tuple(comments), tuple(notes))


def column_key(name: str) -> str:
    """A header name as a column name, case, spaces and hyphens aside ("Axial strain": axial_strain)."""
    return re.sub(r"[\s\-_]+", "_", name.strip().lower()).strip("_")


def _units_of(name: str) -> dict:
    return _STRAIN_UNITS if name.endswith("strain") else _STRESS_UNITS


def _header_columns(path, place, header_line, header):
    """The needed columns of a header: ({name: (column, scale, unit)}, strain name, stress name).

    Names match case- and space-insensitively (:func:`column_key`), the unit in brackets or parentheses
    (its case aside); columns of other names are ignored whatever their form. Every problem of the header
    is reported at once.

    Raises:
      LabRecordError: naming each missing column, unknown unit and repeated column, with the fix.
    """
    columns, problems = {}, []
    known = {name for group in _COLUMN_GROUPS for name in group}
    for index, cell in enumerate(header, start=1):
        match = _HEADER.match(cell)
        name = column_key(match.group(1)) if match else ""
        if name not in known:
            continue
        if name in columns:
            first = columns[name][0]
            problems.append(f"column {index} ({cell.strip()!r}) repeats column {first}; keep one '{name}'")
            continue
        columns[name] = (index, match.group(2), cell.strip())
    chosen = []
    for group in _COLUMN_GROUPS:
        found = [name for name in group if name in columns]
        if not found:
            choices = " or ".join(f"'{name}'" for name in group)
            example = f"{group[0]} [{next(iter(_units_of(group[0])))}]"
            problems.append(f"no column {choices}; add it with its unit, e.g. '{example}'")
            continue
        chosen.append(found[0])
    wanted = {}
    for name in chosen:
        index, unit, cell = columns[name]
        units = _units_of(name)
        lookup = {key.lower(): (key, scale) for key, scale in units.items()}
        if unit is None or unit.lower() not in lookup:
            problems.append(
                f"column {index} ({cell!r}): "
                + ("no unit" if unit is None else f"unknown unit {unit!r}")
                + f"; write one of {', '.join(units)} in brackets, e.g. '{name} [{next(iter(units))}]'"
            )
            continue
        key, scale = lookup[unit.lower()]
        wanted[name] = (index, scale, key)
    if problems:
        header_text = ", ".join(repr(cell.strip()) for cell in header)
        raise LabRecordError(
            f"{_where(path, place, header_line)} (header {header_text}): "
            + "; ".join(problems)
            + ". Other columns are ignored."
        )
    return wanted, chosen[1], chosen[2]


def _average_repeats(data: dict, notes: list):
    """Rows whose axial strain repeats the row before's averaged into one (module docstring)."""
    axial = data["axial_strain"]
    if axial.size < 2:
        return data, notes
    starts = np.concatenate([[True], np.diff(axial) > 0.0])
    if np.all(starts):
        return data, notes
    group = np.cumsum(starts) - 1
    counts = np.bincount(group)
    averaged = {name: np.bincount(group, weights=value) / counts for name, value in data.items()}
    repeated = int(axial.size - counts.size)
    notes.append(
        f"{repeated} readings repeat the axial strain of the reading before (a logger holding its value); "
        f"each run of equal axial strains is averaged into one row: {counts.size} rows of {axial.size}"
    )
    return averaged, notes


def _check_strain_units(path, place, header_line, axial, spec) -> None:
    """A fraction under a ``[%]`` header or percent under ``[-]`` (module docstring)."""
    index, _, unit = spec
    where = _where(path, place, header_line, index, f"axial_strain [{unit}]")
    largest = float(np.max(axial))
    if unit == "%" and largest <= SMALLEST_PERCENT_STRAIN / 100.0:
        raise LabRecordError(
            f"{where}: the axial strain never exceeds {100 * largest:.3g} %; a triaxial test to failure runs "
            f"to several percent. Is the column a fraction under a [%] header? If so, write "
            f"'axial_strain [-]' in the header."
        )
    if unit == "-" and largest > LARGEST_FRACTION_STRAIN:
        raise LabRecordError(
            f"{where}: the axial strain reaches {largest:g}, that is {100 * largest:.3g} %. Is the column in "
            f"percent under a [-] header? If so, write 'axial_strain [%]' in the header."
        )


def _check_strain_sign(path, place, header_line, data, strain_name, index) -> None:
    """A record written dilation positive (module docstring): the sign of dε/dε_a over the first readings."""
    axial = data["axial_strain"][:EARLY_READINGS]
    strain = data[strain_name][:EARLY_READINGS]
    slope = float(np.polyfit(axial, strain, 1)[0]) if axial.size >= 2 else 0.0
    # The slope and the last early reading agree: one noisy reading does not make a record suspect.
    falls = slope < 0.0 and strain[-1] < strain[0]
    where = _where(path, place, header_line, index, strain_name)
    span = f"over the first {axial.size} readings, to {100 * axial[-1]:.3g} % axial strain"
    fix = (
        "membrax takes compression positive: if the file writes dilation positive, pass "
        "--dilation-positive (read_lab_record(..., dilation_positive=True)) or flip the column's sign."
    )
    if strain_name == "volumetric_strain" and falls:
        raise LabRecordError(
            f"{where}: the volumetric strain falls while the specimen is compressed (dε_v/dε_a = {slope:.3g} "
            f"{span}; a drained test starts by contracting). Is dilation written positive? " + fix
        )
    if strain_name == "radial_strain" and slope > 0.0 and strain[-1] > strain[0]:
        raise LabRecordError(
            f"{where}: the radial strain grows while the specimen is compressed (dε_r/dε_a = {slope:.3g} "
            f"{span}; a compressed specimen bulges, ε_r < 0). Is bulging written positive? " + fix
        )
