"""Random packings, first half: a grading sampled by mass, and the loose cloud a compaction starts from.

Contract. :class:`Grading` is a particle-size distribution as a laboratory gives it: sieve sizes (m,
increasing) and the fraction of the mass passing each (0 at the first size, 1 at the last). Its
:func:`sample_diameters` draws the sphere diameters of a given total solid volume so that the spheres' mass
fractions follow the curve; :func:`mass_fractions` measures the fractions of any set of diameters on the
sieves; :func:`loose_cloud` places spheres at random, without overlap, in a cylinder (the mould) at a low
solid fraction. Everything here is host-side numpy in float64, deterministic for a seed (NumPy's
``default_rng``), and not traceable: call it outside ``jax.jit``. The compaction that takes the cloud to a
dense or loose specimen is a DEM run (the next step of the data flow).

Sampling by mass. Between two sieves a and b the grading curve is linear in size (the laboratory's straight
lines between points), so the mass is spread evenly over d ∈ (a, b]: the mass density is uniform in d and,
each sphere weighing ρ π d³/6, the number density is ∝ d⁻³. A bin of mass fraction f then holds
n = f V_s / v̄ spheres of mean volume v̄ = (π/6) 2 (b − a) / (a⁻² − b⁻²) (the mean of d³ under d⁻³), the
counts rounded by largest remainder, and its diameters are drawn from the inverse of F(d) = (a⁻² − d⁻²) /
(a⁻² − b⁻²), stratified (one draw in each of n equal quantile strata) so that a bin of few spheres still
spreads over its sizes. The sampled fractions differ from the curve by the rounding of the counts:
at most about one sphere's mass per bin (:func:`mass_fractions`, ``tests/test_grading.py``).

The loose cloud is random sequential addition (the largest spheres first, each at uniform random positions
until it overlaps none placed so far, found on a uniform cell grid): the cloud YADE's ``makeCloud`` and
PFC's ``ball distribute`` start from. Random sequential addition of equal spheres jams near a solid fraction
of 0.38; clouds are made at :data:`CLOUD_SOLID_FRACTION`, well below it.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from membrax import pytree

__all__ = [
    "CLOUD_SOLID_FRACTION",
    "OUTLINE_SIDES",
    "Grading",
    "RandomSpecimen",
    "loose_cloud",
    "mass_fractions",
    "sample_diameters",
]

#: The solid fraction of the loose cloud (random sequential addition jams near 0.38 for equal spheres).
CLOUD_SOLID_FRACTION = 0.25

#: Sides of the regular polygon, circumscribed about a random specimen's circle, that stands for its outline
#: where a polygon is needed (lateral walls, plots): its area is 1.0008 of the circle's.
OUTLINE_SIDES = 64


@dataclasses.dataclass(frozen=True)
class Grading:
    """A particle-size distribution: sieve sizes and the mass fraction passing each.

    Attributes:
      sizes: (n,) sieve sizes, m, strictly increasing, n >= 2.
      passing: (n,) mass fraction passing each sieve, non-decreasing from 0 (the first size: nothing is
        finer) to 1 (the last: everything passes).

    Raises:
      ValueError: naming the field, the offending point and the fix.
    """

    sizes: tuple[float, ...]
    passing: tuple[float, ...]

    def __post_init__(self):
        sizes = np.asarray(self.sizes, dtype=float)
        passing = np.asarray(self.passing, dtype=float)
        if sizes.ndim != 1 or sizes.shape != passing.shape or sizes.size < 2:
            raise ValueError(
                f"grading: give at least two points of (size, passing) with as many sizes as fractions; got "
                f"{sizes.size} sizes and {passing.size} fractions."
            )
        for name, values in (("size", sizes), ("passing", passing)):
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise ValueError(
                    f"grading: point {bad[0] + 1} has {name} {values[bad[0]]}; give finite numbers."
                )
        if sizes[0] <= 0.0:
            raise ValueError(f"grading: point 1 has size {sizes[0]:g} m; sizes must be positive.")
        steps = np.flatnonzero(np.diff(sizes) <= 0.0)
        if steps.size:
            k = steps[0]
            raise ValueError(
                f"grading: point {k + 2} has size {sizes[k + 1]:g} m after {sizes[k]:g} m; sizes must "
                "increase strictly (list the sieves from the finest to the coarsest)."
            )
        falls = np.flatnonzero(np.diff(passing) < 0.0)
        if falls.size:
            k = falls[0]
            raise ValueError(
                f"grading: point {k + 2} passes {100 * passing[k + 1]:g} % after {100 * passing[k]:g} % at "
                "the smaller sieve; the fraction passing never falls as the sieve grows."
            )
        if passing[0] != 0.0:
            raise ValueError(
                f"grading: the first point passes {100 * passing[0]:g} %; start the curve at 0 % (add the "
                "size below which nothing passes) so every sphere has a smallest size."
            )
        if passing[-1] != 1.0:
            raise ValueError(
                f"grading: the last point passes {100 * passing[-1]:g} %; the curve must rise to 100 % (add "
                "the size everything passes)."
            )

    @staticmethod
    def equal(diameter: float) -> Grading:
        """Equal spheres of ``diameter`` (m): a curve from 0 to 1 over a width of 1e-9 of the diameter."""
        return Grading(sizes=(diameter * (1.0 - 1e-9), float(diameter)), passing=(0.0, 1.0))

    @property
    def bins(self) -> list[tuple[float, float, float]]:
        """(smaller size a, larger size b, mass fraction f) of each bin with mass, m and dimensionless."""
        fractions = np.diff(np.asarray(self.passing, dtype=float))
        return [
            (float(self.sizes[k]), float(self.sizes[k + 1]), float(f))
            for k, f in enumerate(fractions)
            if f > 0.0
        ]

    @property
    def largest(self) -> float:
        """The largest diameter a sphere may have, m (the last sieve with mass below it)."""
        return self.bins[-1][1]

    @property
    def smallest(self) -> float:
        """The smallest diameter a sphere may have, m."""
        return self.bins[0][0]

    def size_passing(self, fraction: float) -> float:
        """The size through which ``fraction`` of the mass passes, m: d50 for 0.5 (a laboratory's D).

        Read off the curve as it is sampled, linear in size between sieves; for :meth:`equal` spheres the
        diameter.

        Raises:
          ValueError: ``fraction`` outside (0, 1].
        """
        if not (0.0 < fraction <= 1.0):
            raise ValueError(f"fraction = {fraction}; give a mass fraction in (0, 1] (0.5 for d50).")
        sizes, passing = np.asarray(self.sizes, dtype=float), np.asarray(self.passing, dtype=float)
        upper = int(np.argmax(passing >= fraction))  # the first sieve passing at least the fraction
        if upper == 0 or passing[upper] == passing[upper - 1]:
            return float(sizes[upper])
        share = (fraction - passing[upper - 1]) / (passing[upper] - passing[upper - 1])
        return float(sizes[upper - 1] + share * (sizes[upper] - sizes[upper - 1]))


def _one_size(a: float, b: float) -> bool:
    """Whether the bin (a, b] is one size, b (:meth:`Grading.equal`): its spheres are all of diameter b."""
    return b - a <= 1e-6 * b


def _mean_bin_volume(a: float, b: float) -> float:
    """Mean sphere volume of a bin whose number density is ∝ d⁻³ on (a, b], m³ (module docstring)."""
    if _one_size(a, b):
        return math.pi / 6.0 * b**3  # an equal-sphere bin (Grading.equal): its spheres are of size b
    return math.pi / 6.0 * 2.0 * (b - a) / (a**-2 - b**-2)


def _largest_remainder(real_counts: np.ndarray, total: int) -> np.ndarray:
    """Integers summing to ``total`` that round ``real_counts`` (Hamilton's method)."""
    counts = np.floor(real_counts).astype(np.int64)
    short = total - int(counts.sum())
    order = np.argsort(-(real_counts - counts), kind="stable")
    counts[order[:short]] += 1
    return counts


def sample_diameters(grading: Grading, solid_volume: float, seed: int = 0) -> np.ndarray:
    """Sphere diameters whose total volume is about ``solid_volume`` and whose mass follows ``grading``.

    Args:
      grading: the particle-size distribution.
      solid_volume: V_s, m³, > 0: the volume of solid to sample (specimen volume × solid fraction).
      seed: seed of NumPy's ``default_rng``.

    Returns:
      (N,) diameters, m, float64, largest first (the order :func:`loose_cloud` places them in).

    Raises:
      ValueError: a non-positive volume, or one that holds fewer than two spheres of the grading.
    """
    if not (math.isfinite(solid_volume) and solid_volume > 0.0):
        raise ValueError(f"solid_volume = {solid_volume}; give a positive volume in m³.")
    bins = grading.bins
    means = np.array([_mean_bin_volume(a, b) for a, b, _ in bins])
    fractions = np.array([f for _, _, f in bins])
    real = fractions * solid_volume / means
    total = round(float(real.sum()))
    if total < 2:
        raise ValueError(
            f"solid_volume = {solid_volume:g} m³ holds {real.sum():.2g} spheres of this grading; give a "
            "specimen several particles across."
        )
    counts = _largest_remainder(real * total / real.sum(), total)
    rng = np.random.default_rng(seed)
    diameters = []
    for (a, b, _), count in zip(bins, counts, strict=True):
        if count == 0:
            continue
        u = (np.arange(count) + rng.random(count)) / count  # one draw in each quantile stratum
        if _one_size(a, b):
            diameters.append(np.full(count, b))
        else:
            diameters.append((a**-2 - u * (a**-2 - b**-2)) ** -0.5)
    return np.sort(np.concatenate(diameters))[::-1].copy()


def mass_fractions(diameters, sizes) -> np.ndarray:
    """Mass fraction of ``diameters`` in each bin between consecutive ``sizes`` (a sieve analysis).

    A sphere of diameter d falls in the bin (a, b] with a < d <= b (it passes sieve b, not sieve a).

    Returns:
      (len(sizes) − 1,) mass fractions, summing to the fraction of the mass within the sizes.
    """
    diameters = np.asarray(diameters, dtype=float)
    volumes = diameters**3
    bin_index = np.searchsorted(np.asarray(sizes, dtype=float), diameters, side="left") - 1
    inside = (bin_index >= 0) & (bin_index < len(sizes) - 1)
    totals = np.bincount(bin_index[inside], weights=volumes[inside], minlength=len(sizes) - 1)
    return totals / volumes.sum()


def loose_cloud(
    diameters,
    mould_radius: float,
    solid_fraction: float = CLOUD_SOLID_FRACTION,
    seed: int = 0,
    max_tries: int = 10_000,
) -> tuple[np.ndarray, float]:
    """Centres of non-overlapping spheres placed at random in a cylinder (random sequential addition).

    The cylinder of radius ``mould_radius`` stands on z = 0 with its axis on z; its height is set so that the
    spheres fill ``solid_fraction`` of it. Every sphere lies wholly inside it.

    Args:
      diameters: (N,) diameters, m (placed in the given order: largest first places best).
      mould_radius: R, m, more than the largest radius.
      solid_fraction: the cloud's solid fraction, in (0, 0.35].
      seed: seed of NumPy's ``default_rng``.
      max_tries: random positions tried per sphere before giving up.

    Returns:
      ((N, 3) centres, m; the cloud's height, m).

    Raises:
      ValueError: bad sizes, or a sphere that found no free place in ``max_tries`` tries.
    """
    diameters = np.asarray(diameters, dtype=float)
    radii = 0.5 * diameters
    if not 0.0 < solid_fraction <= 0.35:
        raise ValueError(f"solid_fraction = {solid_fraction}; give a loose cloud's, in (0, 0.35].")
    if not mould_radius > radii.max():
        raise ValueError(
            f"mould_radius = {mould_radius:g} m; it must exceed the largest radius {radii.max():g} m."
        )
    solid = float(np.sum(math.pi / 6.0 * diameters**3))
    height = solid / (solid_fraction * math.pi * mould_radius**2)
    height = max(height, diameters.max())
    cell = diameters.max()
    grid: dict[tuple[int, int, int], list[int]] = {}
    centres = np.zeros((diameters.size, 3))
    rng = np.random.default_rng(seed)
    for i, radius in enumerate(radii):
        reach = mould_radius - radius
        for _ in range(max_tries):
            # Uniform in the disc of radius `reach` (√u radial law) and in height.
            rho, theta = reach * math.sqrt(rng.random()), 2.0 * math.pi * rng.random()
            point = np.array(
                [rho * math.cos(theta), rho * math.sin(theta), radius + (height - 2 * radius) * rng.random()]
            )
            key = tuple(int(v) for v in np.floor(point / cell))
            neighbours = [
                j
                for dx in (-1, 0, 1)
                for dy in (-1, 0, 1)
                for dz in (-1, 0, 1)
                for j in grid.get((key[0] + dx, key[1] + dy, key[2] + dz), ())
            ]
            if neighbours:
                gaps = np.linalg.norm(centres[neighbours] - point, axis=1) - (radii[neighbours] + radius)
                if np.any(gaps < 0.0):
                    continue
            centres[i] = point
            grid.setdefault(key, []).append(i)
            break
        else:
            raise ValueError(
                f"sphere {i} (diameter {diameters[i]:g} m) found no free place in {max_tries} tries at solid "
                f"fraction {solid_fraction}; lower it."
            )
    return centres, height


@pytree.dataclass
class RandomSpecimen:
    """A cylindrical specimen of spheres at random positions (made by :mod:`membrax.spheres.compaction`).

    It answers what the cells read of a specimen (:class:`membrax.spheres.fcc.Specimen` is the FCC
    one): centres and radii, the height, the cross-section and its outline, the characteristic diameter.
    z is vertical; the specimen stands on z = 0 and its axis is the z axis.

    Attributes:
      position: (N, 3) centres, m.
      radius: (N,) radii, m.
      diameter: the specimen's diameter (the mould's), m.
      height: the platens' separation, m.
      grading: the sieve sizes (m) and fractions passing it was sampled from, as two tuples.
      solid_fraction: of the whole specimen, as compacted.
      seed: the seed it was made with.
      packing_measures: the compaction's measures as (name, value) pairs (:attr:`measures`).
    """

    position: jnp.ndarray
    radius: jnp.ndarray
    diameter: float = pytree.static_field()
    height: float = pytree.static_field()
    grading: tuple = pytree.static_field(default=())
    solid_fraction: float = pytree.static_field(default=math.nan)
    seed: int = pytree.static_field(default=0)
    packing_measures: tuple = pytree.static_field(default=())

    @property
    def measures(self) -> dict:
        """The compaction's :func:`membrax.spheres.compaction.packing_measures` (empty if not known)."""
        return dict(self.packing_measures)

    cross_section = "circle"

    @property
    def num_particles(self) -> int:
        """N."""
        return int(self.position.shape[0])

    @property
    def particle_diameter(self) -> float:
        """The characteristic diameter, m: the mean of the spheres' diameters.

        The membrane's mesh edge and the shearing's inertial number are set from it.
        """
        return float(2.0 * np.mean(np.asarray(self.radius)))

    @property
    def particle_radius(self) -> float:
        """Half the characteristic diameter, m."""
        return 0.5 * self.particle_diameter

    @property
    def largest_diameter(self) -> float:
        """The largest sphere's diameter, m (the contact search's cutoff)."""
        return float(2.0 * np.max(np.asarray(self.radius)))

    @property
    def width_across_flats(self) -> float:
        """The diameter, m (the FCC specimen's name for its width)."""
        return self.diameter

    @property
    def cross_section_area(self) -> float:
        """π D²/4, m²."""
        return math.pi * self.diameter**2 / 4.0

    @property
    def volume(self) -> float:
        """Cross-section × height, m³."""
        return self.cross_section_area * self.height

    @property
    def porosity(self) -> float:
        """1 − V_solid/V."""
        solid = float(np.sum(4.0 / 3.0 * math.pi * np.asarray(self.radius, dtype=float) ** 3))
        return 1.0 - solid / self.volume

    def outline_faces(self):
        """((F, 2) outward unit normals, (F,) distances, m) of the circumscribed polygon.

        A regular polygon of :data:`OUTLINE_SIDES` faces, each touching the circle.
        """
        angles = 2.0 * math.pi * np.arange(OUTLINE_SIDES) / OUTLINE_SIDES
        normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        return jnp.asarray(normals), jnp.asarray(np.full(OUTLINE_SIDES, 0.5 * self.diameter))

    @property
    def outline_vertices(self) -> jnp.ndarray:
        """(F, 2) vertices of the circumscribed polygon, counter-clockwise, m.

        Vertex k lies between faces k − 1 and k.
        """
        angles = 2.0 * math.pi * (np.arange(OUTLINE_SIDES) - 0.5) / OUTLINE_SIDES
        reach = 0.5 * self.diameter / math.cos(math.pi / OUTLINE_SIDES)
        return jnp.asarray(reach * np.stack([np.cos(angles), np.sin(angles)], axis=1))

    @property
    def is_lateral_boundary(self) -> jnp.ndarray:
        """(N,) True for every sphere: the membrane may meet any sphere of a random specimen."""
        return jnp.ones(self.radius.shape, dtype=bool)

    def summary(self) -> str:
        """A short multi-line description."""
        radius = np.asarray(self.radius, dtype=float)
        return "\n".join(
            [
                f"random specimen, circular cross-section: N = {self.num_particles} spheres "
                f"(seed {self.seed})",
                f"  diameters {2e3 * radius.min():.4g}–{2e3 * radius.max():.4g} mm, mean "
                f"{self.particle_diameter * 1e3:.4g} mm",
                f"  diameter = {self.diameter * 1e3:.4g} mm, height = {self.height * 1e3:.4g} mm",
                f"  porosity n = {self.porosity:.4f}",
            ]
        )
