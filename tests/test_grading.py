"""Gradings sampled by mass and the loose random cloud (membrax.spheres.grading)."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from membrax.spheres.grading import (
    OUTLINE_SIDES,
    Grading,
    RandomSpecimen,
    loose_cloud,
    mass_fractions,
    sample_diameters,
)

#: A ballast-like grading, scaled: sieves in m, fraction of the mass passing.
BALLAST = Grading(sizes=(0.0224, 0.0315, 0.040, 0.050, 0.0625), passing=(0.0, 0.1, 0.4, 0.8, 1.0))
#: The solid volume of a 250 × 500 mm specimen at a solid fraction of 0.6, m³.
PAPER_SOLID = 0.6 * math.pi * 0.125**2 * 0.5


def test_the_sampled_mass_fractions_follow_the_grading_to_one_sphere_per_bin():
    """Each bin's sampled mass fraction is the curve's to within the rounding of its sphere count: one
    sphere of the bin's largest size over the sampled volume."""
    diameters = sample_diameters(BALLAST, PAPER_SOLID, seed=3)
    sampled = mass_fractions(diameters, BALLAST.sizes)
    wanted = np.diff(BALLAST.passing)
    volume = np.sum(diameters**3)
    one_sphere = np.asarray(BALLAST.sizes[1:]) ** 3 / volume
    assert np.all(np.abs(sampled - wanted) <= one_sphere), (sampled, wanted, one_sphere)
    assert sampled.sum() == pytest.approx(1.0, abs=1e-12)  # every sphere within the sieves
    assert math.pi / 6 * volume == pytest.approx(PAPER_SOLID, rel=0.02)


def test_within_a_bin_the_mass_is_spread_evenly_over_the_sizes():
    """The curve is linear between sieves, so half the bin's mass lies below its middle size (number
    density ∝ d⁻³): 1 − the fraction below the mid-size is ½ to sampling noise."""
    one_bin = Grading(sizes=(0.02, 0.04), passing=(0.0, 1.0))
    diameters = sample_diameters(one_bin, 4000 * math.pi / 6 * 0.03**3, seed=0)
    below = mass_fractions(diameters, (0.02, 0.03, 0.04))
    assert below[0] == pytest.approx(0.5, abs=0.01)
    # The number density ∝ d⁻³: the fraction of spheres below the mid-size is (a⁻² − m⁻²)/(a⁻² − b⁻²).
    expected = (0.02**-2 - 0.03**-2) / (0.02**-2 - 0.04**-2)
    assert np.mean(diameters <= 0.03) == pytest.approx(expected, abs=0.01)


def test_sampling_is_deterministic_for_a_seed_and_differs_between_seeds():
    first = sample_diameters(BALLAST, PAPER_SOLID, seed=1)
    np.testing.assert_array_equal(first, sample_diameters(BALLAST, PAPER_SOLID, seed=1))
    other = sample_diameters(BALLAST, PAPER_SOLID, seed=2)
    assert first.shape == other.shape  # the counts come from the curve, not the seed
    assert not np.array_equal(first, other)


def test_equal_spheres_are_one_size_and_fill_the_volume():
    diameters = sample_diameters(Grading.equal(0.025), PAPER_SOLID)
    assert np.all(diameters == 0.025)
    assert diameters.size == round(PAPER_SOLID / (math.pi / 6 * 0.025**3))


@pytest.mark.parametrize(
    ("sizes", "passing", "words"),
    [
        ((0.02, 0.03, 0.05), (0.0, 0.6, 0.9), "rise to 100 %"),
        ((0.02, 0.05, 0.03), (0.0, 0.5, 1.0), "point 3 has size 0.03 m after 0.05 m"),
        ((0.02, 0.03, 0.05), (0.0, 0.6, 0.4), "never falls"),
        ((0.02, 0.03, 0.05), (0.1, 0.6, 1.0), "start the curve at 0 %"),
        ((0.02, 0.03, 0.05), (0.0, float("nan"), 1.0), "point 2 has passing nan"),
        ((0.0, 0.03), (0.0, 1.0), "sizes must be positive"),
        ((0.03,), (1.0,), "at least two points"),
    ],
)
def test_a_bad_grading_is_refused_with_the_point_and_the_fix(sizes, passing, words):
    with pytest.raises(ValueError, match="grading") as error:
        Grading(sizes=sizes, passing=passing)
    assert words in str(error.value)


def test_the_loose_cloud_has_no_overlap_lies_in_the_mould_and_has_the_asked_solid_fraction():
    diameters = sample_diameters(BALLAST, 0.2 * PAPER_SOLID, seed=0)
    radius = 0.5 * diameters
    mould_radius = 0.15
    centres, height = loose_cloud(diameters, mould_radius, solid_fraction=0.25, seed=4)
    pairs = cKDTree(centres).query_pairs(diameters.max(), output_type="ndarray")
    gaps = np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1) - radius[pairs].sum(axis=1)
    assert gaps.min() >= 0.0
    assert np.all(np.hypot(centres[:, 0], centres[:, 1]) + radius <= mould_radius * (1 + 1e-12))
    assert np.all(centres[:, 2] - radius >= 0.0) and np.all(centres[:, 2] + radius <= height * (1 + 1e-12))
    solid = np.sum(math.pi / 6 * diameters**3)
    assert solid / (math.pi * mould_radius**2 * height) == pytest.approx(0.25, rel=1e-12)
    again, _ = loose_cloud(diameters, mould_radius, solid_fraction=0.25, seed=4)
    np.testing.assert_array_equal(centres, again)


def test_random_specimen_geometry_is_the_circle_s():
    """Area π D²/4; the outline polygon's vertices lie on its faces, the faces touch the circle; the
    characteristic diameter is the mean, the cutoff the largest; every sphere may touch the membrane."""
    radius = np.array([0.01, 0.0125, 0.015])
    specimen = RandomSpecimen(
        position=np.zeros((3, 3)), radius=radius, diameter=0.2, height=0.3, solid_fraction=0.6, seed=1
    )
    assert specimen.cross_section_area == pytest.approx(math.pi * 0.01)
    assert specimen.particle_diameter == pytest.approx(0.025)
    assert specimen.largest_diameter == pytest.approx(0.03)
    assert bool(np.all(np.asarray(specimen.is_lateral_boundary)))
    normals, distances = (np.asarray(a) for a in specimen.outline_faces())
    vertices = np.asarray(specimen.outline_vertices)
    assert normals.shape == (OUTLINE_SIDES, 2)
    np.testing.assert_allclose(distances, 0.1)
    # Vertex k is where faces k − 1 and k meet.
    np.testing.assert_allclose(np.sum(vertices * normals, axis=1), distances, rtol=1e-12)
    np.testing.assert_allclose(np.sum(vertices * np.roll(normals, 1, axis=0), axis=1), distances, rtol=1e-12)
    expected_porosity = 1.0 - np.sum(4.0 / 3.0 * math.pi * radius**3) / (math.pi * 0.01 * 0.3)
    assert specimen.porosity == pytest.approx(expected_porosity)


def test_d50_is_read_off_the_grading_curve_linearly_between_sieves():
    # 50 % lies between 40 mm (40 %) and 50 mm (80 %): 40 + (10/40) × 10 = 42.5 mm, by hand
    assert BALLAST.size_passing(0.5) == pytest.approx(0.0425, rel=1e-12)
    assert BALLAST.size_passing(0.1) == pytest.approx(0.0315, rel=1e-12)  # on a sieve
    assert BALLAST.size_passing(1.0) == pytest.approx(0.0625, rel=1e-12)
    assert Grading.equal(0.025).size_passing(0.5) == pytest.approx(0.025, rel=1e-8)
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(ValueError, match="d50"):
            BALLAST.size_passing(bad)
