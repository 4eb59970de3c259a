"""VTK files of the membrane and the particles (meshio), one snapshot or a time series, for ParaView.

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

VTK time series. :class:`VTKSeries` writes ``{stem}_membrane_{step:09d}.vtu`` and
``{stem}_particles_{step:09d}.vtu`` (through the writers above) and after every :meth:`VTKSeries.add`
rewrites the ParaView collections ``{stem}_membrane.pvd`` and ``{stem}_particles.pvd``, which list
``<DataSet timestep="{time}" part="0" file="{file}.vtu"/>`` in step order, file names relative to the
folder. Open the ``.pvd`` in ParaView to get a time series. On construction the existing ``.pvd``
entries are read back, so a resumed run appends to them; ``resume_step`` (or
:meth:`VTKSeries.truncate_after`) drops the entries with a later step and deletes their files.

Errors: :mod:`membrax.io`.
"""

from __future__ import annotations

import contextlib
import math
import operator
import os
import re
import xml.etree.ElementTree as ElementTree
from collections.abc import Mapping
from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

from membrax.io.files import (
    atomic_write,
    atomic_write_bytes,
    check_stem,
    ensure_folder,
)

__all__ = ["write_membrane_vtk", "write_particles_vtk", "VTKSeries", "read_pvd"]

#: The two kinds of file in a :class:`VTKSeries`.
SERIES_KINDS = ("membrane", "particles")
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
        self.folder = ensure_folder(folder)
        self.stem = check_stem(stem)
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
        atomic_write_bytes(self.pvd_path(kind), _pvd_text(entries).encode("utf-8"))

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
                atomic_write(path, lambda temporary, w=writer, a=arguments: w(temporary, *a), ".tmp.vtu")
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
