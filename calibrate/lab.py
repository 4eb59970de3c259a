"""Laboratory test records: a CSV with units in its header, read and checked before anything is computed.

Contract. :func:`read_lab_record` reads a drained triaxial test record and returns a :class:`LabRecord` in
SI units (Pa, strains as fractions, compression positive), or raises :class:`LabRecordError` naming the
line, the column and the fix. The file:

- may start with comment lines beginning with ``#`` (e.g. ``# synthetic: produced by membrax``);
- has one header line of comma-separated columns, each ``name [unit]``;
- then one row per reading, in loading order.

Columns (other columns are ignored, so true internal stresses may sit beside them):

- ``axial_strain``: unit ``-`` (a fraction) or ``%``;
- ``volumetric_strain`` or ``radial_strain``: ``-`` or ``%`` (one of the two; ε_r = 1 − √((1 − ε_v)/(1 −
  ε_a)) and its inverse, :func:`membrax.theory.radial_strain`);
- ``deviator_stress`` (q = σ1 − σ3) or ``axial_stress`` (σ1): ``Pa``, ``kPa`` or ``MPa``;
- ``cell_pressure`` (σ3): ``Pa``, ``kPa`` or ``MPa``.

Checks, each with the line and column: a missing column; an unknown or missing unit; a value that is not a
finite number; a strain in ``-`` whose magnitude exceeds 1 (percent written as a fraction); an axial strain
that does not increase from row to row (unsorted, or an unloading branch); a negative cell pressure.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["LabRecord", "LabRecordError", "read_lab_record"]

_STRESS_UNITS = {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6}
_STRAIN_UNITS = {"-": 1.0, "%": 1e-2}
_HEADER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[\s*([^\]]*?)\s*\])?\s*$")


class LabRecordError(ValueError):
    """A laboratory record that cannot be read: the message names the line, the column and the fix."""


class LabRecord(NamedTuple):
    """A drained triaxial record in SI units (module docstring); every field a float64 array over rows."""

    axial_strain: np.ndarray
    volumetric_strain: np.ndarray
    radial_strain: np.ndarray
    axial_stress: np.ndarray
    cell_pressure: np.ndarray
    comments: tuple


def _where(path, line, column=None, name=None) -> str:
    place = f"{path}, line {line}"
    if column is not None:
        place += f", column {column}"
    if name is not None:
        place += f" ({name})"
    return place


def read_lab_record(path) -> LabRecord:
    """Read and check a laboratory record (module docstring).

    Raises:
      FileNotFoundError: no such file. LabRecordError: the file breaks a rule of the module docstring.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no laboratory record at '{path}'.")
    lines = path.read_text().splitlines()
    comments, start = [], 0
    while start < len(lines) and (lines[start].startswith("#") or not lines[start].strip()):
        if lines[start].startswith("#"):
            comments.append(lines[start][1:].strip())
        start += 1
    if start >= len(lines):
        raise LabRecordError(f"{path}: no header line; write one such as 'axial_strain [-],...'.")
    header_line = start + 1
    header = next(csv.reader([lines[start]]))
    columns = {}
    for index, cell in enumerate(header, start=1):
        match = _HEADER.match(cell)
        if not match:
            raise LabRecordError(
                f"{_where(path, header_line, index)}: {cell!r} is not 'name [unit]'; "
                "e.g. 'cell_pressure [kPa]'."
            )
        columns[match.group(1)] = (index, match.group(2))

    def unit_of(name, units):
        index, unit = columns[name]
        if unit is None or unit not in units:
            raise LabRecordError(
                f"{_where(path, header_line, index, name)}: unknown unit {unit!r}; write one of "
                f"{', '.join(units)} in brackets, e.g. '{name} [{next(iter(units))}]'."
            )
        return index, units[unit], unit

    def need(*names):
        found = [name for name in names if name in columns]
        if not found:
            choices = " or ".join(f"'{name}'" for name in names)
            raise LabRecordError(
                f"{_where(path, header_line)} (header): no column {choices}; add it with its unit."
            )
        return found[0]

    strain_name = need("volumetric_strain", "radial_strain")
    stress_name = need("deviator_stress", "axial_stress")
    need("axial_strain")
    need("cell_pressure")
    wanted = {
        "axial_strain": unit_of("axial_strain", _STRAIN_UNITS),
        strain_name: unit_of(strain_name, _STRAIN_UNITS),
        stress_name: unit_of(stress_name, _STRESS_UNITS),
        "cell_pressure": unit_of("cell_pressure", _STRESS_UNITS),
    }
    values = {name: [] for name in wanted}
    for line_number, line in enumerate(lines[start + 1 :], start=header_line + 1):
        if not line.strip() or line.startswith("#"):
            continue
        row = next(csv.reader([line]))
        for name, (index, scale, unit) in wanted.items():
            text = row[index - 1].strip() if index - 1 < len(row) else ""
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise LabRecordError(
                    f"{_where(path, line_number, index, name)}: {text!r} is not a finite number; "
                    "give a value or remove the row."
                )
            if unit == "-" and abs(value) > 1.0:
                raise LabRecordError(
                    f"{_where(path, line_number, index, name)}: {value:g} as a fraction is over 100 % "
                    f"strain; if the column is in percent, write '{name} [%]' in the header."
                )
            if name == "cell_pressure" and value < 0.0:
                raise LabRecordError(
                    f"{_where(path, line_number, index, name)}: {value:g} {unit}; a cell pressure is >= 0 "
                    "(compression positive)."
                )
            if name == "axial_strain" and values[name] and value * scale <= values[name][-1]:
                raise LabRecordError(
                    f"{_where(path, line_number, index, name)}: {value:g} after "
                    f"{values[name][-1] / scale:g}; the axial strain must increase row by row: sort the "
                    "record, or cut the unloading branch."
                )
            values[name].append(value * scale)
    if len(values["axial_strain"]) < 2:
        raise LabRecordError(f"{path}: fewer than 2 rows of readings; give the whole record.")
    data = {name: np.asarray(v, dtype=np.float64) for name, v in values.items()}
    axial, cell = data["axial_strain"], data["cell_pressure"]
    if strain_name == "volumetric_strain":
        volumetric = data["volumetric_strain"]
        radial = 1.0 - np.sqrt((1.0 - volumetric) / (1.0 - axial))
    else:
        radial = data["radial_strain"]
        volumetric = 1.0 - (1.0 - axial) * (1.0 - radial) ** 2
    axial_stress = data[stress_name] + (cell if stress_name == "deviator_stress" else 0.0)
    return LabRecord(axial, volumetric, radial, axial_stress, cell, tuple(comments))
