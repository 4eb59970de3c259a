"""membrax.spheres.fcc against hand counts, FCC lattice geometry and closed-form porosities.

Units: m, kg. D = 25 mm spheres as in the paper unless stated. Neighbour searches use scipy's KD-tree on
the built positions, independently of the integer-lattice arithmetic inside the builder.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_close
from scipy.spatial import cKDTree

from membrax import theory
from membrax.spheres import fcc
from membrax.spheres.particles import GRANITE_DENSITY, moment_of_inertia, particle_mass

D = 0.025
R = D / 2


@pytest.fixture(scope="module")
def paper():
    return fcc.fcc_specimen(particle_diameter=D, width_spheres=10, height_layers=25)


def _contact_pairs(specimen):
    """(P, 2) index pairs at distance D within 1e-9 D, and their exact centre differences."""
    position = np.asarray(specimen.position)
    diameter = specimen.particle_diameter
    pairs = cKDTree(position).query_pairs(diameter * (1 + 1e-6), output_type="ndarray")
    delta = position[pairs[:, 1]] - position[pairs[:, 0]]
    distance = np.linalg.norm(delta, axis=-1)
    touching = np.abs(distance - diameter) < 1e-9 * diameter
    return pairs[touching], delta[touching]


def _face_gaps(specimen):
    """(N, F) distance from each centre to each outline face minus R (0 = touching, < 0 = penetrating)."""
    normals, distances = (np.asarray(a) for a in specimen.outline_faces())
    xy = np.asarray(specimen.position)[:, :2]
    return distances[None, :] - xy @ normals.T - specimen.particle_radius


# ------------------------------------------------------------------------------------------------------
# Counts and sizes
# ------------------------------------------------------------------------------------------------------


def test_paper_size_counts_height_and_width(paper):
    # Hand count, octagon W = 10, c = 6D (√2·4.5 = 6.36 → 6). Even layer: half-integer (in D) x, y ≤ 4.5;
    # per quadrant (a, b) = (|x| − ½, |y| − ½) ∈ 0..4 with a + b ≤ 5: 25 − 6 = 19, ×4 = 76. Odd layer:
    # integer |x|, |y| ≤ 4 (81) minus |x| + |y| ≥ 7, i.e. (3,4), (4,3), (4,4) per quadrant: 81 − 12 = 69.
    assert paper.num_particles == 1816 == 13 * 76 + 12 * 69
    per_layer = np.bincount(np.asarray(paper.layer))
    assert per_layer.tolist() == [76, 69] * 12 + [76]
    assert paper.centre_diagonal_limit == pytest.approx(6 * D, rel=1e-15)
    # Height: 24 layer spacings of D/√2 plus one diameter, 449.26 mm (the paper's ~449 mm).
    assert paper.height == pytest.approx(24 * D / math.sqrt(2) + D, rel=1e-15)
    assert paper.height == pytest.approx(0.44926, abs=5e-6)
    # Bottom spheres touch z = 0 and the top ones touch z = height.
    z = np.asarray(paper.position)[:, 2]
    assert z.min() - R == pytest.approx(0.0, abs=1e-15)
    assert z.max() + R == pytest.approx(paper.height, rel=1e-14)
    # Width across flats: opposite flat faces (normals ±x) at ±(4.5D + R) = ±125 mm.
    normals, distances = (np.asarray(a) for a in paper.outline_faces())
    assert_close(normals[0], [1.0, 0.0], atol=1e-15)
    assert_close(normals[4], [-1.0, 0.0], atol=1e-15)
    assert distances[0] + distances[4] == pytest.approx(10 * D, rel=1e-14)
    assert paper.width_across_flats == pytest.approx(0.25, rel=1e-15)


def test_paper_size_porosity_by_hand(paper):
    # Outline: square of side 10D minus four corner triangles cut by x + y = (6 + 1/√2)D, legs
    # (10 − 6 − 1/√2)D = 3.2929D: area = (100 − 2·3.2929²)D² = 78.3137 D². Height 17.9706 D.
    area = (100 - 2 * (4 - 1 / math.sqrt(2)) ** 2) * D**2
    assert area / D**2 == pytest.approx(78.3137, abs=5e-5)
    assert paper.cross_section_area == pytest.approx(area, rel=1e-14)
    volume = area * (24 / math.sqrt(2) + 1) * D
    porosity = 1 - 1816 * math.pi / 6 * D**3 / volume
    assert porosity == pytest.approx(0.32436, abs=5e-6)
    assert paper.porosity == pytest.approx(porosity, rel=1e-13)
    assert paper.void_ratio == pytest.approx(porosity / (1 - porosity), rel=1e-13)
    assert paper.solid_volume == pytest.approx(1816 * math.pi * D**3 / 6, rel=1e-14)


def test_tiny_specimen_counted_by_hand():
    # W = 4, L = 4, octagon: h = 1.5D and √2·h = 2.12D, so c = 2D.
    # Even layer: x, y ∈ {±0.5, ±1.5}D, 16 sites, minus the 4 corners (1.5, 1.5) with |x| + |y| = 3 > 2: 12.
    # Odd layer: x, y ∈ {−1, 0, 1}D, 9 sites, all with |x| + |y| ≤ 2: 9. N = 12 + 9 + 12 + 9 = 42.
    tiny = fcc.fcc_specimen(particle_diameter=D, width_spheres=4, height_layers=4)
    assert tiny.centre_diagonal_limit == pytest.approx(2 * D, rel=1e-15)
    assert np.bincount(np.asarray(tiny.layer)).tolist() == [12, 9, 12, 9]
    assert tiny.num_particles == 42
    # Only the odd layers' centre (0, 0) and the even layers' four (±0.5, ±0.5) sites have all 12
    # lattice-neighbour sites inside: 42 − 2·1 − 2·4 = 32 on the lateral boundary.
    assert int(np.sum(np.asarray(tiny.is_lateral_boundary))) == 32


@pytest.mark.parametrize(("width", "layers"), [(2, 2), (3, 5), (4, 4), (7, 6), (10, 25)])
def test_square_count_closed_form(width, layers):
    # Square: W² sites in the even layers, (W − 1)² in the odd ones.
    specimen = fcc.fcc_specimen(D, width, layers, cross_section="square")
    expected = math.ceil(layers / 2) * width**2 + (layers // 2) * (width - 1) ** 2
    assert specimen.num_particles == expected
    assert specimen.cross_section_area == pytest.approx((width * D) ** 2, rel=1e-14)


def test_ordering_is_layer_then_y_then_x(paper):
    position = np.asarray(paper.position)
    layer = np.asarray(paper.layer)
    order = np.lexsort((position[:, 0], position[:, 1], layer))
    assert np.array_equal(order, np.arange(paper.num_particles))
    assert np.all(np.diff(position[:, 2]) >= 0)
    # z of layer k is R + k·D/√2.
    assert_close(position[:, 2], R + layer * D / math.sqrt(2), rtol=1e-14)
    assert np.array_equal(np.asarray(paper.is_bottom), layer == 0)
    assert np.array_equal(np.asarray(paper.is_top), layer == 24)


# ------------------------------------------------------------------------------------------------------
# FCC lattice geometry
# ------------------------------------------------------------------------------------------------------


def test_neighbours_at_exactly_one_diameter_and_no_overlap(paper):
    position = np.asarray(paper.position)
    nearest, _ = cKDTree(position).query(position, k=2)
    nearest = nearest[:, 1]
    assert np.max(np.abs(nearest - D)) < 1e-12 * D
    assert nearest.min() >= D - 1e-12
    pairs, _ = _contact_pairs(paper)
    counts = np.bincount(pairs.ravel(), minlength=paper.num_particles)
    outer = np.asarray(paper.is_lateral_boundary) | np.asarray(paper.is_bottom) | np.asarray(paper.is_top)
    interior = ~outer
    # Layers 1..23: 11 even ones with 76 − 24 = 52 interior spheres, 12 odd ones with 69 − 24 = 45 (see the
    # boundary hand count).
    assert interior.sum() == 11 * 52 + 12 * 45
    assert np.all(counts[interior] == 12)
    assert counts.max() == 12


def test_interlayer_contact_normals_are_45_degrees(paper):
    pairs, delta = _contact_pairs(paper)
    layer = np.asarray(paper.layer)
    layer_step = np.abs(layer[pairs[:, 1]] - layer[pairs[:, 0]])
    assert set(layer_step.tolist()) == {0, 1}  # contacts only within a layer or between adjacent ones
    between = layer_step == 1
    assert_close(np.abs(delta[between, 2]) / D, 1 / math.sqrt(2), rtol=1e-13)
    # Horizontal part (±D/2, ±D/2): the normals point along the square layer's diagonals.
    assert_close(np.abs(delta[between, :2]) / D, 0.5, rtol=1e-13)
    assert np.all(delta[~between, 2] == 0.0)
    # Within a layer the contacts are along x or y: one of |dx|, |dy| is D, the other zero.
    assert_close(np.sort(np.abs(delta[~between, :2]), axis=-1), np.tile([0.0, D], (int((~between).sum()), 1)),
                 atol=1e-15)  # fmt: skip


def test_octagon_is_symmetric_and_centred(paper):
    position = np.asarray(paper.position)
    layer = np.asarray(paper.layer)
    for k in (0, 1):  # all even (odd) layers hold the same sites
        xy = position[layer == k, :2]

        def as_set(points):
            return set(map(tuple, points.tolist()))

        assert as_set(xy * [-1, 1]) == as_set(xy)
        assert as_set(xy * [1, -1]) == as_set(xy)
        assert as_set(xy[:, ::-1]) == as_set(xy)
    assert abs(position[:, 0].mean()) < 1e-12
    assert abs(position[:, 1].mean()) < 1e-12


@pytest.mark.parametrize(("width", "layers"), [(4, 4), (8, 12), (16, 24), (32, 48)])
def test_square_porosity_closed_form(width, layers):
    # Hand derivation for even L: N = (L/2)(W² + (W − 1)²), V = (W·D)²·((L − 1)/√2 + 1)·D, so
    # (1 − n)/(1 − n_FCC) = (W² + (W − 1)²)/(2W²) · L/(L − 1 + √2) = (1 − 1/W + 1/(2W²)) · L/(L − 1 + √2).
    specimen = fcc.fcc_specimen(D, width, layers, cross_section="square")
    wall_factor = 1 - 1 / width + 1 / (2 * width**2)
    end_factor = layers / (layers - 1 + math.sqrt(2))
    expected = 1 - theory.FCC_SOLID_FRACTION * wall_factor * end_factor
    assert specimen.porosity == pytest.approx(expected, rel=1e-13)


def test_square_porosity_approaches_fcc_from_above():
    # The excess over bulk FCC is the wall and end voids, of first order 1/W + (√2 − 1)/L:
    # 1 − (1 − 1/W + 1/(2W²))·L/(L − 1 + √2) ≤ 1/W + (√2 − 1)/L. Measured: n = 0.4758, 0.3681, 0.3162,
    # 0.2884 for (W, L) = (4, 4), (8, 12), (16, 24), (32, 48): still 11 % above n_FCC = 0.2595 at W = 32
    # (22 % at W = 16). The wall voids dominate; within 2 % of n_FCC needs W, L of several hundred.
    sizes = [(4, 4), (8, 12), (16, 24), (32, 48)]
    porosities = [fcc.fcc_specimen(D, w, n, cross_section="square").porosity for w, n in sizes]
    assert np.all(np.diff(porosities) < 0)
    for (width, layers), porosity in zip(sizes, porosities, strict=True):
        excess = porosity - theory.FCC_POROSITY
        assert 0 < excess <= theory.FCC_SOLID_FRACTION * (1 / width + (math.sqrt(2) - 1) / layers)
    assert porosities[2] == pytest.approx(0.3162, abs=5e-5)
    assert porosities[3] == pytest.approx(0.2884, abs=5e-5)


# ------------------------------------------------------------------------------------------------------
# Lateral boundary and outline
# ------------------------------------------------------------------------------------------------------


def test_lateral_boundary_paper_count(paper):
    # Hand count per layer (units of D). Even layer: interior when all 4 in-layer neighbours (±1, 0), (0, ±1)
    # and the 4 odd-layer sites (±½, ±½) exist, i.e. per quadrant a, b ≤ 3 and a + b ≤ 4 (13 of 19):
    # 76 − 52 = 24. Odd layer: interior when |x|, |y| ≤ 3 and |x| + |y| ≤ 5: 49 − 4 = 45, so 69 − 45 = 24.
    # 25 layers × 24 = 600.
    boundary = np.asarray(paper.is_lateral_boundary)
    assert boundary.sum() == 600
    assert np.all(np.bincount(np.asarray(paper.layer), weights=boundary) == 24)


@pytest.mark.parametrize("cross_section", ["octagon", "square"])
@pytest.mark.parametrize("width", [3, 4, 5, 6, 9, 10])
def test_lateral_boundary_equals_missing_contacts(cross_section, width):
    # Independent of the builder's lattice bookkeeping: a sphere in a full lattice has 4 contacts in its
    # layer and 4 in each existing adjacent layer; it is on the lateral boundary iff it has fewer.
    layers = 4
    specimen = fcc.fcc_specimen(D, width, layers, cross_section=cross_section)
    pairs, _ = _contact_pairs(specimen)
    counts = np.bincount(pairs.ravel(), minlength=specimen.num_particles)
    layer = np.asarray(specimen.layer)
    expected_full = 4 + 4 * ((layer > 0).astype(int) + (layer < layers - 1).astype(int))
    assert np.array_equal(np.asarray(specimen.is_lateral_boundary), counts < expected_full)


@pytest.mark.parametrize("cross_section", ["octagon", "square"])
@pytest.mark.parametrize("width", [3, 4, 5, 6, 7, 10, 13])
def test_outline_faces_touch_and_are_not_penetrated(cross_section, width):
    specimen = fcc.fcc_specimen(D, width, 3, cross_section=cross_section)
    gaps = _face_gaps(specimen)
    assert gaps.min() >= -1e-12 * D  # nobody penetrates a wall
    touching = np.abs(gaps) < 1e-12 * D
    assert np.all(touching.any(axis=0))  # each face is touched by some sphere
    boundary = np.asarray(specimen.is_lateral_boundary)
    assert np.all(boundary[touching.any(axis=1)])  # every sphere touching a wall is a boundary sphere
    # Boundary spheres that touch no wall: the odd layers' outer rows sit D/2 behind the flat faces (the
    # flat faces are lattice planes of alternate layers only). So boundary ⇔ gap to the nearest face ≤ D/2,
    # and the nearest gap of a boundary sphere is 0 or D/2.
    nearest_gap = gaps.min(axis=1)
    assert np.array_equal(boundary, nearest_gap <= 0.5 * D + 1e-12 * D)
    on_boundary = nearest_gap[boundary]
    assert np.all((np.abs(on_boundary) < 1e-12 * D) | (np.abs(on_boundary - 0.5 * D) < 1e-12 * D))
    set_back = boundary & ~touching.any(axis=1)
    assert np.all(np.asarray(specimen.layer)[set_back] % 2 == 1)


def test_outline_faces_touch_paper_boundary(paper):
    gaps = _face_gaps(paper)
    touching = (np.abs(gaps) < 1e-12 * D).any(axis=1)
    boundary = np.asarray(paper.is_lateral_boundary)
    # Per layer (units of D; see the boundary hand count): the 24 even-layer boundary spheres touch a face
    # (16 on the flats |x| or |y| = 4.5, 8 more on the diagonals |x| + |y| = 6). Of the 24 odd-layer ones,
    # those with |x| + |y| = 6, i.e. (4, 2), (3, 3), (2, 4) per quadrant, touch a diagonal face (12); the
    # other 12, |x| or |y| = 4 with the other ≤ 1, lie D/2 behind a flat face.
    layer = np.asarray(paper.layer)
    assert (boundary & touching & (layer == 0)).sum() == 24
    assert (boundary & touching & (layer == 1)).sum() == 12
    assert (boundary & ~touching & (layer == 1)).sum() == 12


@pytest.mark.parametrize("cross_section", ["octagon", "square"])
def test_outline_vertices_polygon(paper, cross_section):
    specimen = paper if cross_section == "octagon" else fcc.fcc_specimen(cross_section="square")
    vertices = np.asarray(specimen.outline_vertices)
    normals, distances = (np.asarray(a) for a in specimen.outline_faces())
    assert len(vertices) == len(distances) == (8 if cross_section == "octagon" else 4)
    assert_close(np.linalg.norm(normals, axis=-1), 1.0, rtol=1e-15)
    # Face k runs from vertex k to vertex k + 1.
    following = np.roll(vertices, -1, axis=0)
    assert_close(np.sum(normals * vertices, axis=-1), distances, rtol=1e-14)
    assert_close(np.sum(normals * following, axis=-1), distances, rtol=1e-14)
    # Shoelace: positive (counter-clockwise) and equal to the closed-form area.
    signed_area = 0.5 * np.sum(vertices[:, 0] * following[:, 1] - following[:, 0] * vertices[:, 1])
    assert signed_area == pytest.approx(specimen.cross_section_area, rel=1e-13)
    assert specimen.volume == pytest.approx(signed_area * specimen.height, rel=1e-13)


def test_octagon_is_near_regular(paper):
    # Diagonal faces at c/√2 + R = (6/√2 + 0.5)D = 4.743D from the axis, flat faces at 5D: within 5.2 %.
    _, distances = paper.outline_faces()
    assert float(distances[1]) / D == pytest.approx(6 / math.sqrt(2) + 0.5, rel=1e-14)
    assert float(distances[1]) / float(distances[0]) == pytest.approx(0.9485, abs=5e-5)


# ------------------------------------------------------------------------------------------------------
# Inputs
# ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"width_spheres": 1}, "width_spheres"),
        ({"width_spheres": 2}, "width_spheres"),  # the octagon's corner cut would leave no centre
        ({"width_spheres": 2.5}, "width_spheres"),
        ({"height_layers": 1}, "height_layers"),
        ({"particle_diameter": -1.0}, "particle_diameter"),
        ({"particle_diameter": 0.0}, "particle_diameter"),
        ({"particle_diameter": float("nan")}, "particle_diameter"),
        ({"particle_diameter": float("inf")}, "particle_diameter"),
        ({"cross_section": "hexagon"}, "cross_section"),
    ],
)
def test_bad_inputs_raise_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        fcc.fcc_specimen(**kwargs)


def test_square_accepts_two_spheres_across():
    # W = 2: 4 spheres in the even layers, the single centre (0, 0) in the odd ones.
    assert fcc.fcc_specimen(width_spheres=2, height_layers=3, cross_section="square").num_particles == 9


# ------------------------------------------------------------------------------------------------------
# Mass properties and transforms
# ------------------------------------------------------------------------------------------------------


def test_particle_mass_and_time_scale_by_hand(paper):
    # 2650 kg/m³ · π/6 · 0.025³ m³ = 2650 · 8.18123e-6 = 0.0216803 kg (the brief's 0.021679 was a slip in
    # the last digit); √(m/k) for k = 1e7 N/m is 4.656e-5 s (the issue quotes 4.7e-5 s).
    mass = particle_mass(R, GRANITE_DENSITY)
    assert float(mass) == pytest.approx(2650 * math.pi / 6 * D**3, rel=1e-14)
    assert float(mass) == pytest.approx(0.0216803, abs=5e-8)
    assert math.sqrt(float(mass) / 1e7) == pytest.approx(4.656e-5, abs=5e-9)
    assert round(math.sqrt(float(mass) / 1e7), 6) == 4.7e-5
    inertia = moment_of_inertia(mass, R)
    # I = 2/5 m R² = 0.4 · 0.0216803 kg · 1.5625e-4 m² = 1.35502e-6 kg·m².
    assert float(inertia) == pytest.approx(1.35502e-6, abs=5e-12)
    assert_close(paper.mass(GRANITE_DENSITY), np.full(1816, float(mass)), rtol=1e-15)
    assert paper.mass(GRANITE_DENSITY).dtype == jnp.float64  # tests run in x64


def test_mass_functions_under_jit_vmap_and_grad():
    radii = jnp.array([0.01, 0.0125, 0.02])
    density = jnp.asarray(GRANITE_DENSITY)
    eager = particle_mass(radii, density)
    assert_close(jax.jit(particle_mass)(radii, density), eager, rtol=1e-15)
    assert_close(jax.vmap(particle_mass, in_axes=(0, None))(radii, density), eager, rtol=1e-15)
    inertia = moment_of_inertia(eager, radii)
    assert_close(jax.jit(moment_of_inertia)(eager, radii), inertia, rtol=1e-15)
    assert_close(jax.vmap(moment_of_inertia)(eager, radii), inertia, rtol=1e-15)
    # dm/dR = 4πR²ρ.
    gradient = jax.vmap(jax.grad(particle_mass), in_axes=(0, None))(radii, density)
    assert_close(gradient, 4 * math.pi * np.asarray(radii) ** 2 * GRANITE_DENSITY, rtol=1e-14)


def test_mass_functions_reject_bad_inputs():
    with pytest.raises(ValueError, match="density"):
        particle_mass(R, -1.0)
    with pytest.raises(ValueError, match="radius"):
        moment_of_inertia(1.0, float("nan"))


def test_specimen_is_a_pytree_with_static_parameters(paper):
    leaves, treedef = jax.tree_util.tree_flatten(paper)
    assert len(leaves) == 6  # position, radius, layer and the three flags; the parameters are static
    rebuilt = jax.tree_util.tree_unflatten(treedef, leaves)
    assert rebuilt.width_spheres == 10 and rebuilt.cross_section == "octagon"
    # A jitted function of the specimen sees the static fields as Python values.
    highest = jax.jit(lambda s: jnp.max(s.position[:, 2]) + s.particle_radius)(paper)
    assert float(highest) == pytest.approx(paper.height, rel=1e-14)
    assert paper.position.dtype == jnp.float64 and paper.layer.dtype == jnp.int64


def test_summary_reports_the_numbers(paper):
    text = paper.summary()
    for fragment in ("N = 1816", "D = 25 mm", "250 mm", "449.3 mm", "n = 0.3244", "e = 0.4801", ": 600"):
        assert fragment in text
