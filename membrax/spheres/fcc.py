"""Face-centred cubic (FCC) specimens of equal spheres.

Contract: :func:`fcc_specimen` returns a :class:`Specimen`, a frozen pytree (:mod:`membrax.pytree`) whose
array fields are the sphere centres ``position`` (N, 3) in metres, the radii (N,) in metres, the 0-based
``layer`` index (N,) and boolean flags (N,) for the lateral boundary, the bottom and the top layer. Float
arrays come in JAX's default float dtype (float32, or float64 when the user enabled x64); this module
never enables x64. The build parameters are static fields, and the derived geometry (height, outline,
cross-section area, porosity, void ratio) are Python floats or small arrays computed from them, in SI units
(m, m², m³). A sphere's mass and moment of inertia are in :mod:`membrax.spheres.particles`.

Conventions. z is vertical and points up; the specimen stands on the plane z = 0, which the bottom spheres
touch; its axis is the z axis (x = y = 0). Particles are ordered layer by layer (z ascending), then by y
ascending, then by x ascending. The builder is deterministic and runs on the host in float64 with exact
integer lattice arithmetic, so it is not traceable: call it outside ``jax.jit``.

Geometry. FCC packing of touching spheres of diameter D with the cube axis vertical: horizontal square
layers of spacing D (a square layer of FCC is a {100} plane whose in-plane neighbours are half a cube
face diagonal apart, a/√2 = D for the cube side a = √2 D), stacked a/2 = D/√2 apart, each layer offset
by (D/2, D/2) from the one below. A sphere touches 12 others at distance exactly D: 4 in its layer at
(±D, 0, 0), (0, ±D, 0), and 4 above and 4 below at (±D/2, ±D/2, ±D/√2), whose distance is
√(D²/4 + D²/4 + D²/2) = D. The contact normals between layers make 45° with the vertical
(cos θ = (D/√2)/D), which is the orientation of Rowe's (1962) closed form for FCC (see
:data:`membrax.theory.FCC`).

Checks. Called with NaN, non-positive or non-integer sizes, or an unknown cross-section, the builder
raises ``ValueError`` naming the argument and its accepted values (see :mod:`membrax.validation`).
"""

from __future__ import annotations

import math
import operator

import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.spheres.particles import particle_mass
from membrax.validation import check_range

__all__ = [
    "CROSS_SECTIONS",
    "Specimen",
    "fcc_specimen",
    "with_imperfection",
]

#: Accepted values of ``cross_section`` in :func:`fcc_specimen`.
CROSS_SECTIONS = ("octagon", "square")

# In-layer and out-of-layer lattice neighbour offsets, in units of D/2 (see the module docstring).
_IN_LAYER_NEIGHBOURS = np.array([(2, 0), (-2, 0), (0, 2), (0, -2)])
_OUT_OF_LAYER_NEIGHBOURS = np.array([(1, 1), (1, -1), (-1, 1), (-1, -1)])

# Outward face normals of the outlines, counter-clockwise from (1, 0); written out so that they are exact.
_SQUARE_NORMALS = np.array([(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)])
_DIAGONAL = 1.0 / math.sqrt(2.0)
_OCTAGON_NORMALS = np.array(
    [(1.0, 0.0), (_DIAGONAL, _DIAGONAL), (0.0, 1.0), (-_DIAGONAL, _DIAGONAL), (-1.0, 0.0),
     (-_DIAGONAL, -_DIAGONAL), (0.0, -1.0), (_DIAGONAL, -_DIAGONAL)]
)  # fmt: skip


# ---------------------------------------------------------------------------------------------------------
# The specimen
# ---------------------------------------------------------------------------------------------------------


@pytree.dataclass
class Specimen:
    """An FCC specimen of equal spheres; built by :func:`fcc_specimen`, which states the geometry.

    Attributes:
      position: (N, 3) sphere centres in m; z of layer k is R + k·D/√2.
      radius: (N,) sphere radii R = D/2 in m.
      layer: (N,) 0-based layer index (integer).
      is_lateral_boundary: (N,) True where at least one of the sphere's 12 FCC lattice-neighbour sites lies
        outside the cross-section; sites above the top layer or below the bottom one do not count. These
        are the spheres on the side surface, which the membrane touches.
      is_bottom: (N,) True in the first layer (k = 0).
      is_top: (N,) True in the last layer (k = L − 1).
      particle_diameter: D in m.
      width_spheres: W, the number of spheres across the flats in the even layers.
      height_layers: L, the number of layers.
      cross_section: ``"octagon"`` or ``"square"``.
    """

    position: jnp.ndarray
    radius: jnp.ndarray
    layer: jnp.ndarray
    is_lateral_boundary: jnp.ndarray
    is_bottom: jnp.ndarray
    is_top: jnp.ndarray
    particle_diameter: float = pytree.static_field()
    width_spheres: int = pytree.static_field()
    height_layers: int = pytree.static_field()
    cross_section: str = pytree.static_field()

    # --- sizes ------------------------------------------------------------------------------------------

    @property
    def num_particles(self) -> int:
        """N, the number of spheres."""
        return int(self.position.shape[0])

    @property
    def particle_radius(self) -> float:
        """R = D/2 in m."""
        return 0.5 * self.particle_diameter

    @property
    def largest_diameter(self) -> float:
        """D in m: the contact search's cutoff (a random specimen's largest sphere)."""
        return self.particle_diameter

    @property
    def centre_half_width(self) -> float:
        """Centre half-width h = (W − 1)·D/2 in m: the centres lie in |x|, |y| ≤ h."""
        return 0.5 * (self.width_spheres - 1) * self.particle_diameter

    @property
    def centre_diagonal_limit(self) -> float:
        """Diagonal bound c in m: the centres lie in |x| + |y| ≤ c; ``math.inf`` for the square."""
        if self.cross_section == "square":
            return math.inf
        return _diagonal_limit_half_diameters(self.width_spheres) * self.particle_radius

    @property
    def width_across_flats(self) -> float:
        """Distance between opposite flat faces of the outline, 2h + D = W·D, in m."""
        return self.width_spheres * self.particle_diameter

    @property
    def height(self) -> float:
        """Specimen height (L − 1)·D/√2 + D in m: from the bottom plane to the top of the last layer."""
        return (self.height_layers - 1) * self.particle_diameter / math.sqrt(2.0) + self.particle_diameter

    # --- outline ----------------------------------------------------------------------------------------

    def _faces_float64(self) -> tuple[np.ndarray, np.ndarray]:
        """Outward unit normals (F, 2) and distances (F,) of the outline faces, float64 numpy."""
        flat_distance = self.centre_half_width + self.particle_radius
        if self.cross_section == "square":
            return _SQUARE_NORMALS.copy(), np.full(4, flat_distance)
        # A face |x| + |y| = s lies s/√2 from the axis; offset outwards by R from the centres' c.
        diagonal_distance = self.centre_diagonal_limit / math.sqrt(2.0) + self.particle_radius
        distances = np.where(np.arange(8) % 2 == 0, flat_distance, diagonal_distance)
        normals = _OCTAGON_NORMALS.copy()
        return normals, distances

    def outline_faces(self) -> tuple[jnp.ndarray, jnp.ndarray]:
        """The faces of the outline, for placing one lateral wall on each.

        The outline is the polygon of the centres offset outwards by R along each face normal (not the
        rounded Minkowski sum with a disc): flat faces |x|, |y| = h + R and, for the octagon, diagonal faces
        |x| + |y| = c + √2·R, i.e. c/√2 + R from the axis. A wall on a face touches the spheres whose centres
        lie on the corresponding face of the centre polygon and is penetrated by none.

        Returns:
          ``(normals, distances)``: outward unit normals (F, 2) in the xy plane and the distances (F,) in m
          of the faces from the axis, so that the outline is {p : normals @ p ≤ distances}. F = 8 for the
          octagon, 4 for the square; face k runs from ``outline_vertices[k]`` to ``outline_vertices[k+1]``,
          counter-clockwise starting with the face of normal (1, 0).
        """
        normals, distances = self._faces_float64()
        return jnp.asarray(normals), jnp.asarray(distances)

    def _vertices_float64(self) -> np.ndarray:
        normals, distances = self._faces_float64()
        previous = np.roll(np.arange(len(distances)), 1)
        # Vertex k is where face k − 1 meets face k: solve n_{k−1}·p = d_{k−1}, n_k·p = d_k.
        systems = np.stack([normals[previous], normals], axis=1)
        right_hand_sides = np.stack([distances[previous], distances], axis=1)
        return np.linalg.solve(systems, right_hand_sides[..., None])[..., 0]

    @property
    def outline_vertices(self) -> jnp.ndarray:
        """(F, 2) vertices (x, y) of the outline in m, counter-clockwise; see :meth:`outline_faces`."""
        return jnp.asarray(self._vertices_float64())

    @property
    def cross_section_area(self) -> float:
        """Area of the outline in m².

        Square: (2h + D)² = (W·D)². Octagon: the square minus four right isosceles corner triangles cut by
        the diagonal faces x + y = s (s = c + √2·R) of legs 2(h + R) − s, i.e. (2X)² − 2(2X − s)² with
        X = h + R.
        """
        flat_distance = self.centre_half_width + self.particle_radius
        area = (2.0 * flat_distance) ** 2
        if self.cross_section == "octagon":
            diagonal_sum = self.centre_diagonal_limit + math.sqrt(2.0) * self.particle_radius
            area -= 2.0 * (2.0 * flat_distance - diagonal_sum) ** 2
        return area

    # --- volumes ----------------------------------------------------------------------------------------

    @property
    def volume(self) -> float:
        """Total volume (outline area × height) in m³."""
        return self.cross_section_area * self.height

    @property
    def solid_volume(self) -> float:
        """Volume of the spheres, N·π·D³/6, in m³."""
        return self.num_particles * math.pi * self.particle_diameter**3 / 6.0

    @property
    def porosity(self) -> float:
        """Porosity n = 1 − V_solid/V; above the bulk FCC value because of the voids along the walls."""
        return 1.0 - self.solid_volume / self.volume

    @property
    def void_ratio(self) -> float:
        """Void ratio e = n/(1 − n) = V_voids/V_solid."""
        return self.porosity / (1.0 - self.porosity)

    # --- mass -------------------------------------------------------------------------------------------

    def mass(self, density):
        """(N,) particle masses in kg for a density ρ in kg/m³ (:mod:`membrax.spheres.particles`)."""
        return particle_mass(self.radius, density)

    def summary(self) -> str:
        """A short multi-line description: N, D, width, height, porosity, void ratio, boundary count."""
        num_boundary = int(np.sum(np.asarray(self.is_lateral_boundary)))
        return "\n".join(
            [
                f"FCC specimen, {self.cross_section} cross-section: N = {self.num_particles} spheres",
                f"  particle diameter D = {self.particle_diameter * 1e3:.4g} mm",
                f"  width across flats = {self.width_across_flats * 1e3:.4g} mm"
                f" ({self.width_spheres} spheres across)",
                f"  height = {self.height * 1e3:.4g} mm ({self.height_layers} layers)",
                f"  porosity n = {self.porosity:.4f}, void ratio e = {self.void_ratio:.4f}",
                f"  lateral-boundary particles: {num_boundary}",
            ]
        )


# ---------------------------------------------------------------------------------------------------------
# The builder
# ---------------------------------------------------------------------------------------------------------


def _diagonal_limit_half_diameters(width_spheres: int) -> int:
    """The octagon's centre bound c in units of D/2: 2·⌊(W − 1)/√2⌋, computed exactly with isqrt.

    In units of D/2 the centre half-width is H = W − 1 and √2·h = √2·H. Within a layer, x and y are both
    odd or both even multiples of D/2, so |x| + |y| is an even multiple, i.e. a multiple of D, and every
    multiple of D up to W − 2 is taken by some centre. The largest such value not exceeding √2·H is
    2·⌊H/√2⌋ = 2·⌊√(H²/2)⌋ = 2·isqrt(⌊H²/2⌋).
    """
    half_width = width_spheres - 1
    return 2 * math.isqrt(half_width * half_width // 2)


def _layer_sites(width_spheres: int, parity: int, diagonal_limit: int | None) -> np.ndarray:
    """Centres (x, y) of one layer in units of D/2, integer (M, 2), sorted by y then x.

    Even layers hold x, y = 2i − (W − 1), i = 0..W − 1; odd layers the lattice shifted by one unit (D/2),
    kept inside the same envelope |x|, |y| ≤ W − 1, which leaves W − 1 per row.
    """
    half_width = width_spheres - 1
    coordinates = np.arange(-half_width + parity, half_width + 1, 2)
    y, x = np.meshgrid(coordinates, coordinates, indexing="ij")
    sites = np.stack([x.ravel(), y.ravel()], axis=-1)
    if diagonal_limit is not None:
        sites = sites[np.abs(sites).sum(axis=-1) <= diagonal_limit]
    return sites


def _check_count(name: str, value, minimum: int, hint: str = "") -> int:
    """Return ``value`` as an int, raising ``ValueError`` if it is not an integer ≥ ``minimum``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} = {value!r} is not an integer; accepted values are integers >= {minimum}.")
    try:
        count = operator.index(value)
    except TypeError:
        raise ValueError(
            f"{name} = {value!r} is not an integer; accepted values are integers >= {minimum}."
        ) from None
    check_range(name, count, lower=minimum, hint=hint)
    return count


def fcc_specimen(
    particle_diameter: float = 0.025,
    width_spheres: int = 10,
    height_layers: int = 25,
    cross_section: str = "octagon",
) -> Specimen:
    """Build an FCC specimen of touching equal spheres, centred on the z axis and standing on z = 0.

    Layers. Layer k (k = 0..L − 1) has its centres at z = R + k·D/√2, so the bottom spheres touch z = 0 and
    the height is (L − 1)·D/√2 + D. Even layers hold the square lattice x, y ∈ {(i − (W − 1)/2)·D,
    i = 0..W − 1}; odd layers hold the lattice shifted by (D/2, D/2), kept inside the same envelope
    |x|, |y| ≤ h with h = (W − 1)·D/2, which leaves W − 1 per row. (With W even the even layers have
    half-integer coordinates in units of D and the odd layers integer ones; with W odd the other way round.)
    Membership is decided exactly on integer coordinates in units of D/2, so no tolerance is needed.

    Cross-section. ``"square"`` keeps the whole envelope (W² and (W − 1)² spheres per layer).
    ``"octagon"`` also cuts the four vertical edges, keeping the centres with |x| + |y| ≤ c, where c is
    the largest value of |x| + |y| taken by lattice centres that does not exceed √2·h. Since |x| + |y| of
    any centre is a multiple of D, c = D·⌊(W − 1)/√2⌋: the diagonal faces of the centre polygon then lie
    c/√2 ≤ h from the axis, as near as the lattice allows to the flat faces, a near-regular octagon. For
    W = 10 (D = 25 mm: 250 mm across flats), c = 6D and the layers hold 76 (even) and 69 (odd) spheres;
    L = 25 gives N = 13·76 + 12·69 = 1816 and a height of 449.3 mm, the paper's ~1800 spheres.

    Boundary. A sphere is on the lateral boundary when at least one of its 12 lattice-neighbour sites lies
    outside the cross-section; sites above the top layer or below the bottom one do not count. Not all of
    them touch a wall of :meth:`Specimen.outline_faces`: a flat face x = const is a {110} lattice plane that
    holds rows of alternate layers only, so it is touched by the even layers' outer rows while the odd
    layers' outer rows sit D/2 behind it; a diagonal face is a {100} plane and is touched in every layer.
    For W = 10 each layer has 24 boundary spheres; 12 of those in each odd layer are the set-back ones.

    Args:
      particle_diameter: D in m, > 0 (25 mm ballast-sized spheres by default).
      width_spheres: W, spheres per row in the even layers, an integer ≥ 3 for the octagon (W = 2 leaves no
        centre inside the corner cut) and ≥ 2 for the square.
      height_layers: L, the number of layers, an integer ≥ 2.
      cross_section: ``"octagon"`` (default) or ``"square"``.

    Returns:
      The :class:`Specimen`, ordered layer by layer (z ascending), then y, then x ascending.

    Raises:
      ValueError: naming the argument, for a non-positive, infinite or NaN diameter, a non-integer or too
        small width or height, or an unknown cross-section.
    """
    check_range(
        "particle_diameter",
        particle_diameter,
        lower=0.0,
        upper=math.inf,
        lower_open=True,
        upper_open=True,
        hint="Metres, e.g. 0.025 for 25 mm.",
    )
    if np.ndim(particle_diameter) != 0:
        raise ValueError(f"particle_diameter must be a scalar, got shape {np.shape(particle_diameter)}.")
    if cross_section not in CROSS_SECTIONS:
        raise ValueError(f"cross_section = {cross_section!r} is not one of {', '.join(CROSS_SECTIONS)}.")
    octagon = cross_section == "octagon"
    width_spheres = _check_count(
        "width_spheres",
        width_spheres,
        3 if octagon else 2,
        hint="The octagon needs at least 3 spheres across; use cross_section='square' for 2."
        if octagon
        else "",
    )
    height_layers = _check_count("height_layers", height_layers, 2)
    diameter = float(particle_diameter)

    diagonal_limit = _diagonal_limit_half_diameters(width_spheres) if octagon else None
    sites_by_parity = [_layer_sites(width_spheres, parity, diagonal_limit) for parity in (0, 1)]

    # Occupancy grids (one per parity) indexed by coordinate + offset, padded so neighbour lookups stay
    # inside; every layer of one parity has the same sites.
    offset = width_spheres + 2
    occupied = np.zeros((2, 2 * offset + 1, 2 * offset + 1), dtype=bool)
    for parity, sites in enumerate(sites_by_parity):
        occupied[parity, sites[:, 1] + offset, sites[:, 0] + offset] = True

    def all_occupied(parity: int, sites: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        neighbours = sites[:, None, :] + offsets[None, :, :]
        return occupied[parity, neighbours[..., 1] + offset, neighbours[..., 0] + offset].all(axis=-1)

    # With L ≥ 2 every layer has at least one adjacent layer, and all adjacent layers (of the other parity)
    # hold the same sites, so the boundary flag depends only on the site and the layer's parity.
    boundary_by_parity = [
        ~(
            all_occupied(parity, sites, _IN_LAYER_NEIGHBOURS)
            & all_occupied(1 - parity, sites, _OUT_OF_LAYER_NEIGHBOURS)
        )
        for parity, sites in enumerate(sites_by_parity)
    ]

    layer_indices = np.arange(height_layers)
    sites = np.concatenate([sites_by_parity[k % 2] for k in layer_indices])
    layer = np.concatenate([np.full(len(sites_by_parity[k % 2]), k) for k in layer_indices])
    is_lateral_boundary = np.concatenate([boundary_by_parity[k % 2] for k in layer_indices])

    radius = 0.5 * diameter
    position = np.empty((len(sites), 3))
    position[:, :2] = sites * radius
    position[:, 2] = radius + layer * (diameter / math.sqrt(2.0))

    return Specimen(
        position=jnp.asarray(position),
        radius=jnp.asarray(np.full(len(sites), radius)),
        layer=jnp.asarray(layer),
        is_lateral_boundary=jnp.asarray(is_lateral_boundary),
        is_bottom=jnp.asarray(layer == 0),
        is_top=jnp.asarray(layer == height_layers - 1),
        particle_diameter=diameter,
        width_spheres=width_spheres,
        height_layers=height_layers,
        cross_section=cross_section,
    )


def with_imperfection(specimen: Specimen, fraction: float, seed: int = 0) -> Specimen:
    """A copy of ``specimen`` whose radii are reduced at random: a seeded imperfection of the lattice.

    Sphere i gets R_i = R − f D u_i with u_i uniform on [0, 1) from ``numpy.random.default_rng(seed)``, so
    the same seed gives the same specimen on every machine; the centres stay on the lattice. A perfect
    FCC lattice deforms homogeneously and cannot localise; smaller spheres scattered through it open
    gaps of up to f D at its contacts, which let a failure mechanism form (the paper's Fig. 4 shows one).
    Radii are only reduced, because an enlarged sphere would start with an overlap of up to f D
    (k_n f D ≈ 250 N at f = 1e-3 and the paper's 25 mm, 1e7 N/m spheres, against ~6 N per contact at
    10 kPa).

    Args:
      specimen: from :func:`fcc_specimen`.
      fraction: f, the largest reduction as a fraction of the particle diameter, in [0, 0.5).
      seed: seed of the random numbers, >= 0.

    Raises:
      ValueError: ``fraction`` outside [0, 0.5) or a negative or non-integer ``seed``.
    """
    check_range("fraction", fraction, lower=0.0, upper=0.5, upper_open=True, hint="e.g. 1e-3.")
    seed = _check_count("seed", seed, 0, "a non-negative integer")
    draws = np.random.default_rng(seed).random(specimen.num_particles)
    radius = np.asarray(specimen.radius, dtype=float) - fraction * specimen.particle_diameter * draws
    return specimen.set(radius=jnp.asarray(radius, dtype=specimen.radius.dtype))
