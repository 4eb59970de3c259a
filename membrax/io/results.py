"""Results tables: records → xarray.Dataset → NetCDF3 and CSV, and back.

Results tables. :func:`records_to_dataset` turns the driver's records (a dict, a dataclass such as
:class:`membrax.spheres.measure.Measurements`, or a NamedTuple of arrays whose first axis is time) into an
:class:`xarray.Dataset` over the dimension ``time_dim`` (default ``"record"``): an array of shape (T,) or
(T, 1) becomes a 1-D variable (the size-1 member axis of a one-specimen run is squeezed), (T, k) with
k > 1 a 2-D variable with second dimension ``"{name}_component"``, higher ranks keep their extra axes as
``"{name}_dim1"``, ``"{name}_dim2"``, …. ``step``, if present, is also a coordinate. ``None`` values and
jax-md static fields are skipped. Optional ``units`` give each variable a ``units`` attribute. Dataset
attributes that are not str, int (within int32) or float (bools, None, dicts, lists, large ints) are
stored as JSON strings, listed in the attribute ``"membrax_json_attrs"``;
:func:`dataset_attrs_to_python` gives all attributes back as Python values.

:func:`write_results` writes ``{stem}.nc`` and ``{stem}.csv`` into a folder (created if missing):

- ``{stem}.nc``: NetCDF3 64-bit offset through scipy (no netCDF4 library needed). netCDF3 has no bool,
  int64 or unsigned types, so such variables are stored as int8 (bool), int32 (integers that fit) or
  float64 (integers beyond int32 but exact in float64) with the variable attribute ``"membrax_dtype"``
  naming the original dtype; :func:`read_results` restores it (and drops that attribute), so a round
  trip gives back the same values and dtypes, loaded into memory with the file closed.
- ``{stem}.csv``: leading comment lines ``# key: value`` with the dataset attributes, one header line of
  comma-separated column names, then one row per record. Columns: the coordinates, then the data
  variables, whose first dimension is the time dimension (the first dimension of the first variable,
  unless ``time_dim`` is given; other variables are only in the ``.nc``). A 2-D variable ``name``
  expands to ``name_0, name_1, …``; higher ranks to ``name_i_j…`` in C order. Floats are written with
  Python's ``repr`` (the shortest string that reads back to the same float64, at most 17 significant
  digits; ``nan``/``inf`` as such), integers as integers, bools as 0/1. Read it with
  ``np.loadtxt(path, delimiter=",", skiprows=1)`` (``#`` lines are comments) or
  ``pandas.read_csv(path, comment="#")``. Units are stored only in the ``.nc``.

Errors: :mod:`membrax.io`.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
from collections.abc import Mapping
from io import BytesIO
from pathlib import Path

import jax
import numpy as np
import xarray as xr

from membrax.io.files import (
    NAME_PATTERN,
    atomic_write_bytes,
    check_stem,
    ensure_folder,
    existing_file,
)

__all__ = [
    "records_to_dataset",
    "dataset_attrs_to_python",
    "write_results",
    "write_netcdf",
    "read_results",
    "write_compressed_copy",
]

#: Dataset attribute listing the attributes stored as JSON strings.
JSON_ATTRS_KEY = "membrax_json_attrs"
#: Variable attribute naming the original dtype of a variable stored as another netCDF3 type.
DTYPE_ATTR = "membrax_dtype"
#: Dataset attribute in the ``.nc`` with the data-variable order (the writer reorders; read_results restores).
ORDER_ATTR = "membrax_variable_order"
_INT32 = np.iinfo(np.int32)
_FLOAT64_EXACT_INT = 2**53

# ----------------------------------------------------------------------------------------------------------
# Results: records -> xarray.Dataset -> NetCDF3 + CSV
# ----------------------------------------------------------------------------------------------------------


def _record_items(records) -> list[tuple[object, object]]:
    if isinstance(records, Mapping):
        return list(records.items())
    if dataclasses.is_dataclass(records) and not isinstance(records, type):
        return [
            (field.name, getattr(records, field.name))
            for field in dataclasses.fields(records)
            if not field.metadata.get("static", False) and field.metadata.get("pytree_node", True)
        ]
    if isinstance(records, tuple) and hasattr(records, "_asdict"):
        return list(records._asdict().items())
    raise ValueError(
        f"records is a {type(records).__name__}; give a dict, a dataclass (e.g. Measurements) or a "
        "NamedTuple mapping names to arrays whose first axis is time."
    )


def _check_name(kind: str, name) -> str:
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise ValueError(
            f"{kind} name {name!r} is not a valid NetCDF name; use letters, digits and '_' (starting with a "
            "letter or '_'), e.g. 'axial_strain'."
        )
    return name


def _json_default(value):
    if isinstance(value, np.ndarray | np.generic | jax.Array):
        return np.asarray(value).tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _encode_attrs(attrs) -> dict:
    """Attributes for a netCDF3 file: str, int32-range int and float as they are, the rest as JSON."""
    if attrs is None:
        return {}
    if not isinstance(attrs, Mapping):
        raise ValueError(f"attrs must be a dict of metadata, got {type(attrs).__name__}.")
    encoded, json_keys = {}, []
    for key, value in attrs.items():
        _check_name("attribute", key)
        if key in (JSON_ATTRS_KEY, ORDER_ATTR):
            raise ValueError(f"attribute name {key!r} is reserved for the file format; rename it.")
        if isinstance(value, np.generic) and not isinstance(value, np.bool_):
            value = value.item()
        if isinstance(value, str | float):
            encoded[key] = value
            continue
        if isinstance(value, int) and not isinstance(value, bool) and _INT32.min <= value <= _INT32.max:
            encoded[key] = value
            continue
        try:
            encoded[key] = json.dumps(value, default=_json_default)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"attrs[{key!r}] of type {type(value).__name__} cannot be stored ({error}); give a str, "
                "number, bool, None, or a list or dict of those."
            ) from error
        json_keys.append(key)
    if json_keys:
        encoded[JSON_ATTRS_KEY] = json.dumps(json_keys)
    return encoded


def records_to_dataset(records, attrs=None, time_dim: str = "record", units=None) -> xr.Dataset:
    """The records of a run as an :class:`xarray.Dataset` over ``time_dim`` (module docstring).

    Args:
      records: dict, dataclass (e.g. :class:`membrax.spheres.measure.Measurements`, static fields skipped) or
        NamedTuple mapping names to numpy/JAX arrays whose first axis is time (T records). ``None``
        values are skipped.
      attrs: optional dict of run metadata for the dataset attributes (any JSON-able values; those that
        are not str, int32-range int or float are stored as JSON, see :func:`dataset_attrs_to_python`).
      time_dim: name of the time dimension.
      units: optional dict name -> units string (e.g. ``{"wall_axial_stress": "Pa"}``), stored as each
        variable's ``units`` attribute.

    Returns:
      The dataset; ``step`` (if present) is a coordinate.

    Raises:
      ValueError: naming the record, for a scalar (no time axis), a record length different from the
        others, a non-numeric dtype, an invalid name, or a ``units`` entry for an unknown record.
    """
    _check_name("time_dim", time_dim)
    variables: dict[str, xr.Variable] = {}
    length = None
    first = None
    for name, value in _record_items(records):
        if value is None:
            continue
        _check_name("record", name)
        if name == time_dim:
            raise ValueError(f"record {name!r} has the name of time_dim; rename it or pass another time_dim.")
        array = np.asarray(value)
        if array.dtype.kind not in "biuf":
            raise ValueError(
                f"record {name!r} has dtype {array.dtype}; only bool, integer and float records can be "
                "stored, convert it to numbers."
            )
        if array.ndim == 0:
            raise ValueError(
                f"record {name!r} is a scalar; every record needs a leading time axis (shape (T, ...)), "
                "put constants in attrs instead."
            )
        if length is None:
            length, first = array.shape[0], name
        elif array.shape[0] != length:
            raise ValueError(
                f"record {name!r} has {array.shape[0]} entries along its first (time) axis but {first!r} "
                f"has {length}; all records must come from the same run."
            )
        if array.ndim == 2 and array.shape[1] == 1:
            array = array[:, 0]
        if array.ndim == 1:
            dims: tuple[str, ...] = (time_dim,)
        elif array.ndim == 2:
            dims = (time_dim, f"{name}_component")
        else:
            dims = (time_dim, *(f"{name}_dim{axis}" for axis in range(1, array.ndim)))
        variables[name] = xr.Variable(dims, array)
    if units is not None:
        if not isinstance(units, Mapping):
            raise ValueError(f"units must be a dict name -> units string, got {type(units).__name__}.")
        for name, unit in units.items():
            if name not in variables:
                raise ValueError(
                    f"units names {name!r}, which is not a record; records are {sorted(variables)}."
                )
            if not isinstance(unit, str):
                raise ValueError(f"units[{name!r}] = {unit!r}; give a string such as 'Pa'.")
            variables[name].attrs["units"] = unit
    dataset = xr.Dataset(variables, attrs=_encode_attrs(attrs))
    if "step" in dataset.data_vars:
        dataset = dataset.set_coords("step")
    return dataset


def dataset_attrs_to_python(dataset) -> dict:
    """The dataset attributes as Python values: JSON attributes decoded, numpy scalars as int/float."""
    attrs = dataset.attrs
    json_keys = set(json.loads(attrs[JSON_ATTRS_KEY])) if JSON_ATTRS_KEY in attrs else set()
    result = {}
    for key, value in attrs.items():
        if key == JSON_ATTRS_KEY:
            continue
        if key in json_keys:
            result[key] = json.loads(value)
        elif isinstance(value, np.ndarray):
            result[key] = value.item() if value.size == 1 else value.tolist()
        elif isinstance(value, np.generic):
            result[key] = value.item()
        else:
            result[key] = value
    return result


def _storable_attrs(attrs: Mapping) -> dict:
    """Dataset attributes fit for netCDF3: already-encoded JSON attributes kept, the others encoded."""
    json_keys = json.loads(attrs[JSON_ATTRS_KEY]) if JSON_ATTRS_KEY in attrs else []
    encoded = _encode_attrs({key: value for key, value in attrs.items() if key != JSON_ATTRS_KEY})
    new_keys = json.loads(encoded.pop(JSON_ATTRS_KEY, "[]"))
    json_keys += [key for key in new_keys if key not in json_keys]
    if json_keys:
        encoded[JSON_ATTRS_KEY] = json.dumps(json_keys)
    return encoded


def _netcdf3_variable(name: str, variable: xr.Variable) -> xr.Variable:
    """``variable`` in a netCDF3 type, tagged with :data:`DTYPE_ATTR` when the type changed."""
    values = np.asarray(variable.values)
    attrs = dict(variable.attrs)
    kind, dtype = values.dtype.kind, values.dtype
    if kind == "b":
        stored = values.astype(np.int8)
    elif kind in "iu":
        if dtype in (np.dtype(np.int8), np.dtype(np.int16), np.dtype(np.int32)):
            stored = values
        elif values.size == 0 or (values.min() >= _INT32.min and values.max() <= _INT32.max):
            stored = values.astype(np.int32)
        elif values.min() >= -_FLOAT64_EXACT_INT and values.max() <= _FLOAT64_EXACT_INT:
            stored = values.astype(np.float64)
        else:
            raise ValueError(
                f"variable {name!r} has integers beyond ±2**53, which NetCDF3 cannot store exactly; "
                "store them as floats or split them."
            )
    elif dtype in (np.dtype(np.float32), np.dtype(np.float64)):
        stored = values
    elif dtype == np.dtype(np.float16):
        stored = values.astype(np.float32)
    elif kind == "U":  # text (a member's status): xarray stores it as characters
        stored = values
    else:
        raise ValueError(
            f"variable {name!r} has dtype {dtype}, which NetCDF3 cannot store; convert it to bool, integers "
            "or float32/float64."
        )
    if stored.dtype != dtype:
        attrs[DTYPE_ATTR] = str(dtype)
    return xr.Variable(variable.dims, stored, attrs=attrs)


def _netcdf_bytes(dataset: xr.Dataset) -> bytes:
    coords = {name: _netcdf3_variable(name, dataset.variables[name]) for name in dataset.coords}
    data_vars = {name: _netcdf3_variable(name, dataset.variables[name]) for name in dataset.data_vars}
    attrs = {**dataset.attrs, ORDER_ATTR: json.dumps(list(dataset.data_vars))}
    encoded = xr.Dataset(data_vars, coords=coords, attrs=attrs)
    encoding = {name: {"_FillValue": None} for name in encoded.variables}
    return bytes(encoded.to_netcdf(engine="scipy", format="NETCDF3_64BIT", encoding=encoding))


def _format_column(values: np.ndarray) -> list[str]:
    if values.dtype.kind == "b":
        return ["1" if value else "0" for value in values.tolist()]
    if values.dtype.kind in "iu":
        return [str(value) for value in values.tolist()]
    return [repr(value) for value in values.astype(np.float64).tolist()]


def _comment_value(value) -> str:
    """An attribute value for a ``# key: value`` line: str as is, numbers by repr, the rest as JSON."""
    if isinstance(value, str):
        return json.dumps(value) if ("\n" in value or "\r" in value) else value
    if isinstance(value, int | float) and not isinstance(value, bool):
        return repr(value)
    return json.dumps(value, default=_json_default)


def _csv_text(dataset: xr.Dataset, time_dim: str | None) -> str:
    names = list(dataset.coords) + list(dataset.data_vars)
    if time_dim is None:
        time_dim = next(
            (dataset.variables[name].dims[0] for name in dataset.data_vars if dataset.variables[name].dims),
            None,
        )
    header: list[str] = []
    columns: list[list[str]] = []
    for name in names:
        variable = dataset.variables[name]
        if not variable.dims or variable.dims[0] != time_dim:
            continue
        values = np.asarray(variable.values)
        if values.ndim == 1:
            parts = [(str(name), values)]
        else:
            flat = values.reshape(values.shape[0], -1)
            parts = [
                (f"{name}_" + "_".join(str(i) for i in index), flat[:, k])
                for k, index in enumerate(np.ndindex(*values.shape[1:]))
            ]
        for column, column_values in parts:
            if column in header:
                raise ValueError(
                    f"CSV column {column!r} occurs twice (a variable name clashes with an expanded "
                    "multi-column variable); rename one of them."
                )
            header.append(column)
            columns.append(_format_column(column_values))
    attrs = dataset_attrs_to_python(dataset)
    lines = [f"# {key}: {_comment_value(value)}" for key, value in attrs.items()]
    lines.append(",".join(header))
    lines.extend(",".join(row) for row in zip(*columns, strict=True))
    return "\n".join(lines) + "\n"


def write_results(dataset, folder, stem: str = "results", time_dim: str | None = None) -> dict[str, Path]:
    """Write ``{stem}.nc`` (NetCDF3 via scipy) and ``{stem}.csv`` into ``folder``, each atomically.

    Args:
      dataset: an :class:`xarray.Dataset`, e.g. from :func:`records_to_dataset`.
      folder: output folder, created if missing.
      stem: file-name stem.
      time_dim: the dimension whose entries are the CSV rows; default the first dimension of the first
        data variable.

    Returns:
      ``{"nc": path of the .nc file, "csv": path of the .csv file}``.

    Raises:
      ValueError: if ``folder`` is not a directory, ``stem`` is not a plain name, or a variable cannot be
        stored in NetCDF3 (strings, complex numbers, integers beyond ±2**53).
    """
    if not isinstance(dataset, xr.Dataset):
        raise ValueError(
            f"dataset is a {type(dataset).__name__}; pass an xarray.Dataset, e.g. "
            "records_to_dataset(records)."
        )
    folder = ensure_folder(folder)
    stem = check_stem(stem)
    dataset = dataset.copy(deep=False)
    dataset.attrs = _storable_attrs(dataset.attrs)
    netcdf = _netcdf_bytes(dataset)
    text = _csv_text(dataset, time_dim).encode("utf-8")
    paths = {"nc": folder / f"{stem}.nc", "csv": folder / f"{stem}.csv"}
    atomic_write_bytes(paths["nc"], netcdf)
    atomic_write_bytes(paths["csv"], text)
    return paths


def write_netcdf(dataset, path) -> Path:
    """Write an :class:`xarray.Dataset` of any dimensions to one NetCDF3 file (scipy engine), atomically.

    The multi-dimensional sibling of :func:`write_results` (no CSV: a grid of runs does not flatten into one
    table); read it back with :func:`read_results`. Returns the path.
    """
    if not isinstance(dataset, xr.Dataset):
        raise ValueError(f"dataset is a {type(dataset).__name__}; pass an xarray.Dataset.")
    path = Path(os.fspath(path))
    if path.is_dir():
        raise ValueError(f"NetCDF path '{path}' is a directory; give a file name such as 'sweep.nc'.")
    ensure_folder(path.parent, "the folder of the NetCDF path")
    dataset = dataset.copy(deep=False)
    dataset.attrs = _storable_attrs(dataset.attrs)
    atomic_write_bytes(path, _netcdf_bytes(dataset))
    return path


#: The first two bytes of a gzip stream (RFC 1952).
_GZIP_MAGIC = b"\x1f\x8b"


def write_compressed_copy(source, target) -> Path:
    """Write a gzip-compressed copy of the results file ``source`` to ``target`` (atomically), and return it.

    A sweep of a long campaign is kept in a repository this way (a third to a tenth of the size; the
    stream's time stamp is zeroed, so the same file always compresses to the same bytes).
    :func:`read_results` reads the copy as the original.

    Raises:
      FileNotFoundError: ``source`` missing. ValueError: ``source`` is not a NetCDF3 results file.
    """
    source = existing_file(source, "results file", "pass a .nc that write_results wrote", "the .nc file")
    data = source.read_bytes()
    read_results(source)  # refuses a file that is not a results file, before anything is written
    target = Path(os.fspath(target))
    ensure_folder(target.parent, "the folder of the compressed copy")
    atomic_write_bytes(target, gzip.compress(data, compresslevel=9, mtime=0))
    return target


def read_results(path) -> xr.Dataset:
    """Read a ``.nc`` written by :func:`write_results`, loaded into memory, the file closed.

    Variables stored under another netCDF3 type get their original dtype back (:data:`DTYPE_ATTR`). A
    gzip-compressed file (``.nc.gz``, :func:`write_compressed_copy`; told by its magic bytes, not its name)
    is read the same way.

    Raises:
      FileNotFoundError: if ``path`` does not exist.
      ValueError: if ``path`` is not a NetCDF3 file.
    """
    path = existing_file(
        path, "results file", "pass the {stem}.nc that write_results wrote", "the {stem}.nc file"
    )
    data = path.read_bytes()
    if data[:2] == _GZIP_MAGIC:
        data = gzip.decompress(data)
    try:
        with xr.open_dataset(
            BytesIO(data),
            engine="scipy",
            decode_times=False,
            decode_timedelta=False,
            mask_and_scale=False,
        ) as opened:
            dataset = opened.load()
    except Exception as error:
        hint = " (that is the CSV; read_results reads the .nc)" if path.suffix.lower() == ".csv" else ""
        raise ValueError(
            f"'{path}' is not a NetCDF3 results file{hint}: {error}; pass the {{stem}}.nc that "
            "write_results wrote."
        ) from error
    for name in list(dataset.variables):
        variable = dataset.variables[name]
        if DTYPE_ATTR in variable.attrs:
            attrs = {key: value for key, value in variable.attrs.items() if key != DTYPE_ATTR}
            restored = xr.Variable(
                variable.dims, variable.values.astype(np.dtype(variable.attrs[DTYPE_ATTR])), attrs=attrs
            )
            if name in dataset.coords:
                dataset = dataset.assign_coords({name: restored})
            else:
                dataset[name] = restored
        dataset.variables[name].encoding = {}
    order = json.loads(dataset.attrs.pop(ORDER_ATTR, "[]"))
    if sorted(order) == sorted(dataset.data_vars):
        dataset = dataset[order]
    return dataset
