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
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import meshio
import numpy as np

__all__ = ["write_membrane_vtk", "write_particles_vtk"]

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
