"""Matplotlib figures: horizontal sections through the specimen and its membrane (the paper's Fig. 4).

Contract. The geometry functions run on the host in numpy float64 (JAX arrays are converted with
``np.asarray``; nothing is traced) and work in SI units (m):

- :func:`membrane_section` cuts the triangulated membrane surface with the plane z = height and returns
  the intersection polylines of (x, y) points;
- :func:`particle_section` cuts the spheres with the same plane and returns the circles.

:func:`plot_section` draws both on a matplotlib ``Axes`` given by the caller (object API; it never calls
``pyplot.show``), converting m to mm for display only: the particle sections as filled grey circles (one
``PatchCollection``) and the membrane mid-surface section as a line, with equal aspect, axes labelled in
mm and the height in the title.

Section rule. A node counts as above the plane when z >= height and below when z < height, so a node
exactly on the plane is never ambiguous. An edge crosses the plane when one end is below and the other
above; it contributes one point, interpolated linearly from its lower to its upper end (the upper end
itself when it lies on the plane). A triangle with nodes on both sides has exactly two crossing edges and
contributes the segment between their points; segments are chained into polylines through the edges they
share. An edge shared by two triangles links two segments, so on a closed band the section is a set of
closed loops; a loop is returned with its first point repeated at the end (matplotlib's convention) and
ordered counter-clockwise seen from above (+z). A polyline reaching the mesh boundary is returned open.
Consecutive coincident points (from nodes lying on the plane) are merged into one.

Test figures (the paper's Figs 5–8). :func:`plot_friction_angles`, :func:`plot_additional_stresses`,
:func:`plot_axial_ratio_and_strain_ratio` and :func:`plot_radial_ratio_and_radial_strain` take the records
of a membrane triaxial test (the mapping described in :mod:`membrax.triaxial.analysis`) and optionally its
:func:`membrax.triaxial.analysis.derived_quantities`, and return a new matplotlib ``Figure`` made without
pyplot (nothing to close, no global state). The x axis is the axial strain in %, stresses are shown in kPa,
angles in degrees; each data series is one line, in the order :func:`plot_test_figure` lists (the four
are that one function, each with its figure's name, drawn from one table of series, colours and labels).
:func:`save_test_figures` writes all four as PNG files.

Fig. 9 of the paper. :func:`plot_fig9` draws the per-thickness numbers of
:func:`membrax.paper.fig9_data` (and optionally :func:`membrax.paper.paper_fig9_data`) against the cell
pressure on a log axis: the Molenkamp & Luger indentation ratio on the left axis, the negative of the
relative initial axial stress ratio on a twin right axis, ours with open markers and the paper's with
filled ones; :func:`save_fig9` writes it as ``fig9_indentation.png``.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import numpy as np
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.ticker import NullFormatter

from membrax.triaxial import analysis

__all__ = [
    "membrane_section",
    "particle_section",
    "plot_section",
    "plot_test_figure",
    "plot_friction_angles",
    "plot_additional_stresses",
    "plot_axial_ratio_and_strain_ratio",
    "plot_radial_ratio_and_radial_strain",
    "save_test_figures",
    "plot_element_figure",
    "save_element_figure",
    "plot_fig9",
    "save_fig9",
]

MM_PER_M = 1e3


def _shoelace(loop: np.ndarray) -> float:
    """Signed area of a closed (x, y) polygon, positive counter-clockwise (first point may be repeated)."""
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def membrane_section(node_position, triangles, height) -> list[np.ndarray]:
    """Intersection of the triangulated membrane with the horizontal plane z = ``height``.

    See the module docstring for the rule (nodes with z == height count as above; loops closed by repeating
    the first point and oriented counter-clockwise).

    Args:
      node_position: (N, 3) node positions in m.
      triangles: (T, 3) integer node indices.
      height: z of the cutting plane in m.

    Returns:
      A list of (M, 2) float64 arrays of (x, y) points in m, one per connected polyline, ordered along it;
      empty when the plane misses the surface. For a closed loop ``loop[0] == loop[-1]``.

    Raises:
      ValueError: if an edge crossing the plane is shared by more than two triangles (non-manifold mesh).
    """
    position = np.asarray(node_position, dtype=np.float64).reshape(-1, 3)
    cells = np.asarray(triangles).astype(np.int64).reshape(-1, 3)
    height = float(height)
    above = position[:, 2] >= height
    flags = above[cells]
    crossing = flags.any(axis=1) & ~flags.all(axis=1)
    cells = cells[crossing]
    if cells.shape[0] == 0:
        return []

    # The two crossing edges of each triangle: (a, b), (b, c), (c, a) with different flags.
    pairs = np.stack([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]], axis=1)  # (T, 3, 2)
    differs = above[pairs[..., 0]] != above[pairs[..., 1]]  # (T, 3), two True per row
    crossing_pairs = pairs[differs].reshape(-1, 2, 2)  # (T, 2 edges, 2 nodes)
    # Orient each edge from its lower to its upper node, so both triangles compute the same point.
    lower_first = ~above[crossing_pairs[..., 0]]
    low = np.where(lower_first, crossing_pairs[..., 0], crossing_pairs[..., 1])
    high = np.where(lower_first, crossing_pairs[..., 1], crossing_pairs[..., 0])
    keys, edge_of_segment = np.unique(
        np.stack([low, high], axis=-1).reshape(-1, 2), axis=0, return_inverse=True
    )
    edge_of_segment = edge_of_segment.reshape(-1, 2)
    z_low, z_high = position[keys[:, 0], 2], position[keys[:, 1], 2]
    fraction = (height - z_low) / (z_high - z_low)
    # (1 − f)·low + f·high returns the upper node exactly when it lies on the plane (f == 1.0 exactly).
    points = (1.0 - fraction)[:, None] * position[keys[:, 0], :2] + fraction[:, None] * position[
        keys[:, 1], :2
    ]

    # Segments incident to each crossing edge.
    incident: list[list[int]] = [[] for _ in range(keys.shape[0])]
    for segment, (e0, e1) in enumerate(edge_of_segment.tolist()):
        incident[e0].append(segment)
        incident[e1].append(segment)
    for edge, segments in enumerate(incident):
        if len(segments) > 2:
            raise ValueError(
                f"the edge between nodes {keys[edge].tolist()} is shared by {len(segments)} triangles; "
                "membrane_section needs a manifold surface (each edge in at most two triangles)."
            )

    used = np.zeros(edge_of_segment.shape[0], dtype=bool)

    def walk(start_edge: int) -> list[int]:
        """Edges visited following unused segments from ``start_edge`` until a dead end or back to start."""
        chain = [start_edge]
        edge = start_edge
        while True:
            following = [s for s in incident[edge] if not used[s]]
            if not following:
                return chain
            segment = following[0]
            used[segment] = True
            e0, e1 = edge_of_segment[segment]
            edge = int(e1 if e0 == edge else e0)
            chain.append(edge)

    chains = []
    # Open polylines first: they start at edges with a single triangle (mesh boundary).
    for edge, segments in enumerate(incident):
        if len(segments) == 1 and not used[segments[0]]:
            chains.append((walk(edge), False))
    for segment in range(edge_of_segment.shape[0]):
        if not used[segment]:
            chains.append((walk(int(edge_of_segment[segment, 0])), True))

    polylines = []
    for chain, closed in chains:
        line = points[chain]
        keep = np.ones(line.shape[0], dtype=bool)
        keep[1:] = np.any(line[1:] != line[:-1], axis=1)
        line = line[keep]
        if closed:
            if not np.all(line[0] == line[-1]):
                line = np.vstack([line, line[:1]])
            if _shoelace(line) < 0.0:
                line = line[::-1].copy()
        polylines.append(line)
    return polylines


def particle_section(position, radius, height) -> tuple[np.ndarray, np.ndarray]:
    """Circles cut from the spheres by the horizontal plane z = ``height``.

    A sphere of centre z and radius R is cut when |z − height| < R, in a circle of radius
    √(R² − (z − height)²) centred at its (x, y).

    Args:
      position: (N, 3) sphere centres in m.
      radius: (N,) radii in m, or one scalar for all.
      height: z of the cutting plane in m.

    Returns:
      ``(centres, radii)``: (K, 2) circle centres (x, y) and (K,) circle radii in m, float64, for the K cut
      spheres in their input order.
    """
    position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), position.shape[:1])
    distance = position[:, 2] - float(height)
    cut = np.abs(distance) < radius
    radii = np.sqrt(radius[cut] ** 2 - distance[cut] ** 2)
    return position[cut, :2].copy(), radii


def _offset_polyline(line: np.ndarray, offset: float) -> np.ndarray:
    """Polyline moved by ``offset`` along its unit left normals (inward for a counter-clockwise loop).

    The normal at a point is the normalised sum of the unit left normals of the segments meeting there.
    """
    closed = line.shape[0] > 2 and np.all(line[0] == line[-1])
    body = line[:-1] if closed else line
    if closed:
        forward = np.roll(body, -1, axis=0) - body
        backward = body - np.roll(body, 1, axis=0)
    else:
        forward = np.vstack([body[1:] - body[:-1], body[-1:] - body[-2:-1]])
        backward = np.vstack([body[1:2] - body[:1], body[1:] - body[:-1]])

    def unit_left(d):
        n = np.column_stack([-d[:, 1], d[:, 0]])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    normal = unit_left(forward) + unit_left(backward)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    moved = body + offset * normal
    return np.vstack([moved, moved[:1]]) if closed else moved


def plot_section(
    ax,
    position,
    radius,
    node_position,
    triangles,
    height,
    membrane_thickness=None,
    *,
    particle_color="0.65",
    membrane_color="tab:red",
    linewidth=1.5,
):
    """Draw a horizontal section z = ``height`` through the particles and the membrane (paper's Fig. 4).

    Draws the circles of :func:`particle_section` as filled grey patches in one ``PatchCollection`` (label
    ``"particles"``) and each polyline of :func:`membrane_section` as a line (label ``"membrane"``). With
    ``membrane_thickness`` t_m it also draws the membrane's inner and outer faces as thin lines (label
    ``"membrane faces"``), the mid-line moved by ±t_m/2 along the averaged in-plane segment normals.
    Coordinates are shown in mm; the axes get equal aspect, x/y labels in mm and a title with the height
    in mm. The data limits cover the particles and the membrane.

    Args:
      ax: a matplotlib ``Axes`` to draw on.
      position: (N, 3) sphere centres in m.
      radius: (N,) radii in m, or a scalar.
      node_position: (n_nodes, 3) membrane node positions in m (current, deformed configuration).
      triangles: (T, 3) integer node indices of the membrane.
      height: z of the section plane in m.
      membrane_thickness: t_m in m, optional; when given, the faces at ±t_m/2 are drawn.
      particle_color: face colour of the particle sections.
      membrane_color: colour of the membrane lines.
      linewidth: width of the membrane mid-line in points.

    Returns:
      ``ax``.
    """
    centres, radii = particle_section(position, radius, height)
    circles = [Circle(tuple(c), r) for c, r in zip(centres * MM_PER_M, radii * MM_PER_M, strict=True)]
    collection = PatchCollection(
        circles, facecolor=particle_color, edgecolor="0.3", linewidth=0.5, label="particles"
    )
    ax.add_collection(collection, autolim=True)
    lines = membrane_section(node_position, triangles, height)
    for k, line in enumerate(lines):
        mm = line * MM_PER_M
        ax.plot(
            mm[:, 0],
            mm[:, 1],
            color=membrane_color,
            linewidth=linewidth,
            label="membrane" if k == 0 else None,
        )
        if membrane_thickness is not None and line.shape[0] >= 2:
            half = 0.5 * float(membrane_thickness) * MM_PER_M
            for sign in (-1.0, 1.0):
                face = _offset_polyline(mm, sign * half)
                ax.plot(
                    face[:, 0],
                    face[:, 1],
                    color=membrane_color,
                    linewidth=0.5 * linewidth,
                    label="membrane faces" if (k == 0 and sign < 0) else None,
                )
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"Horizontal section at z = {float(height) * MM_PER_M:.1f} mm")
    return ax


# ---------------------------------------------------------------------------------------------------------
# Test figures: external against internal stresses (the paper's Figs 5–8)
# ---------------------------------------------------------------------------------------------------------

PERCENT = 1e2
KPA_PER_PA = 1e-3


def _test_figure(records, derived):
    """A new pyplot-free Figure with one Axes, the axial strain in %, and the derived quantities."""
    derived = analysis.derived_quantities(records) if derived is None else derived
    strain_pct = analysis.record(records, "axial_strain") * PERCENT
    figure = Figure(figsize=(6.4, 4.4), layout="constrained")
    ax = figure.add_subplot()
    ax.set_xlabel("Axial strain εa (%)")
    ax.grid(True, linewidth=0.5, alpha=0.5)
    return figure, ax, strain_pct, derived


class _Line(NamedTuple):
    """One line of Figs 5–8: ``scale`` × the derived quantity ``key`` (with ``from_records``, the record)."""

    key: str
    color: str
    label: str
    scale: float = 1.0
    from_records: bool = False
    optional: bool = False  # drawn only where the derived quantities have it (the Love–Weber series)
    linewidth: float | None = None  # None: matplotlib's default


class _Axis(NamedTuple):
    """A y axis of Figs 5–8: its label and its lines, in drawing order."""

    label: str
    lines: tuple[_Line, ...]


#: Figs 5–8 (plot_test_figure), by name: the title, then the left y axis and, where there is one, the
#: twin right one.
_TEST_FIGURE_TABLE: dict[str, tuple[str, tuple[_Axis, ...]]] = {
    "friction": (
        "Mobilised friction: external and internal stresses",
        (
            _Axis(
                "Mobilised friction angle φ' (°)",
                (
                    _Line("external_friction_angle_deg", "tab:blue", "External"),
                    _Line("internal_friction_angle_deg", "tab:red", "Internal"),
                    _Line("love_weber_friction_angle_deg", "0.4", "Love–Weber", optional=True, linewidth=0.7),
                ),
            ),
        ),
    ),
    "additional_stress": (
        "Additional membrane stress (internal − external)",
        (
            _Axis(
                "Additional membrane stress (kPa)",
                (
                    _Line("additional_radial_stress", "tab:green", "Additional radial stress", KPA_PER_PA),
                    _Line("additional_axial_stress", "tab:purple", "Additional axial stress", KPA_PER_PA),
                ),
            ),
        ),
    ),
    "axial_ratio": (
        "Axial stress ratio and change in strain ratio",
        (
            _Axis(
                "Axial stress ratio, internal/external",
                (_Line("axial_stress_ratio", "tab:blue", "Axial stress ratio"),),
            ),
            _Axis(
                "Change in strain ratio dεr/dεa",
                (_Line("strain_ratio_change", "tab:orange", "Change in strain ratio dεr/dεa"),),
            ),
        ),
    ),
    "radial_ratio": (
        "Radial stress ratio and radial strain",
        (
            _Axis(
                "Radial stress ratio, internal/external",
                (_Line("radial_stress_ratio", "tab:green", "Radial stress ratio"),),
            ),
            _Axis(
                "Radial strain εr (%, compression +)",
                (_Line("radial_strain", "tab:brown", "Radial strain εr", PERCENT, from_records=True),),
            ),
        ),
    ),
}


def plot_test_figure(records, derived=None, *, name) -> Figure:
    """One of the paper's Figs 5–8 for a test: its lines against the axial strain in %, one legend for all.

    The figures, by ``name`` (each also a function of its own, below), and their lines in order:

    - ``"friction"`` (Fig. 5, :func:`plot_friction_angles`): ``ax.lines[0]`` external φ', ``ax.lines[1]``
      internal φ' and, when the records have the Love–Weber series, ``ax.lines[2]`` Love–Weber φ' (thin);
      degrees, from sin φ' = (σ1 − σ3)/(σ1 + σ3) (:func:`membrax.triaxial.analysis.derived_quantities`).
    - ``"additional_stress"`` (Fig. 6, :func:`plot_additional_stresses`): the additional membrane stresses,
      internal − external: ``ax.lines[0]`` radial Δσ_r, ``ax.lines[1]`` axial Δσ_a, both in kPa.
    - ``"axial_ratio"`` (Fig. 7, :func:`plot_axial_ratio_and_strain_ratio`): ``figure.axes[0].lines[0]``
      the axial stress ratio internal/external (left axis), ``figure.axes[1].lines[0]`` the change in
      strain ratio dε_r/dε_a from :func:`membrax.triaxial.analysis.strain_ratio_change` (twin right axis),
      both dimensionless.
    - ``"radial_ratio"`` (Fig. 8, :func:`plot_radial_ratio_and_radial_strain`): ``figure.axes[0].lines[0]``
      the radial stress ratio internal/external (left axis), ``figure.axes[1].lines[0]`` the radial strain
      ε_r in % as recorded, compression positive, so bulging is negative (twin right axis).

    Args:
      records: the test records (see :mod:`membrax.triaxial.analysis`).
      derived: :func:`membrax.triaxial.analysis.derived_quantities` of the records, computed when not given.
      name: which figure, a key of the list above.

    Returns:
      The Figure.
    """
    title, axes_spec = _TEST_FIGURE_TABLE[name]
    figure, ax, strain_pct, derived = _test_figure(records, derived)
    axes = [ax] + [ax.twinx() for _ in axes_spec[1:]]
    for axis, spec in zip(axes, axes_spec, strict=True):
        for line in spec.lines:
            if line.optional and line.key not in derived:
                continue
            values = analysis.record(records, line.key) if line.from_records else derived[line.key]
            style = {} if line.linewidth is None else {"linewidth": line.linewidth}
            axis.plot(strain_pct, values * line.scale, color=line.color, label=line.label, **style)
        axis.set_ylabel(spec.label)
    ax.set_title(title)
    handles, labels = [], []
    for axis in axes:
        more_handles, more_labels = axis.get_legend_handles_labels()
        handles += more_handles
        labels += more_labels
    ax.legend(handles, labels, loc="best")
    return figure


# The figures one by one, called as (records, derived=None) (see plot_test_figure).
#: The paper's Fig. 5: mobilised friction angles from external and internal stresses.
plot_friction_angles = functools.partial(plot_test_figure, name="friction")
#: The paper's Fig. 6: additional membrane stresses, internal − external.
plot_additional_stresses = functools.partial(plot_test_figure, name="additional_stress")
#: The paper's Fig. 7: axial stress ratio internal/external and change in strain ratio dε_r/dε_a.
plot_axial_ratio_and_strain_ratio = functools.partial(plot_test_figure, name="axial_ratio")
#: The paper's Fig. 8: radial stress ratio internal/external and radial strain.
plot_radial_ratio_and_radial_strain = functools.partial(plot_test_figure, name="radial_ratio")


#: File names of :func:`save_test_figures` after the stem, with the function drawing each.
TEST_FIGURES = (
    ("5_friction.png", plot_friction_angles),
    ("6_additional_stress.png", plot_additional_stresses),
    ("7_axial_ratio.png", plot_axial_ratio_and_strain_ratio),
    ("8_radial_ratio.png", plot_radial_ratio_and_radial_strain),
)


def save_test_figures(records, folder, stem="fig", derived=None, dpi=120, title=None) -> list[Path]:
    """Write the paper's Figs 5–8 for one test as PNG files.

    Files ``{stem}5_friction.png``, ``{stem}6_additional_stress.png``, ``{stem}7_axial_ratio.png`` and
    ``{stem}8_radial_ratio.png`` in ``folder`` (created if missing), drawn by :func:`plot_friction_angles`,
    :func:`plot_additional_stresses`, :func:`plot_axial_ratio_and_strain_ratio` and
    :func:`plot_radial_ratio_and_radial_strain`. The figures are pyplot-free, so each is released once
    saved (cleared; nothing stays registered).

    Args:
      records: the test records (see :mod:`membrax.triaxial.analysis`).
      folder: output directory.
      stem: file-name prefix.
      derived: :func:`membrax.triaxial.analysis.derived_quantities` of the records, computed once when
        not given.
      dpi: resolution of the PNG files.
      title: a line set above every figure (e.g. the test's cell pressure, membrane and packing).

    Returns:
      The paths written, in figure order.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    derived = analysis.derived_quantities(records) if derived is None else derived
    paths = []
    for suffix, draw in TEST_FIGURES:
        figure = draw(records, derived)
        if title:
            figure.suptitle(title, fontsize=9)
        path = folder / f"{stem}{suffix}"
        figure.savefig(path, dpi=dpi)
        figure.clear()
        paths.append(path)
    return paths


def plot_element_figure(records) -> Figure:
    """A periodic element test's shearing: φ' (left) and ε_v (right, compression +) against ε_a in %.

    ``ax.lines[0]`` of the left Axes is φ' from the cell's Love–Weber stress (σ1 axial, σ3 the lateral
    mean), of the right one ε_v; the late φ' (:func:`membrax.triaxial.analysis.late_mean`) is a dashed line.
    """
    strain_pct = analysis.record(records, "axial_strain") * PERCENT
    angle = analysis.friction_angle_deg(
        analysis.record(records, "axial_stress"), analysis.record(records, "lateral_stress")
    )
    figure = Figure(figsize=(9.6, 4.0), layout="constrained")
    left, right = figure.subplots(1, 2)
    left.plot(strain_pct, angle, color="0.2", label="Love–Weber φ'")
    late = analysis.late_mean(strain_pct, angle)
    left.axhline(late, color="tab:red", linestyle="--", linewidth=0.8, label=f"late {late:.1f}°")
    left.set_ylabel("Mobilised friction angle φ' (°)")
    left.legend()
    right.plot(strain_pct, analysis.record(records, "volumetric_strain") * PERCENT, color="tab:blue")
    right.set_ylabel("Volumetric strain εv (%, compression +)")
    for ax in (left, right):
        ax.set_xlabel("Axial strain εa (%)")
        ax.grid(True, linewidth=0.5, alpha=0.5)
    return figure


def save_element_figure(records, folder, name="element.png", dpi=120, title=None) -> Path:
    """Write :func:`plot_element_figure` to ``folder/name`` (created if missing) and release it."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figure = plot_element_figure(records)
    if title:
        figure.suptitle(title, fontsize=9)
    path = folder / name
    figure.savefig(path, dpi=dpi)
    figure.clear()
    return path


# ---------------------------------------------------------------------------------------------------------
# The paper's Fig. 9: indentation ratio and initial axial stress ratio against cell pressure
# ---------------------------------------------------------------------------------------------------------

#: Colours of the membrane thicknesses of :func:`plot_fig9`, in increasing thickness (cycled).
FIG9_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")


def _fig9_line(axis, series, key, pressures, **style):
    """Draw ``series[key]`` against its cell pressures on ``axis``; the pressures join ``pressures``."""
    pressure = np.asarray(series["cell_pressure_kpa"], dtype=np.float64)
    pressures.update(pressure.tolist())
    axis.plot(pressure, np.asarray(series[key], dtype=np.float64), **style)


def plot_fig9(data, paper=None, labels=("membrax", "paper")) -> Figure:
    """Indentation ratio and −relative initial axial stress ratio against cell pressure (paper's Fig. 9).

    Lines, one per thickness of ``data`` in increasing thickness (k = 0, 1, …), one colour per thickness:
    ``figure.axes[0].lines[k]`` the indentation ratio α/D (left axis, solid, small dots);
    ``figure.axes[1].lines[k]`` our −(σ1,int/σ1,ext − 1) (twin right axis, dashed, open circles); with
    ``paper``, ``figure.axes[1].lines[n + k]`` (n thicknesses in ``data``) the paper's, for the thicknesses
    of ``paper`` in increasing order (dotted, filled circles). Each line has one point per cell pressure.
    The pressure axis is logarithmic, ticked at the pressures drawn.

    Args:
      data: ``{thickness_mm: {"cell_pressure_kpa", "indentation_ratio",
        "negative_relative_axial_stress_ratio", ...}}`` as :func:`membrax.paper.fig9_data` returns.
      paper: the same structure for the paper's values (:func:`membrax.paper.paper_fig9_data`), optional;
        only its stress ratio is drawn (its indentation ratio is the same theory).
      labels: the legend's names of ``data`` and ``paper`` (e.g. random specimens beside FCC ones).

    Returns:
      The Figure.
    """
    figure = Figure(figsize=(7.0, 5.2), layout="constrained")
    ax = figure.add_subplot()
    twin = ax.twinx()
    thicknesses = sorted(data)
    color = {t: FIG9_COLORS[k % len(FIG9_COLORS)] for k, t in enumerate(thicknesses)}
    pressures = set()
    for thickness in thicknesses:
        _fig9_line(
            ax,
            data[thickness],
            "indentation_ratio",
            pressures,
            color=color[thickness],
            marker=".",
            label=f"α/D, t_m = {thickness:.3g} mm",
        )
    for thickness in thicknesses:
        _fig9_line(
            twin,
            data[thickness],
            "negative_relative_axial_stress_ratio",
            pressures,
            color=color[thickness],
            linestyle="--",
            marker="o",
            markerfacecolor="none",
            label=f"−(σ1,int/σ1,ext − 1), t_m = {thickness:.3g} mm, {labels[0]}",
        )
    for k, thickness in enumerate(sorted(paper or {})):
        _fig9_line(
            twin,
            paper[thickness],
            "negative_relative_axial_stress_ratio",
            pressures,
            color=color.get(thickness, FIG9_COLORS[k % len(FIG9_COLORS)]),
            linestyle=":",
            marker="o",
            label=f"−(σ1,int/σ1,ext − 1), t_m = {thickness:.3g} mm, {labels[1]}",
        )
    ax.set_xscale("log")
    ticks = sorted(pressures)
    ax.set_xticks(ticks, labels=[f"{p:g}" for p in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("Cell pressure σc (kPa)")
    ax.set_ylabel("Indentation ratio α/D (Molenkamp & Luger, Eq. 2)")
    twin.set_ylabel("−relative initial axial stress ratio, 1 − σ1,int/σ1,ext")
    ax.grid(True, linewidth=0.5, alpha=0.5)
    ax.set_title("Indentation ratio and initial axial stress ratio (Fig. 9)")
    handles, labels = ax.get_legend_handles_labels()
    more_handles, more_labels = twin.get_legend_handles_labels()
    figure.legend(
        handles + more_handles, labels + more_labels, loc="outside lower center", ncols=2, fontsize=7
    )
    return figure


def save_fig9(data, folder, paper=None, dpi=120, labels=("membrax", "paper")) -> Path:
    """Write :func:`plot_fig9` of ``data`` (and ``paper``) as ``fig9_indentation.png`` in ``folder``.

    Args:
      data: :func:`membrax.paper.fig9_data` of our results.
      folder: output directory (created if missing).
      paper: :func:`membrax.paper.paper_fig9_data`, optional.
      dpi: resolution of the PNG file.
      labels: the legend's names of ``data`` and ``paper`` (:func:`plot_fig9`).

    Returns:
      The path written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figure = plot_fig9(data, paper, labels)
    path = folder / "fig9_indentation.png"
    figure.savefig(path, dpi=dpi)
    figure.clear()
    return path
