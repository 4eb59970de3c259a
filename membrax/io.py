"""VTK export of the membrane and the particles through meshio, for viewing in ParaView.

Contract. :func:`write_membrane_vtk` writes the triangulated membrane and :func:`write_particles_vtk` the
spheres, each as one VTK unstructured-grid XML file (``.vtu``; any other suffix is refused). Inputs may
be numpy or JAX arrays (converted on the host with ``np.asarray``); nothing is traced, so call these
outside ``jax.jit``. SI units throughout: positions and radii in m, forces in N, velocities in m/s; the
files store the numbers as given, in float64, without conversion.

- Membrane: the nodes are the points, the triangles are VTK "triangle" cells (0-based node indices).
  Point fields have shape (N,) or (N, 3) (e.g. ``"contact_force"``, ``"indentation"``), cell fields
  (T,) or (T, 3) (e.g. ``"stretch"``).
- Particles: the centres are the points, one VTK "vertex" cell per particle. The point fields
  ``"radius"`` and ``"diameter"`` (= 2·radius, m) are always written; extra point fields have shape (N,)
  or (N, 3) (e.g. ``"velocity"``, ``"force"``).

Float fields are written as float64, integer fields as int64, boolean fields as uint8 (0/1).

Checks. A wrong shape, a NaN or infinite value, a non-positive radius, a triangle index outside
[0, N), a reserved or empty field name, or a wrong suffix raise ``ValueError`` naming the argument or
field and saying how to fix it. Nothing is written when a check fails.

Viewing in ParaView. Open the ``.vtu`` file and press Apply. Membrane: colour by any field. Particles:
apply Filters → Glyph, Glyph Type "Sphere", Scale Array "diameter", Scale Factor 1 (the unit sphere
glyph has diameter 1, so each glyph then has the particle's true size), Glyph Mode "All Points".

Results tables. :func:`records_to_dataset` turns the driver's records (a dict, a dataclass such as
:class:`membrax.measure.Measurements`, or a NamedTuple of arrays whose first axis is time) into an
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

VTK time series. :class:`VTKSeries` writes ``{stem}_membrane_{step:09d}.vtu`` and
``{stem}_particles_{step:09d}.vtu`` (through the writers above) and after every :meth:`VTKSeries.add`
rewrites the ParaView collections ``{stem}_membrane.pvd`` and ``{stem}_particles.pvd``, which list
``<DataSet timestep="{time}" part="0" file="{file}.vtu"/>`` in step order, file names relative to the
folder. Open the ``.pvd`` in ParaView to get a time series. On construction the existing ``.pvd``
entries are read back, so a resumed run appends to them; ``resume_step`` (or
:meth:`VTKSeries.truncate_after`) drops the entries with a later step and deletes their files.

Checkpoints. :func:`save_checkpoint` stores any JAX pytree (jax-md dataclasses, NamedTuples, dicts,
arrays, Python scalars, typed PRNG keys) and an optional ``host`` dict in one ``.npz``: the leaves of
``jax.tree_util.tree_flatten(state)`` as ``leaf_00000``, ``leaf_00001``, …; numpy/JAX array values of
``host`` as ``host__{key}``; the other ``host`` values as one JSON string ``__host__``; and a JSON string
``__meta__`` with the format name, version, and every leaf's key path, shape and dtype. Nothing is
pickled. :func:`load_checkpoint` rebuilds the state with the tree structure of a template ``like`` (a
state of the same configuration, or ``jax.eval_shape`` of one), checks the leaf count, shapes and
dtypes, and returns the leaves bit-exact: JAX array leaves of the template as JAX arrays of its dtype,
numpy leaves as numpy arrays, Python scalars as Python scalars. JSON turns tuples into lists.

Atomic writes. Every file written here (``.nc``, ``.csv``, ``.vtu`` of a series, ``.pvd``, checkpoint)
goes to a temporary file ``.{name}.*.tmp`` in the destination folder, is flushed and fsynced, and then
moved over the destination with ``os.replace``: a crash mid-write leaves the previous file intact (or
no file), never a half-written one, and the temporary file is removed when the write fails.

Errors. A folder argument that exists but is not a directory, a bad stem, a file that is not a
checkpoint or results file, a damaged ``.npz``, or a checkpoint of another configuration raise
``ValueError`` naming the path and the fix; a missing file raises ``FileNotFoundError``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import operator
import os
import re
import secrets
import xml.etree.ElementTree as ElementTree
from collections.abc import Callable, Mapping
from io import BytesIO
from pathlib import Path
from xml.sax.saxutils import quoteattr

import jax
import jax.numpy as jnp
import meshio
import numpy as np
import xarray as xr

__all__ = [
    "write_membrane_vtk",
    "write_particles_vtk",
    "records_to_dataset",
    "dataset_attrs_to_python",
    "write_results",
    "write_netcdf",
    "read_results",
    "VTKSeries",
    "read_pvd",
    "save_checkpoint",
    "load_checkpoint",
    "read_checkpoint_host",
]

#: Field names written by :func:`write_particles_vtk` itself; users may not pass them.
PARTICLE_RESERVED_FIELDS = ("radius", "diameter")


def _check_suffix(path) -> str:
    path = os.fspath(path)
    if not str(path).lower().endswith(".vtu"):
        raise ValueError(
            f"path = {path!r} does not end in '.vtu'; these writers produce VTK XML unstructured grids, "
            "give a file name ending in .vtu."
        )
    return path


def _finite_float(name: str, value, shape_hint: str) -> np.ndarray:
    """``value`` as float64; ValueError naming ``name`` if it is not real or not finite."""
    array = np.asarray(value)
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} has dtype {array.dtype}; give real numbers, {shape_hint}.")
    array = array.astype(np.float64)
    if not np.isfinite(array).all():
        bad = int(np.count_nonzero(~np.isfinite(array)))
        raise ValueError(
            f"{name} has {bad} NaN or infinite value(s); ParaView cannot show them, "
            "remove or replace them before writing."
        )
    return array


def _positions(name: str, value) -> np.ndarray:
    array = _finite_float(name, value, "an (N, 3) array of x, y, z in m")
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"{name} has shape {array.shape}; expected (N, 3) with N >= 1: x, y, z in m.")
    return array


def _fields(kind: str, fields: Mapping | None, count: int, what: str, reserved=()) -> dict:
    """Validate a dict of (count,) or (count, 3) fields and convert them to numpy arrays for meshio."""
    if fields is None:
        return {}
    if not isinstance(fields, Mapping):
        raise ValueError(f"{kind} must be a dict mapping field names to arrays, got {type(fields).__name__}.")
    converted = {}
    for name, value in fields.items():
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"{kind} has a field named {name!r}; field names must be non-empty strings.")
        if name in reserved:
            raise ValueError(
                f"{kind} field {name!r} is reserved (written from `radius`); rename it or leave it out."
            )
        label = f"{kind} field {name!r}"
        array = np.asarray(value)
        expected = f"({count},) or ({count}, 3): one value or one 3-vector per {what}"
        if array.ndim not in (1, 2) or array.shape[0] != count or (array.ndim == 2 and array.shape[1] != 3):
            raise ValueError(f"{label} has shape {array.shape}; expected {expected}.")
        if array.dtype == np.bool_:
            array = array.astype(np.uint8)
        elif np.issubdtype(array.dtype, np.integer):
            array = array.astype(np.int64)
        else:
            array = _finite_float(label, array, f"shape {expected}")
        converted[name] = array
    return converted


def write_membrane_vtk(path, node_position, triangles, point_data=None, cell_data=None) -> None:
    """Write the triangulated membrane as a ``.vtu`` file of VTK triangle cells.

    Args:
      path: output file name, ending in ``.vtu`` (str or path-like); overwritten if it exists.
      node_position: (N, 3) node positions in m.
      triangles: (T, 3) integer node indices in [0, N), e.g. ``MembraneMesh.triangles``.
      point_data: optional dict name -> (N,) or (N, 3) array of per-node values (SI units), e.g.
        ``{"contact_force": f, "indentation": delta}``.
      cell_data: optional dict name -> (T,) or (T, 3) array of per-triangle values, e.g.
        ``{"stretch": lam}``.

    Raises:
      ValueError: naming the argument or field, for a wrong suffix or shape, a NaN or infinite value, a
        non-integer triangle array, or a triangle index outside [0, N).
    """
    path = _check_suffix(path)
    points = _positions("node_position", node_position)
    cells = np.asarray(triangles)
    if not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"triangles has dtype {cells.dtype}; give integer node indices, shape (T, 3).")
    if cells.ndim != 2 or cells.shape[1] != 3 or cells.shape[0] == 0:
        raise ValueError(f"triangles has shape {cells.shape}; expected (T, 3) with T >= 1 node indices.")
    cells = cells.astype(np.int64)
    num_nodes = points.shape[0]
    out_of_range = (cells < 0) | (cells >= num_nodes)
    if out_of_range.any():
        row = int(np.argwhere(out_of_range)[0, 0])
        raise ValueError(
            f"triangles[{row}] = {cells[row].tolist()} indexes outside [0, {num_nodes}) for the "
            f"{num_nodes} rows of node_position; use 0-based indices into node_position."
        )
    points_fields = _fields("point_data", point_data, num_nodes, "node")
    cell_fields = _fields("cell_data", cell_data, cells.shape[0], "triangle")
    mesh = meshio.Mesh(
        points,
        [("triangle", cells)],
        point_data=points_fields,
        cell_data={name: [array] for name, array in cell_fields.items()},
    )
    meshio.write(path, mesh, file_format="vtu")


def write_particles_vtk(path, position, radius, point_data=None) -> None:
    """Write the particles as a ``.vtu`` file of VTK vertex cells with ``radius`` and ``diameter`` fields.

    In ParaView, Glyph → Sphere with Scale Array ``"diameter"`` and Scale Factor 1 draws each particle
    at its true size (see the module docstring).

    Args:
      path: output file name, ending in ``.vtu`` (str or path-like); overwritten if it exists.
      position: (N, 3) particle centres in m.
      radius: (N,) radii in m, > 0, or one scalar radius for all particles.
      point_data: optional dict name -> (N,) or (N, 3) array of per-particle values (SI units), e.g.
        ``{"velocity": v, "force": f}``. The names ``"radius"`` and ``"diameter"`` are reserved.

    Raises:
      ValueError: naming the argument or field, for a wrong suffix or shape, a NaN or infinite value, a
        non-positive radius, or a reserved field name.
    """
    path = _check_suffix(path)
    points = _positions("position", position)
    num_particles = points.shape[0]
    radii = _finite_float("radius", radius, f"shape ({num_particles},) or a scalar, in m")
    if radii.ndim == 0:
        radii = np.full(num_particles, float(radii))
    if radii.shape != (num_particles,):
        raise ValueError(
            f"radius has shape {radii.shape}; expected ({num_particles},) (one radius per row of position) "
            "or a scalar, in m."
        )
    if (radii <= 0.0).any():
        raise ValueError(f"radius has min {radii.min():g} m; every radius must be > 0 (m).")
    fields = {"radius": radii, "diameter": 2.0 * radii}
    fields.update(_fields("point_data", point_data, num_particles, "particle", PARTICLE_RESERVED_FIELDS))
    vertices = np.arange(num_particles, dtype=np.int64)[:, None]
    meshio.write(path, meshio.Mesh(points, [("vertex", vertices)], point_data=fields), file_format="vtu")


# ----------------------------------------------------------------------------------------------------------
# Shared helpers: folders, stems, atomic writes
# ----------------------------------------------------------------------------------------------------------

#: Dataset attribute listing the attributes stored as JSON strings.
JSON_ATTRS_KEY = "membrax_json_attrs"
#: Variable attribute naming the original dtype of a variable stored as another netCDF3 type.
DTYPE_ATTR = "membrax_dtype"
#: Dataset attribute in the ``.nc`` with the data-variable order (the writer reorders; read_results restores).
ORDER_ATTR = "membrax_variable_order"
#: ``format`` entry of a checkpoint's ``__meta__``, and the version written.
CHECKPOINT_FORMAT = "membrax-checkpoint"
CHECKPOINT_VERSION = 1
#: The two kinds of file in a :class:`VTKSeries`.
SERIES_KINDS = ("membrane", "particles")

_NAME_PATTERN = re.compile(r"^[A-Za-z_][A-Za-z0-9_.@+-]*$")
_INT32 = np.iinfo(np.int32)
_FLOAT64_EXACT_INT = 2**53


def _ensure_folder(folder, argument: str = "folder") -> Path:
    """``folder`` as a Path, created (with parents) if missing; ValueError if it is not a directory."""
    path = Path(os.fspath(folder))
    if path.exists() and not path.is_dir():
        raise ValueError(
            f"{argument} = '{path}' exists and is not a directory; pass a directory (it is created if "
            "missing) or move that file out of the way."
        )
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(
            f"{argument} = '{path}' cannot be created ({error}); pass a directory path whose parents are "
            "directories you can write to."
        ) from error
    return path


def _check_stem(stem) -> str:
    if not isinstance(stem, str) or not stem or stem.startswith(".") or "/" in stem or os.sep in stem:
        raise ValueError(
            f"stem = {stem!r} is not a plain file-name stem; give a non-empty name without '/' that does not "
            "start with '.', e.g. 'results'."
        )
    return stem


def _temporary_path(path: Path, suffix: str = ".tmp") -> Path:
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every platform can open a directory)."""
    with contextlib.suppress(OSError):
        descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def _atomic_write(path: Path, write: Callable[[Path], None], suffix: str = ".tmp") -> None:
    """Write ``path`` by ``write(temporary)`` in the same folder, fsync, then ``os.replace``.

    On any failure (including in ``os.replace``) the temporary file is removed and ``path`` is untouched.
    """
    temporary = _temporary_path(path, suffix)
    try:
        write(temporary)
        with open(temporary, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    _fsync_folder(path.parent)


def _atomic_write_file(path: Path, write_handle: Callable) -> None:
    """:func:`_atomic_write` through an open binary handle (created with the process umask)."""

    def write(temporary: Path) -> None:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(descriptor, "wb") as handle:
            write_handle(handle)

    _atomic_write(path, write)


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    _atomic_write_file(path, lambda handle: handle.write(data))


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
    if not isinstance(name, str) or not _NAME_PATTERN.match(name):
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
      records: dict, dataclass (e.g. :class:`membrax.measure.Measurements`, static fields skipped) or
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
    folder = _ensure_folder(folder)
    stem = _check_stem(stem)
    dataset = dataset.copy(deep=False)
    dataset.attrs = _storable_attrs(dataset.attrs)
    netcdf = _netcdf_bytes(dataset)
    text = _csv_text(dataset, time_dim).encode("utf-8")
    paths = {"nc": folder / f"{stem}.nc", "csv": folder / f"{stem}.csv"}
    _atomic_write_bytes(paths["nc"], netcdf)
    _atomic_write_bytes(paths["csv"], text)
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
    _ensure_folder(path.parent, "the folder of the NetCDF path")
    dataset = dataset.copy(deep=False)
    dataset.attrs = _storable_attrs(dataset.attrs)
    _atomic_write_bytes(path, _netcdf_bytes(dataset))
    return path


def _existing_file(path, what: str, missing_hint: str, inside: str) -> Path:
    """``path`` as a Path, or FileNotFoundError (missing) / ValueError (a directory) naming ``what``."""
    path = Path(os.fspath(path))
    if not path.exists():
        raise FileNotFoundError(f"{what} '{path}' does not exist; {missing_hint}.")
    if path.is_dir():
        raise ValueError(f"{what} path '{path}' is a directory; pass {inside} inside it.")
    return path


def read_results(path) -> xr.Dataset:
    """Read a ``.nc`` written by :func:`write_results`, loaded into memory, the file closed.

    Variables stored under another netCDF3 type get their original dtype back (:data:`DTYPE_ATTR`).

    Raises:
      FileNotFoundError: if ``path`` does not exist.
      ValueError: if ``path`` is not a NetCDF3 file.
    """
    path = _existing_file(
        path, "results file", "pass the {stem}.nc that write_results wrote", "the {stem}.nc file"
    )
    data = path.read_bytes()
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


# ----------------------------------------------------------------------------------------------------------
# VTK time series with ParaView collection files
# ----------------------------------------------------------------------------------------------------------


def read_pvd(path) -> list[tuple[float, str]]:
    """The ``(timestep, file)`` entries of a ParaView collection file, in file order.

    Raises:
      FileNotFoundError: if ``path`` does not exist.
      ValueError: if it is not a ``VTKFile`` of type ``Collection`` with ``DataSet`` entries.
    """
    path = Path(os.fspath(path))
    if not path.exists():
        raise FileNotFoundError(f"collection file '{path}' does not exist; check the folder and stem.")
    fix = "delete it (the .vtu files stay) or use another stem"
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise ValueError(f"'{path}' is not valid XML ({error}); {fix}.") from error
    collection = root.find("Collection")
    if root.tag != "VTKFile" or root.get("type") != "Collection" or collection is None:
        raise ValueError(f"'{path}' is not a ParaView collection (VTKFile type=\"Collection\"); {fix}.")
    entries = []
    for element in collection.findall("DataSet"):
        timestep, file = element.get("timestep"), element.get("file")
        try:
            time = float(timestep)
        except (TypeError, ValueError) as error:
            raise ValueError(f"'{path}' has a DataSet with timestep={timestep!r}; {fix}.") from error
        if not file:
            raise ValueError(f"'{path}' has a DataSet without a file; {fix}.")
        entries.append((time, file))
    return entries


def _pvd_text(entries: list[tuple[int, float, str]]) -> str:
    lines = [
        '<?xml version="1.0"?>',
        '<VTKFile type="Collection" version="0.1">',
        "  <Collection>",
    ]
    lines.extend(
        f'    <DataSet timestep="{time!r}" part="0" file={quoteattr(file)}/>' for _, time, file in entries
    )
    lines.extend(["  </Collection>", "</VTKFile>"])
    return "\n".join(lines) + "\n"


class VTKSeries:
    """A time series of membrane and particle ``.vtu`` files with ParaView ``.pvd`` collections.

    Files in ``folder``: ``{stem}_membrane_{step:09d}.vtu``, ``{stem}_particles_{step:09d}.vtu``,
    ``{stem}_membrane.pvd`` and ``{stem}_particles.pvd`` (module docstring). Existing ``.pvd`` entries
    are read back on construction, so a resumed run continues the series.

    Args:
      folder: output folder, created if missing.
      stem: file-name stem of the series.
      resume_step: if given, :meth:`truncate_after` ``(resume_step)`` is applied on construction: entries
        (and files) written after the checkpoint a run resumes from are dropped.

    Raises:
      ValueError: if ``folder`` is not a directory, ``stem`` is not a plain name, or an existing ``.pvd``
        is unreadable or lists a file that does not follow the naming above.
    """

    def __init__(self, folder, stem: str, resume_step: int | None = None):
        self.folder = _ensure_folder(folder)
        self.stem = _check_stem(stem)
        self._patterns = {
            kind: re.compile(rf"^{re.escape(self.stem)}_{kind}_(\d+)\.vtu$") for kind in SERIES_KINDS
        }
        self._entries: dict[str, dict[int, tuple[float, str]]] = {
            kind: self._read_existing(kind) for kind in SERIES_KINDS
        }
        if resume_step is not None:
            self.truncate_after(resume_step)

    def pvd_path(self, kind: str) -> Path:
        """Path of the collection file of ``kind`` ("membrane" or "particles")."""
        return self.folder / f"{self.stem}_{self._kind(kind)}.pvd"

    def vtu_path(self, kind: str, step: int) -> Path:
        """Path of the ``.vtu`` file of ``kind`` at ``step``."""
        return self.folder / f"{self.stem}_{self._kind(kind)}_{step:09d}.vtu"

    def entries(self, kind: str) -> list[tuple[int, float, Path]]:
        """The listed ``(step, time, path)`` of ``kind``, in step order."""
        listed = self._entries[self._kind(kind)]
        return [(step, listed[step][0], self.folder / listed[step][1]) for step in sorted(listed)]

    @staticmethod
    def _kind(kind: str) -> str:
        if kind not in SERIES_KINDS:
            raise ValueError(f"kind = {kind!r}; use one of {SERIES_KINDS}.")
        return kind

    def _step_of(self, kind: str, file: str) -> int | None:
        match = self._patterns[kind].match(file)
        return int(match.group(1)) if match else None

    def _read_existing(self, kind: str) -> dict[int, tuple[float, str]]:
        path = self.pvd_path(kind)
        if not path.exists():
            return {}
        entries = {}
        for time, file in read_pvd(path):
            step = self._step_of(kind, file)
            if step is None:
                raise ValueError(
                    f"'{path}' lists {file!r}, which is not a '{self.stem}_{kind}_<step>.vtu' file of this "
                    "series; delete the .pvd or use another stem."
                )
            entries[step] = (time, file)
        return entries

    def _write_pvd(self, kind: str) -> None:
        listed = self._entries[kind]
        entries = [(step, *listed[step]) for step in sorted(listed)]
        _atomic_write_bytes(self.pvd_path(kind), _pvd_text(entries).encode("utf-8"))

    def add(self, step, time, membrane=None, particles=None) -> dict[str, Path]:
        """Write the membrane and/or particles at ``step`` and rewrite the collection files.

        An entry for a step already listed is replaced (its file overwritten).

        Args:
          step: non-negative integer step number (in the file name).
          time: simulated time of the step, s (the ``timestep`` in the ``.pvd``).
          membrane: ``(node_position, triangles[, point_data[, cell_data]])`` for
            :func:`write_membrane_vtk`, or None.
          particles: ``(position, radius[, point_data])`` for :func:`write_particles_vtk`, or None.

        Returns:
          dict kind -> path of the ``.vtu`` written.

        Raises:
          ValueError: for a negative or non-integer step, a non-finite time, nothing to write, or any
            error of the writers (then nothing new is listed and no new file is left behind).
        """
        if isinstance(step, bool):
            raise ValueError(f"step = {step!r}; give a non-negative integer step number.")
        try:
            step = operator.index(step if not hasattr(step, "shape") else np.asarray(step).item())
        except TypeError as error:
            raise ValueError(f"step = {step!r}; give a non-negative integer step number.") from error
        if step < 0:
            raise ValueError(f"step = {step}; give a non-negative integer step number.")
        time = float(np.asarray(time))
        if not math.isfinite(time):
            raise ValueError(f"time = {time}; give the finite simulated time of the step, in s.")
        parts = {
            "membrane": (membrane, write_membrane_vtk, 2, 4),
            "particles": (particles, write_particles_vtk, 2, 3),
        }
        if membrane is None and particles is None:
            raise ValueError("nothing to write: pass membrane=(...) and/or particles=(...).")
        written: dict[str, Path] = {}
        try:
            for kind, (arguments, writer, least, most) in parts.items():
                if arguments is None:
                    continue
                if not isinstance(arguments, tuple | list) or not least <= len(arguments) <= most:
                    raise ValueError(
                        f"{kind} must be a tuple of {least} to {most} arguments of {writer.__name__}, got "
                        f"{type(arguments).__name__}"
                        + (f" of length {len(arguments)}" if isinstance(arguments, tuple | list) else "")
                        + "."
                    )
                path = self.vtu_path(kind, step)
                _atomic_write(path, lambda temporary, w=writer, a=arguments: w(temporary, *a), ".tmp.vtu")
                written[kind] = path
        except BaseException:
            for kind, path in written.items():
                if step not in self._entries[kind]:
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()
            raise
        for kind, path in written.items():
            self._entries[kind][step] = (time, path.name)
            self._write_pvd(kind)
        return written

    def truncate_after(self, step) -> list[Path]:
        """Drop the entries with a step > ``step`` and delete their files (also unlisted ones).

        Returns:
          the deleted ``.vtu`` paths, sorted.
        """
        step = operator.index(step)
        removed = []
        for kind in SERIES_KINDS:
            listed = self._entries[kind]
            later = [s for s in listed if s > step]
            for s in later:
                del listed[s]
            for name in os.listdir(self.folder):
                found = self._step_of(kind, name)
                if found is not None and found > step:
                    with contextlib.suppress(FileNotFoundError):
                        (self.folder / name).unlink()
                        removed.append(self.folder / name)
            if later or self.pvd_path(kind).exists():
                self._write_pvd(kind)
        return sorted(removed)


# ----------------------------------------------------------------------------------------------------------
# Checkpoints
# ----------------------------------------------------------------------------------------------------------


def _is_key_array(leaf) -> bool:
    dtype = getattr(leaf, "dtype", None)
    return dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)


def _leaf_signature(leaf) -> tuple[tuple[int, ...], str]:
    """(shape, dtype name) of a leaf, the same for a saved leaf and a template leaf."""
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(int(n) for n in leaf.shape), str(leaf.dtype)
    array = np.asarray(leaf)
    return tuple(array.shape), str(array.dtype)


def _leaf_to_numpy(label: str, leaf) -> tuple[np.ndarray, dict]:
    shape, dtype = _leaf_signature(leaf)
    info: dict = {"path": label, "shape": list(shape), "dtype": dtype}
    if _is_key_array(leaf):
        info["key_impl"] = str(jax.random.key_impl(leaf))
        return np.asarray(jax.random.key_data(leaf)), info
    array = np.asarray(leaf)
    if array.dtype.kind in "OV" and array.dtype.type.__module__ == "numpy":
        raise ValueError(
            f"state leaf {label} is a {type(leaf).__name__}, which is not an array or number; make it a "
            "static field of its dataclass or pass it in host."
        )
    if array.dtype.type.__module__ != "numpy":  # extension dtypes (bfloat16, ...): stored as raw bytes
        info["raw_bytes"] = True
        return np.frombuffer(np.ascontiguousarray(array).tobytes(), np.uint8), info
    return array, info


def _split_host(host) -> tuple[str, dict[str, np.ndarray], dict]:
    if host is None:
        return "null", {}, {"none": True, "order": [], "arrays": {}}
    if not isinstance(host, Mapping):
        raise ValueError(f"host must be a dict of host-side data (or None), got {type(host).__name__}.")
    plain, arrays, kinds = {}, {}, {}
    for key, value in host.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"host key {key!r} is not a non-empty string; use string keys.")
        if isinstance(value, np.ndarray | np.generic | jax.Array):
            array = np.asarray(value)
            if array.dtype.kind == "O":
                raise ValueError(f"host[{key!r}] is an object array; give numbers or JSON-able values.")
            arrays[f"host__{key}"] = array
            kinds[key] = "scalar" if isinstance(value, np.generic) else "array"
            continue
        try:
            json.dumps(value)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"host[{key!r}] of type {type(value).__name__} cannot be stored ({error}); give numpy "
                "arrays or JSON-able values (str, numbers, bools, None, lists and dicts of those)."
            ) from error
        plain[key] = value
    return json.dumps(plain), arrays, {"none": False, "order": list(host), "arrays": kinds}


def save_checkpoint(path, state, host=None) -> Path:
    """Save a JAX pytree ``state`` and a ``host`` dict to one ``.npz``, atomically (module docstring).

    Args:
      path: the checkpoint file (conventionally ``.npz``); its folder is created if missing; an existing
        file is replaced only once the new one is completely written.
      state: any pytree of arrays and numbers (jax-md dataclasses, NamedTuples, dicts, PRNG keys).
      host: optional dict of host-side data: numpy/JAX arrays (stored as ``host__{key}``) and JSON-able
        values (step counters, settings).

    Returns:
      ``path`` as a Path.

    Raises:
      ValueError: if ``path`` is a directory or its folder cannot be made, a leaf is not an array or
        number, or a host value is neither an array nor JSON-able.
    """
    path = Path(os.fspath(path))
    if path.is_dir():
        raise ValueError(f"checkpoint path '{path}' is a directory; give a file name such as 'state.npz'.")
    _ensure_folder(path.parent, "the folder of the checkpoint path")
    flat, treedef = jax.tree_util.tree_flatten_with_path(state)
    arrays: dict[str, np.ndarray] = {}
    leaves = []
    for index, (key_path, leaf) in enumerate(flat):
        array, info = _leaf_to_numpy(jax.tree_util.keystr(key_path), leaf)
        arrays[f"leaf_{index:05d}"] = array
        leaves.append(info)
    host_json, host_arrays, host_meta = _split_host(host)
    arrays.update(host_arrays)
    meta = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "num_leaves": len(leaves),
        "treedef": str(treedef),
        "leaves": leaves,
        "host": host_meta,
    }
    arrays["__meta__"] = np.array(json.dumps(meta))
    arrays["__host__"] = np.array(host_json)
    _atomic_write_file(path, lambda handle: np.savez(handle, **arrays))
    return path


def _read_checkpoint_entries(path: Path) -> dict[str, np.ndarray]:
    not_checkpoint = "pass a checkpoint written by membrax.io.save_checkpoint"
    try:
        loaded = np.load(path, allow_pickle=False)
    except Exception as error:
        raise ValueError(f"'{path}' is not a checkpoint .npz ({error}); {not_checkpoint}.") from error
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ValueError(f"'{path}' holds a single array, not a checkpoint .npz; {not_checkpoint}.")
    try:
        with loaded:
            if "__meta__" not in loaded.files:
                raise ValueError(
                    f"'{path}' is an .npz but not a membrax checkpoint (no __meta__ entry); {not_checkpoint}."
                )
            return {name: loaded[name] for name in loaded.files}
    except ValueError:
        raise
    except Exception as error:
        raise ValueError(
            f"checkpoint '{path}' is damaged ({type(error).__name__}: {error}); delete it and resume from an "
            "earlier checkpoint, or start a fresh run."
        ) from error


def _mismatch(path: Path, label: str, saved: str, template: str) -> ValueError:
    return ValueError(
        f"checkpoint '{path}' does not fit the template state at leaf {label}: {saved}, {template}. "
        "The checkpoint belongs to a different configuration (another particle count, mesh, batch size, "
        "neighbour capacity or precision); resume with the configuration that wrote it, or start a fresh run."
    )


def _restore_leaf(array: np.ndarray, info: dict, template):
    shape, dtype = tuple(info["shape"]), info["dtype"]
    if "key_impl" in info:
        return jax.random.wrap_key_data(jnp.asarray(array), impl=info["key_impl"])
    if info.get("raw_bytes"):
        array = np.frombuffer(array.tobytes(), jnp.dtype(dtype)).reshape(shape).copy()
    if isinstance(template, bool | int | float | complex):
        return type(template)(array.item())
    if isinstance(template, np.ndarray):
        return array
    if isinstance(template, np.generic):
        return array[()]
    return jnp.asarray(array, dtype=template.dtype)


def read_checkpoint_host(path) -> dict:
    """The JSON part of a checkpoint's host data, without its state (e.g. to size a template first)."""
    path = Path(os.fspath(path))
    entries = _read_checkpoint_entries(path)
    try:
        return json.loads(str(entries["__host__"][()]))
    except (KeyError, json.JSONDecodeError) as error:
        message = f"checkpoint '{path}' is damaged or not a membrax checkpoint ({error!r})."
        raise ValueError(message) from error


def load_checkpoint(path, like):
    """Load a checkpoint written by :func:`save_checkpoint` into the tree structure of ``like``.

    Args:
      path: the checkpoint file.
      like: a template state with the same structure, shapes and dtypes (e.g. the freshly initialised
        state of the same configuration, or ``jax.eval_shape`` of it).

    Returns:
      ``(state, host)``: the state, bit-exact (JAX leaves of ``like`` as JAX arrays of its dtypes, numpy
      leaves as numpy arrays, Python scalars as Python scalars), and the host dict (None if none was
      saved), its arrays as numpy arrays.

    Raises:
      FileNotFoundError: if ``path`` does not exist.
      ValueError: if ``path`` is not a checkpoint or is damaged, or its leaf count, a shape or a dtype
        differs from ``like`` (naming the first mismatching leaf by its key path).
    """
    path = _existing_file(
        path, "checkpoint", "check the path, or start a fresh run without resuming", "the checkpoint file"
    )
    entries = _read_checkpoint_entries(path)
    damaged = f"checkpoint '{path}' is damaged"
    fix = "delete it and resume from an earlier checkpoint, or start a fresh run"
    try:
        meta = json.loads(str(entries["__meta__"][()]))
        host_plain = json.loads(str(entries["__host__"][()]))
        leaves_info = meta["leaves"]
        host_meta = meta["host"]
        if meta.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"format {meta.get('format')!r}")
        saved = [entries[f"leaf_{index:05d}"] for index in range(meta["num_leaves"])]
        host_arrays = {key: entries[f"host__{key}"] for key in host_meta["arrays"]}
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as error:
        raise ValueError(f"{damaged} or not a membrax checkpoint ({error!r}); {fix}.") from error
    if meta.get("version", 0) > CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint '{path}' has format version {meta['version']}, newer than this membrax "
            f"({CHECKPOINT_VERSION}); load it with the membrax version that wrote it."
        )
    like_flat, treedef = jax.tree_util.tree_flatten_with_path(like)
    counts = f"({len(saved)} leaves)", f"({len(like_flat)} leaves)"
    for index in range(max(len(saved), len(like_flat))):
        if index >= len(like_flat):
            label = leaves_info[index]["path"]
            raise _mismatch(path, label, f"in the checkpoint {counts[0]}", f"not in the template {counts[1]}")
        label = jax.tree_util.keystr(like_flat[index][0])
        if index >= len(saved):
            raise _mismatch(path, label, f"not in the checkpoint {counts[0]}", f"in the template {counts[1]}")
        like_shape, like_dtype = _leaf_signature(like_flat[index][1])
        info = leaves_info[index]
        if tuple(info["shape"]) != like_shape or info["dtype"] != like_dtype:
            raise _mismatch(
                path,
                label,
                f"shape {tuple(info['shape'])} dtype {info['dtype']} in the checkpoint "
                f"(saved as {info['path']})",
                f"shape {like_shape} dtype {like_dtype} in the template",
            )
    leaves = [
        _restore_leaf(array, info, template)
        for array, info, (_, template) in zip(saved, leaves_info, like_flat, strict=True)
    ]
    state = jax.tree_util.tree_unflatten(treedef, leaves)
    if host_meta.get("none"):
        return state, None
    host = {}
    for key in host_meta["order"]:
        if key in host_arrays:
            host[key] = host_arrays[key][()] if host_meta["arrays"][key] == "scalar" else host_arrays[key]
        else:
            host[key] = host_plain[key]
    return state, host
