"""membrax.plots: horizontal sections against chord-sag bounds, exact polygon areas and hand counts.

Units: m (the plots show mm). Bounds used:

- cylinder mesh, radius R, n_θ nodes per ring. A section between two rings has its points on the
  diagonal edges, chords between nodes π/n_θ apart, so R·cos(π/(2n_θ)) <= r <= R. The band is the side of
  the convex antiprism spanned by the two rings, whose section contains (1 − t)·P_j + t·P_{j+1}
  (Minkowski) of two regular n_θ-gons, so by Brunn–Minkowski its area lies between the inscribed n_θ-gon
  area (n_θ/2)·R²·sin(2π/n_θ) and πR². At a ring height the section is that ring's n_θ-gon exactly.
- prism mesh around the offset octagon (area A_oct by the shoelace formula), n_θ nodes per ring s = P/n_θ
  apart along it. At a ring height the section is the ring polygon: each of the 8 corners (interior angle
  135°) is cut by a chord between nodes u and s − u from it, a triangle of area ½·u(s − u)·sin 45° <=
  s²·sin 45°/8, so A_oct − s²·sin 45° <= A <= A_oct. Between two rings the section has one point on each
  edge of the polygon Q through the nodes of both rings (s/2 apart): Q loses at most s²·sin 45°/32 per
  corner, and the section cuts Q's vertices by triangles ½·a·b·sin θ <= s²·sin θ/8 (a, b <= s/2, θ the
  turn of Q there), nonzero only at the two vertices by each corner, whose turns add to 45°:
  <= s²·2 sin 22.5°/8. Hence A_oct − s²·(sin 45°/4 + 2 sin 22.5°) <= A <= A_oct.
"""

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from membrax import plots
from membrax.membrane.mesh import cylinder_mesh, offset_polygon, prism_mesh
from membrax.spheres import fcc

R = 0.13
HEIGHT = 0.2
EDGE = 0.02
D = 0.025
THICKNESS = 0.002


def shoelace(loop):
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


@pytest.fixture(scope="module")
def cylinder():
    return cylinder_mesh(R, HEIGHT, EDGE)


@pytest.fixture(scope="module")
def specimen():
    # W = 4 octagon, hand count in units of D/2: even layers x, y ∈ {±1, ±3} with |x| + |y| <= c = 4
    # (c = 2·isqrt(⌊3²/2⌋) = 4): 16 − 4 corners (3, 3) = 12 spheres; odd layers x, y ∈ {0, ±2}: all 9.
    return fcc.fcc_specimen(particle_diameter=D, width_spheres=4, height_layers=3)


@pytest.fixture(scope="module")
def prism(specimen):
    """Membrane mid-surface t_m/2 outside the octagon outline, over the specimen height."""
    return prism_mesh(np.asarray(specimen.outline_vertices), 0.5 * THICKNESS, specimen.height, 0.01)


def _ring_count(mesh):
    z = np.asarray(mesh.reference_position)[:, 2]
    levels = np.unique(z)
    return levels, z.size // levels.size


def test_cylinder_section_between_rings(cylinder):
    levels, n_theta = _ring_count(cylinder)
    assert n_theta == round(2 * math.pi * R / EDGE) == 41
    height = levels[6] + 0.3 * (levels[7] - levels[6])
    loops = plots.membrane_section(cylinder.reference_position, cylinder.triangles, height)
    assert len(loops) == 1
    loop = loops[0]
    # one point per diagonal edge between the rings (2 n_θ), closed by repeating the first
    assert loop.shape == (2 * n_theta + 1, 2)
    np.testing.assert_array_equal(loop[0], loop[-1])
    r = np.hypot(loop[:, 0], loop[:, 1])
    assert np.all(r <= R * (1 + 1e-14))
    assert np.all(r >= R * math.cos(math.pi / (2 * n_theta)) * (1 - 1e-14))
    area = shoelace(loop)  # > 0: counter-clockwise
    inscribed = 0.5 * n_theta * R**2 * math.sin(2 * math.pi / n_theta)
    assert inscribed <= area <= math.pi * R**2
    # consecutive points go around once: the angle increases monotonically by 2π in total
    turn = np.diff(np.unwrap(np.arctan2(loop[:, 1], loop[:, 0])))
    assert np.all(turn > 0)
    assert math.isclose(turn.sum(), 2 * math.pi, rel_tol=1e-12)


def test_cylinder_section_at_a_ring_is_the_ring(cylinder):
    """Nodes on the plane count as above: the section is the ring's regular n_θ-gon, nodes not repeated."""
    levels, n_theta = _ring_count(cylinder)
    for height in (levels[6], levels[-1]):
        (loop,) = plots.membrane_section(cylinder.reference_position, cylinder.triangles, height)
        assert loop.shape == (n_theta + 1, 2)
        ring = np.asarray(cylinder.reference_position)
        ring = ring[ring[:, 2] == height, :2]
        # every point is a ring node, exactly
        assert {tuple(p) for p in loop} == {tuple(p) for p in ring}
        area = shoelace(loop)
        assert math.isclose(area, 0.5 * n_theta * R**2 * math.sin(2 * math.pi / n_theta), rel_tol=1e-12)
    # the bottom ring counts as above and nothing lies below it; above the top, nothing either
    assert plots.membrane_section(cylinder.reference_position, cylinder.triangles, levels[0]) == []
    assert plots.membrane_section(cylinder.reference_position, cylinder.triangles, levels[-1] + 1e-6) == []


def test_prism_section_area(specimen, prism):
    outline = np.asarray(specimen.outline_vertices)
    mesh = prism
    octagon = offset_polygon(outline, 0.5 * THICKNESS)
    octagon_area = shoelace(octagon)
    # offset octagon by hand: flat faces at h + R + t/2 = 1.5D + R + t/2 = 51 mm from the axis, diagonal
    # faces at c/√2 + R + t/2; area = (2X)² − 2(2X − s)², X = 51 mm, s = √2·(c/√2 + R + t/2)
    flat = 0.051
    diagonal_sum = math.sqrt(2) * (2 * D / math.sqrt(2) + D / 2 + THICKNESS / 2)
    assert math.isclose(octagon_area, (2 * flat) ** 2 - 2 * (2 * flat - diagonal_sum) ** 2, rel_tol=1e-12)
    levels, n_theta = _ring_count(mesh)
    perimeter = np.sum(np.linalg.norm(np.roll(octagon, -1, axis=0) - octagon, axis=1))
    spacing = perimeter / n_theta
    ring_bound = spacing**2 * math.sin(math.pi / 4)
    between_bound = spacing**2 * (math.sin(math.pi / 4) / 4 + 2 * math.sin(math.pi / 8))
    # heights between rings (none of these is a ring level), then ring levels
    between = np.linspace(0.001, specimen.height - 0.001, 7)
    assert np.min(np.abs(between[:, None] - levels[None, :])) > 1e-4
    for heights, bound in ((between.tolist(), between_bound), (levels[1:].tolist(), ring_bound)):
        for height in heights:
            (loop,) = plots.membrane_section(mesh.reference_position, mesh.triangles, height)
            area = shoelace(loop)
            assert octagon_area - bound <= area <= octagon_area * (1 + 1e-14)


def test_two_loops_and_open_polyline(cylinder):
    # the cylinder and a copy scaled by 2 in x, y: two loops, of radius R and 2R
    levels, n_theta = _ring_count(cylinder)
    position = np.asarray(cylinder.reference_position)
    offset = position.shape[0]
    both = np.concatenate([position, position * np.array([2.0, 2.0, 1.0])])
    triangles = np.concatenate([np.asarray(cylinder.triangles), np.asarray(cylinder.triangles) + offset])
    loops = plots.membrane_section(both, triangles, 0.5 * (levels[2] + levels[3]))
    assert len(loops) == 2
    areas = sorted(shoelace(loop) for loop in loops)
    for area, radius in zip(areas, (R, 2 * R), strict=True):
        assert 0.5 * n_theta * radius**2 * math.sin(2 * math.pi / n_theta) <= area <= math.pi * radius**2
    assert math.isclose(areas[1], 4 * areas[0], rel_tol=1e-12)  # scaling by 2 multiplies areas by 4

    # a vertical sheet at y = 0 by hand: nodes x = 0..W in 5 steps, z = 0..L in 3, two triangles per cell;
    # cut at z: an open straight line from x = 0 to x = W (the boundary edges are vertical), y = 0
    width, length = 0.1, 0.06
    x, z = np.meshgrid(np.linspace(0, width, 6), np.linspace(0, length, 4))
    nodes = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    cell = (np.arange(3)[:, None] * 6 + np.arange(5)[None, :]).ravel()
    sheet = np.concatenate(
        [np.column_stack([cell, cell + 1, cell + 7]), np.column_stack([cell, cell + 7, cell + 6])]
    )
    (line,) = plots.membrane_section(nodes, sheet, 0.023)
    assert np.all(line[:, 1] == 0.0)
    assert np.all(np.diff(line[:, 0]) > 0) or np.all(np.diff(line[:, 0]) < 0)
    # one point per vertical (6) and diagonal (5) edge of the crossed row of cells; ends at x = 0 and W
    assert line.shape == (11, 2)
    np.testing.assert_allclose(np.sort(line[[0, -1], 0]), [0.0, width], rtol=0, atol=1e-15)


def test_non_manifold_edge_raises():
    position = np.array([[0, 0, 0], [1, 0, 1], [0, 1, 0.5], [1, 1, 0.5], [-1, 0, 0.5]], dtype=float)
    triangles = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    with pytest.raises(ValueError, match="shared by 3 triangles"):
        plots.membrane_section(position, triangles, 0.25)


def test_particle_section_single_sphere():
    radius = 2.0**-6  # 15.6 mm; binary fractions make z0 − (z0 − R) = R exact
    z0 = 0.25
    position = np.array([[0.01, -0.02, z0]] * 5)
    dz = np.array([0.006, -0.006, 0.0, radius, 1.01 * radius])
    position[:, 2] = z0 - dz  # plane at z0 is dz above each centre
    centres, radii = plots.particle_section(position, radius, z0)
    assert radii.shape == (3,)  # |dz| = R (tangent) and beyond are not cut
    expected = math.sqrt(radius**2 - 0.006**2)  # 14.43 mm
    np.testing.assert_allclose(radii, [expected, expected, radius], rtol=1e-15)
    np.testing.assert_array_equal(centres, [[0.01, -0.02]] * 3)


def test_particle_section_fcc_counts(specimen):
    radius = specimen.particle_radius
    # at the centre plane of layer 0 only layer 0 is cut (layer 1 is D/√2 > R away): 12 full circles
    centres, radii = plots.particle_section(specimen.position, specimen.radius, radius)
    assert radii.shape == (12,)
    np.testing.assert_allclose(radii, radius, rtol=1e-15)
    # half-way between layers 0 and 1 (dz = D/(2√2) < R for both): 12 + 9 circles of radius
    # √(R² − D²/8) = D/√8
    height = radius + D / (2 * math.sqrt(2))
    centres, radii = plots.particle_section(specimen.position, specimen.radius, height)
    assert centres.shape == (21, 2)
    np.testing.assert_allclose(radii, D / math.sqrt(8), rtol=1e-12)


def test_plot_section(specimen, prism):
    mesh = prism
    height = specimen.particle_radius + D / (2 * math.sqrt(2))
    fig, ax = plt.subplots()
    try:
        returned = plots.plot_section(
            ax, specimen.position, specimen.radius, mesh.reference_position, mesh.triangles, height, THICKNESS
        )
        assert returned is ax
        (collection,) = ax.collections
        paths = collection.get_paths()
        assert len(paths) == 21  # hand count, see test_particle_section_fcc_counts
        # each patch is a circle of radius D/√8 in mm around a lattice site (multiples of D/2 in x, y);
        # its Bézier path reaches exactly ±r along x and y (the control points there are tangent)
        for path in paths:
            low, high = path.vertices.min(axis=0), path.vertices.max(axis=0)
            np.testing.assert_allclose(0.5 * (high - low), D / math.sqrt(8) * 1e3, rtol=1e-12)
            site = 0.5 * (low + high) / (D / 2 * 1e3)
            np.testing.assert_allclose(site, np.round(site), rtol=0, atol=1e-9)

        (loop,) = plots.membrane_section(mesh.reference_position, mesh.triangles, height)
        (line,) = [line for line in ax.lines if line.get_label() == "membrane"]
        np.testing.assert_allclose(line.get_xydata(), loop * 1e3, rtol=0, atol=1e-12)
        faces = [line for line in ax.lines if line is not ax.lines[0]]
        assert len(faces) == 2
        # faces are ±t/2 from the mid-line: every face point is t/2 = 1 mm from its mid-line point
        for face in faces:
            np.testing.assert_allclose(
                np.linalg.norm(face.get_xydata() - loop * 1e3, axis=1), THICKNESS / 2 * 1e3, rtol=1e-12
            )
        # one face encloses t/2 more, the other t/2 less, up to corners: |ΔA| ≈ P·t/2
        face_areas = sorted(shoelace(face.get_xydata()) for face in faces)
        perimeter = np.sum(np.linalg.norm(np.diff(loop * 1e3, axis=0), axis=1))
        mid_area = shoelace(loop * 1e3)
        for face_area, sign in zip(face_areas, (-1, 1), strict=True):
            assert math.isclose(face_area - mid_area, sign * perimeter * THICKNESS / 2 * 1e3, rel_tol=0.02)

        assert ax.get_aspect() == 1.0
        assert ax.get_xlabel() == "x (mm)" and ax.get_ylabel() == "y (mm)"
        assert f"{height * 1e3:.1f} mm" in ax.get_title()
        # the data limits cover the membrane (51 mm + 1 mm from the axis at the flats, in mm)
        x0, x1 = ax.get_xlim()
        assert x0 <= loop[:, 0].min() * 1e3 and x1 >= loop[:, 0].max() * 1e3
    finally:
        plt.close(fig)


def test_plot_section_cylinder_faces(cylinder):
    """At a ring height the mid-line is a regular n_θ-gon, so the faces are n_θ-gons of radius R ± t/2."""
    levels, _ = _ring_count(cylinder)
    fig, ax = plt.subplots()
    try:
        plots.plot_section(
            ax,
            np.zeros((0, 3)),
            np.zeros(0),
            cylinder.reference_position,
            cylinder.triangles,
            levels[4],
            THICKNESS,
        )
        radii = sorted(np.hypot(*line.get_xydata().T).mean() for line in ax.lines)
        np.testing.assert_allclose(
            radii, np.array([R - THICKNESS / 2, R, R + THICKNESS / 2]) * 1e3, rtol=1e-12
        )
        assert len(ax.collections[0].get_paths()) == 0
    finally:
        plt.close(fig)


def test_fig9_of_random_specimens_is_the_mean_over_seeds_beside_fcc():
    from membrax.plots import plot_fig9
    from membrax.reproduce import seed_mean_fig9

    def seed(ratios, pressures=(10.0, 40.0)):
        return {
            5.0: {
                "cell_pressure_kpa": np.array(pressures),
                "indentation_ratio": np.array([0.3, 0.2]),
                "negative_relative_axial_stress_ratio": np.array(ratios),
            }
        }

    # (−0.2 − 0.4)/2 = −0.3 and (−0.1 − 0.3)/2 = −0.2, by hand; a seed with other pressures is left out
    mean = seed_mean_fig9([seed([-0.2, -0.1]), seed([-0.4, -0.3]), seed([9.0, 9.0], (10.0, 100.0))])
    np.testing.assert_allclose(mean[5.0]["negative_relative_axial_stress_ratio"], [-0.3, -0.2], rtol=1e-12)
    np.testing.assert_array_equal(mean[5.0]["indentation_ratio"], [0.3, 0.2])
    figure = plot_fig9(mean, seed([-0.1, 0.0]), labels=("random", "FCC"))
    labels = [line.get_label() for line in figure.axes[1].lines]
    assert labels[0].endswith("random") and labels[1].endswith("FCC")
    np.testing.assert_allclose(figure.axes[1].lines[0].get_ydata(), [-0.3, -0.2], rtol=1e-12)


def test_a_run_s_figures_say_which_test_they_are():
    from membrax.config import DEMO_CONFIG, DEMO_RANDOM_CONFIG, TriaxialConfig
    from membrax.run import figure_title

    assert (
        figure_title(TriaxialConfig(**DEMO_CONFIG), {"num_particles": 390})
        == "demo: σc 10 kPa, membrane 5 mm of 1400 kPa, FCC 6 × 10 (390 spheres)"
    )
    assert (
        figure_title(TriaxialConfig(**DEMO_RANDOM_CONFIG), {"num_particles": 333})
        == "demo_random: σc 10 kPa, membrane 5 mm of 1400 kPa, random 150 × 250 mm, seed 0 (333 spheres)"
    )
