"""The one configuration of a membrane triaxial test: a frozen dataclass, TOML loading and checks.

Contract. :class:`TriaxialConfig` holds every input of a membrane triaxial run in laboratory units, each
field named with its unit (``cell_pressure_kpa``, ``membrane_thickness_mm``, ``friction_angle_deg``, ...);
its defaults are the paper's (25 mm spheres, 10 across, 25 FCC layers, 10 kPa, a 5 mm latex membrane of
1400 kPa, 25° interparticle friction). The SI values the simulator uses are properties converted here,
once (:attr:`TriaxialConfig.cell_pressure` in Pa, :attr:`TriaxialConfig.membrane_thickness` in m, ...).

A :class:`TriaxialConfig` is valid by construction: ``__post_init__`` checks every field and raises
:class:`ConfigError` before anything is built or compiled. Integers are accepted for float fields (and
stored as floats), integral floats for integer fields (stored as ints); booleans, strings and tables are
never numbers. NaN, ±inf and out-of-range values are refused with the field, its accepted range, the bad
value and the unit (ranges are checked by :func:`membrax.validation.check_range`). Several bad fields are
reported together in one :class:`ConfigError`, whose ``errors`` attribute lists them one by one.

TOML layout (:func:`load_config`, read with the standard library's ``tomllib``). Either every key at the
top level of the file (flat), or every key under one ``[triaxial]`` table and nothing else at the top
level; keys left out take their defaults::

    # flat                            # or under a table
    cell_pressure_kpa = 40.0          [triaxial]
    membrane_thickness_mm = 2.5       cell_pressure_kpa = 40.0
    layers = 25                       membrane_thickness_mm = 2.5

Unknown keys are errors. A key that names a known quantity in another unit (``cell_pressure_pa``,
``cell_pressure``, ``particle_diameter_cm``) gets "did you mean `cell_pressure_kpa` (kPa)?"; the unit
suffixes are ``_kpa`` (kPa), ``_mm`` (mm), ``_deg`` (degrees), ``_kg_m3`` (kg/m³) and ``_n_m`` (N/m).
:func:`dump_config_toml` writes the flat layout (or the table one) by hand, commented with each field's
unit and range, and round-trips exactly through :func:`load_config`. :func:`config_from_dict` applies the
same checks to a mapping (the CLI's ``--set key=value`` overrides, parsed by :func:`parse_overrides`).
Nothing here uses JAX: plain Python, ``math`` and numpy.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import os
import tomllib
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from membrax import defaults, theory
from membrax.errors import ConfigError
from membrax.spheres.grading import Grading
from membrax.validation import check_range

__all__ = [
    "TriaxialConfig",
    "load_config",
    "config_from_dict",
    "config_to_dict",
    "dump_config_toml",
    "with_overrides",
    "parse_overrides",
    "toml_value",
    "UNIT_SUFFIXES",
    "DEMO_CONFIG",
    "DEMO_RANDOM_CONFIG",
    "PERIODIC_DEMO_CONFIG",
    "PERIODIC_SMOKE_CONFIG",
    "BALLAST_GRADING_MM",
    "scaled_grading",
    "characteristic_size_mm",
    "compaction_state",
    "PACKINGS",
    "CELLS",
    "SMOKE_CONFIG",
    "SI_SCALE",
    "to_si",
]

#: The demo preset (``membrax demo``; ``membrax reproduce --size small`` takes its specimen, membrane and
#: rate): a small specimen (6 across, 10 layers, a coarser membrane) at 10 kPa in a 5 mm membrane to 10 %
#: axial strain. I = 5e-3 (5× the paper's 1e-3) keeps it within about a minute on 2 CPU cores (45 s
#: measured, 2026-11).
DEMO_CONFIG = dict(
    name="demo",
    particles_across=6,
    layers=10,
    membrane_edges_per_diameter=3.0,
    cell_pressure_kpa=10.0,
    membrane_thickness_mm=5.0,
    target_axial_strain=0.10,
    inertial_number=5e-3,
    chunk_steps=5000,
    checkpoint_every_chunks=5,
)

#: The random demo's changes to :data:`DEMO_CONFIG` (``membrax demo --packing random``): equal 25 mm spheres
#: compacted without friction in a mould 150 mm across (6 diameters, as the FCC demo) and 250 mm high.
DEMO_RANDOM_CONFIG = dict(
    name="demo_random",
    packing="random",
    specimen_diameter_mm=150.0,
    specimen_height_mm=250.0,
)

#: The periodic demo's changes to :data:`DEMO_RANDOM_CONFIG` (``examples/configs/periodic.toml``): the same
#: spheres, compaction, pressure and rate as a boundary-free element of 500 of them (:mod:`membrax.triaxial.
#: periodic`), the material's own response beside the random demo's specimen.
PERIODIC_DEMO_CONFIG = dict(name="periodic", cell="periodic", periodic_particles=500)

#: Railway ballast's grading at full size, [sieve size mm, percent passing by mass]: the midpoints of the
#: envelope of BS EN 13450 grading category A (31.5–50 mm), the one Network Rail specifies (22.4 mm 0–3 %,
#: 31.5 mm 1–25 %, 40 mm 30–65 %, 50 mm 70–99 %, 63 mm 100 %; the 22.4 mm point set to 0 % so that the curve
#: starts at nothing finer) [U: the envelope as commonly quoted, not read in the standard]. The paper's own
#: laboratory specimens were a 1/3 parallel gradation of it (10–20 mm, its §3). Scale with
#: :func:`scaled_grading`.
BALLAST_GRADING_MM = ((22.4, 0.0), (31.5, 12.5), (40.0, 47.5), (50.0, 85.0), (63.0, 100.0))


def scaled_grading(pairs, largest_mm: float) -> tuple[tuple[float, float], ...]:
    """A parallel gradation of ``pairs`` ([size mm, percent passing]) whose last sieve is ``largest_mm``.

    Every size is multiplied by ``largest_mm`` / the last size; the percentages stay (the laboratory's
    "1/3-scale parallel gradation").

    Raises:
      ValueError: a ``largest_mm`` that is not a positive finite number.
    """
    if not (isinstance(largest_mm, numbers.Real) and math.isfinite(largest_mm) and largest_mm > 0.0):
        raise ValueError(f"largest_mm = {largest_mm!r}; give the largest sieve size in mm, > 0.")
    factor = float(largest_mm) / float(pairs[-1][0])
    return tuple((float(size) * factor, float(percent)) for size, percent in pairs)


def compaction_state(compaction_friction_deg: float) -> str:
    """The packing state a compaction friction makes (:data:`membrax.defaults.COMPACTION_FRICTION_DEG`).

    ``"dense"`` or ``"loose"`` for those frictions, else ``"compaction friction X°"``.
    """
    for state, friction in defaults.COMPACTION_FRICTION_DEG.items():
        if math.isclose(float(compaction_friction_deg), friction, abs_tol=1e-9):
            return state
    return f"compaction friction {float(compaction_friction_deg):g}°"


def characteristic_size_mm(values: Mapping) -> float:
    """The particle size D a laboratory quotes for a configuration, mm: d50 of ``grading``, else the diameter.

    ``values``: a configuration as a mapping (:func:`config_to_dict`, a sweep's member). d50 is read off
    the grading curve (:meth:`~membrax.spheres.grading.Grading.size_passing`), as a laboratory reads
    it off its sieve analysis; the membrane corrections' D (``calibrate``) is this size.
    """
    pairs = values.get("grading") or ()
    if not pairs:
        return float(values["particle_diameter_mm"])
    return 1e3 * grading_of(pairs).size_passing(0.5)


#: The notebooks' smoke preset (``MEMBRAX_SMOKE=1``, what CI sets; ``notebooks/01``–``03`` add their cell
#: pressure, thickness or strain): 4 across, 5 layers, a membrane of edge D/3, sheared at I = 5e-3 after a
#: ramp to 0.1 % strain, to 0.4 % axial strain, recorded every 50 steps to 0.2 % and every 100 after.
SMOKE_CONFIG = dict(
    name="smoke",
    particles_across=4,
    layers=5,
    membrane_edges_per_diameter=3.0,
    target_axial_strain=0.004,
    inertial_number=5e-3,
    shear_ramp_strain=1e-3,
    fine_until_strain=2e-3,
    record_every_fine=50,
    record_every_coarse=100,
    chunk_steps=1000,
)


#: The periodic element's smoke preset (``notebooks/08``, the periodic tests): 64 of the random demo's spheres
#: at 40 kPa, sheared at I = 5e-3 to 1 % axial strain, recorded every 50 steps to 0.5 % and every 100 after;
#: it checks the machinery, not the material's answer.
PERIODIC_SMOKE_CONFIG = dict(
    name="periodic_smoke",
    packing="random",
    cell="periodic",
    periodic_particles=64,
    cell_pressure_kpa=40.0,
    inertial_number=5e-3,
    target_axial_strain=0.01,
    fine_until_strain=0.005,
    record_every_fine=50,
    record_every_coarse=100,
    consolidation_max_steps=3000,
    chunk_steps=500,
)


#: The unit suffixes of the field names and the units they stand for.
UNIT_SUFFIXES = {
    "_kg_m3": "kg/m³",
    "_n_m": "N/m",
    "_kpa": "kPa",
    "_mm": "mm",
    "_deg": "degrees",
}

#: The factor that takes a field of each unit suffix to SI (kPa → Pa, mm → m): the one conversion of the
#: configuration's values (its SI properties and :func:`to_si`).
SI_SCALE = {"_kpa": 1e3, "_mm": 1e-3}


def to_si(field: str, value):
    """A value of configuration field ``field`` in SI: ``value`` × :data:`SI_SCALE` of its unit suffix.

    Works on floats and on traced JAX values alike (the sensitivities differentiate through it).

    Raises:
      ValueError: a field whose unit has no SI scale here (degrees, N/m and kg/m³ are taken as they are).
    """
    for suffix, scale in SI_SCALE.items():
        if field.endswith(suffix):
            return scale * value
    raise ValueError(f"{field!r} has no SI conversion; fields ending in {', '.join(SI_SCALE)} do.")


def _in_si(field: str, doc: str) -> property:
    """A read-only property of :class:`TriaxialConfig`: its field ``field`` in SI (:func:`to_si`).

    ``doc`` is the property's docstring.
    """
    return property(lambda config: to_si(field, getattr(config, field)), doc=doc)


#: Accepted values of ``packing``: the FCC lattice of ``particles_across`` × ``layers``, or a random packing
#: compacted in a mould of ``specimen_diameter_mm`` × ``specimen_height_mm``.
PACKINGS = ("fcc", "random")

#: Accepted values of ``cell``: the membrane cell (the reference study's test) or the periodic element test
#: (:mod:`membrax.triaxial.periodic`: no boundary, the material's own response).
CELLS = ("membrane", "periodic")

#: The fewest spheres of a periodic element: a box of about 4 diameters, twice the contact distance plus the
#: neighbour skin (the minimum image needs more than that).
SMALLEST_PERIODIC_ELEMENT = 64

#: The fewest largest-particle diameters a random specimen's diameter and height may hold.
SMALLEST_RANDOM_SPECIMEN = 4.0

#: A membrane over equal spheres cannot hold a cell pressure above its neo-Hookean limit over the square
#: surface windows between them (:func:`membrax.theory.membrane_limit_pressure`): it balloons into the
#: specimen and the run goes non-finite, so such a configuration is refused. Above
#: :data:`INFLATION_WARNING_RATIO` of that limit a run is warned (:func:`inflation_ratio`): the largest ratio
#: at which every run of the laboratory grid and its held-out set (node contact) completed (0.33: 1.5 mm of
#: 1000 kPa at 50 kPa over the narrow grading's 25 mm windows). Above it runs failed: random 150 × 300 mm
#: specimens at the paper's membrane resolution stopped on Gent's lock in shearing at 0.47 (one seed of two)
#: and 0.59 (both; 1 mm of 700 and 1400 kPa, Gent's law and face contact, ``calibrate.designs.LAB_THIN``), a
#: random packing's surface windows being wider than the lattice's square one; FCC lattices in shearing at
#: 0.60 (8 across, node contact) and in consolidation with the cell pressure ramped slowly from 0 at
#: 0.97–1.03 (6 across) and 0.79–0.91 (8 across) of it (docs/model.md).
INFLATION_WARNING_RATIO = 0.33

#: The optional table that may hold every key of a TOML configuration file.
TABLE_NAME = "triaxial"


@dataclasses.dataclass(frozen=True)
class _Spec:
    """How one field is checked: its kind (float, int, bool, str), unit, interval and a fixing hint."""

    kind: type
    unit: str = ""
    lower: float | None = None
    lower_open: bool = False
    upper: float = math.inf
    upper_open: bool = True
    hint: str = ""
    choices: tuple[str, ...] = ()

    def interval(self) -> str:
        """The accepted interval as ``check_range`` writes it, e.g. ``(0, inf)``."""
        left = "(" if self.lower_open else "["
        right = ")" if self.upper_open else "]"
        lo = "-inf" if self.lower is None else f"{self.lower:g}"
        return f"{left}{lo}, {self.upper:g}{right}"

    def describe(self) -> str:
        """Type, interval and unit, e.g. ``a number in (0, inf) kPa``."""
        if self.kind is bool:
            return "a boolean (true or false)"
        if self.kind is str:
            return (
                f"one of {', '.join(repr(c) for c in self.choices)}" if self.choices else "a non-empty string"
            )
        if self.kind is tuple:
            return "an array of [size mm, percent passing] pairs (sizes increasing, 0 to 100 %), or []"
        what = "an integer" if self.kind is int else "a number"
        return f"{what} in {self.interval()} {self.unit}"


_POSITIVE = {"lower": 0.0, "lower_open": True}
_NON_NEGATIVE = {"lower": 0.0}
_ANGLE = {"lower": 0.0, "upper": 90.0}
_FRACTION_OPEN = {"lower": 0.0, "lower_open": True, "upper": 1.0}

_SPECS: dict[str, _Spec] = {
    "name": _Spec(str, hint="a name for the run's files: no path separators or control characters"),
    "particle_diameter_mm": _Spec(float, "mm", **_POSITIVE, hint="the paper uses 25 mm spheres"),
    "particles_across": _Spec(int, "spheres", lower=2, hint="spheres across the specimen; the paper uses 10"),
    "layers": _Spec(int, "layers", lower=2, hint="FCC layers; the paper uses 25"),
    "particle_density_kg_m3": _Spec(float, "kg/m³", **_POSITIVE, hint="solid density, e.g. 2650 kg/m³"),
    "friction_angle_deg": _Spec(
        float, "degrees", **_ANGLE, hint="interparticle friction; the paper uses 25°"
    ),
    "particle_stiffness_n_m": _Spec(float, "N/m", **_POSITIVE, hint="normal contact stiffness, e.g. 1e7 N/m"),
    "cell_pressure_kpa": _Spec(float, "kPa", **_POSITIVE, hint="the paper uses 10, 40 and 100 kPa"),
    "membrane_thickness_mm": _Spec(float, "mm", **_POSITIVE, hint="the paper uses 2.5 to 5 mm"),
    "membrane_modulus_kpa": _Spec(float, "kPa", **_POSITIVE, hint="latex, the paper uses 1400 kPa"),
    "membrane_friction_angle_deg": _Spec(float, "degrees", **_ANGLE, hint="membrane–particle friction"),
    "membrane_edges_per_diameter": _Spec(
        float, "edges per particle diameter", **_POSITIVE, hint="mesh edge = diameter / this; e.g. 5"
    ),
    "membrane_bending_factor": _Spec(
        float,
        "(dimensionless)",
        **_NON_NEGATIVE,
        hint="1: plate bending E t³/12(1 − ν²); 0: a pure membrane (the signs of the paper's Table 3)",
    ),
    "membrane_law": _Spec(str, choices=tuple(defaults.MEMBRANE_LAWS)),
    "membrane_locking_jm": _Spec(
        float,
        "(dimensionless)",
        **_POSITIVE,
        hint="the Gent law's J_m, the largest I₁ − 3; natural rubber about 100 (Gent 1996)",
    ),
    "target_axial_strain": _Spec(
        float, "(strain, dimensionless)", lower=0.0, lower_open=True, upper=1.0, hint="e.g. 0.10 for 10 %"
    ),
    "inertial_number": _Spec(
        float, "(dimensionless)", **_POSITIVE, upper=0.1, upper_open=False, hint="quasi-static: 1e-3"
    ),
    "coarse_inertial_number": _Spec(
        float,
        "(dimensionless)",
        **_NON_NEGATIVE,
        upper=0.1,
        upper_open=False,
        hint="the inertial number after fine_until_strain; 0 keeps inertial_number throughout",
    ),
    "shear_ramp_strain": _Spec(
        float,
        "(strain, dimensionless)",
        **_NON_NEGATIVE,
        upper=0.1,
        hint="axial strain at which the platens reach full speed after a linear ramp; 0: a step change",
    ),
    "symmetric_loading": _Spec(bool),
    "membrane_contact_offset_factor": _Spec(
        float,
        "(fraction of t_m/2)",
        **_NON_NEGATIVE,
        upper=1.0,
        upper_open=False,
        hint="0: nodes touch the sphere surface (the paper); 1: the membrane's inner face does",
    ),
    "membrane_contact_model": _Spec(str, choices=defaults.MEMBRANE_CONTACT_MODELS),
    "imperfection_fraction": _Spec(
        float,
        "(fraction of the particle diameter)",
        **_NON_NEGATIVE,
        upper=0.01,
        upper_open=False,
        hint="radii reduced by up to this fraction of d, at random; 0: a perfect lattice",
    ),
    "imperfection_seed": _Spec(int, "(seed)", lower=0),
    "packing": _Spec(str, choices=PACKINGS),
    "packing_seed": _Spec(int, "(seed)", lower=0),
    "specimen_diameter_mm": _Spec(
        float, "mm", **_POSITIVE, hint="a random specimen's diameter; the paper's specimen is 250 mm"
    ),
    "specimen_height_mm": _Spec(
        float, "mm", **_POSITIVE, hint="a random specimen's height; the paper's specimen is about 500 mm"
    ),
    "grading": _Spec(tuple),
    "compaction_friction_deg": _Spec(
        float,
        "degrees",
        lower=0.0,
        upper=90.0,
        hint="interparticle friction while a random specimen is compacted: 0 the densest, larger looser",
    ),
    "consolidation_tolerance": _Spec(
        float, "(unbalanced-force ratio)", **_NON_NEGATIVE, hint="0 takes the default for the dtype"
    ),
    "consolidation_max_steps": _Spec(int, "steps", lower=1),
    "record_every_fine": _Spec(int, "steps", lower=1),
    "fine_until_strain": _Spec(float, "(strain, dimensionless)", **_NON_NEGATIVE, upper=1.0),
    "record_every_coarse": _Spec(int, "steps", lower=1),
    "chunk_steps": _Spec(int, "steps", lower=1),
    "checkpoint_every_chunks": _Spec(int, "chunks", lower=1),
    "vtk_every_steps": _Spec(int, "steps", lower=0, hint="0 writes no VTK snapshots"),
    "float64": _Spec(bool),
    "float32_shearing": _Spec(bool),
    "viscous_damping": _Spec(bool),
    "damping_frame": _Spec(str, choices=defaults.DAMPING_FRAMES),
    "dt_safety": _Spec(float, "(fraction of the critical time step)", **_FRACTION_OPEN, upper_open=False),
    "cell": _Spec(str, choices=CELLS),
    "periodic_particles": _Spec(
        int,
        "spheres",
        lower=SMALLEST_PERIODIC_ELEMENT,
        hint="the spheres of a periodic element (cell = 'periodic'); 500 hold about 7 diameters per side",
    ),
}


@dataclasses.dataclass(frozen=True)
class TriaxialConfig:
    """Every input of a membrane triaxial test, in laboratory units named in the field names.

    Defaults are the paper's values. Ranges: ``(a, b)`` open, ``[a, b]`` closed, ``inf`` unbounded.

    Attributes:
      name (str): a non-empty name for the run's output files; no path separators or control
        characters, not ``.`` or ``..``. Default ``"membrax"``.
      particle_diameter_mm (float): sphere diameter, mm, in (0, inf). Default 25.
      particles_across (int): spheres across the specimen, in [2, inf). Default 10 (the paper).
      layers (int): FCC layers of the specimen, in [2, inf). Default 25 (the paper).
      particle_density_kg_m3 (float): solid density of the spheres, kg/m³, in (0, inf). Default 2650.
      friction_angle_deg (float): interparticle friction angle, degrees, in [0, 90). Default 25.
      particle_stiffness_n_m (float): normal contact stiffness, N/m, in (0, inf). Default 1e7.
      cell_pressure_kpa (float): cell (confining) pressure, kPa, in (0, inf). Default 10.
      membrane_thickness_mm (float): latex membrane thickness, mm, in (0, inf). Default 5.
      membrane_modulus_kpa (float): membrane Young's modulus, kPa, in (0, inf). Default 1400.
      membrane_friction_angle_deg (float): membrane–particle friction angle, degrees, in [0, 90).
        Default 25.
      membrane_edges_per_diameter (float): membrane mesh resolution, edges per particle diameter
        (dimensionless), in (0, inf); the mesh edge is particle diameter / this. Default 5.
      membrane_bending_factor (float): scale of the membrane's bending rigidity (dimensionless), in
        [0, inf): 1 the plate's E t³/12(1 − ν²), 0 a pure membrane. Default 0 (the paper's membrane: it
        reproduces the paper's Table 3 at paper size; plate bending does not).
      membrane_law (str): the membrane's stretching law, ``"neo-hookean"`` (incompressible), ``"gent"``
        (incompressible, strain-stiffening: it locks at I₁ − 3 = ``membrane_locking_jm``) or ``"svk"``
        (St Venant–Kirchhoff, ν = ½, for small strains); all three have the small-strain modulus
        ``membrane_modulus_kpa`` (:func:`membrax.membrane.energies.stretching_energy`). Default
        ``"neo-hookean"``.
      membrane_locking_jm (float): the Gent law's locking constant J_m (dimensionless), in (0, inf); read
        only when ``membrane_law = "gent"``. Default 97.2 (Gent 1996's natural rubber,
        :data:`membrax.defaults.GENT_LOCKING_JM`).
      target_axial_strain (float): axial strain at which shearing stops (dimensionless), in (0, 1).
        Default 0.10.
      inertial_number (float): inertial number setting the shear strain rate (dimensionless), in
        (0, 0.1]. Default 1e-3.
      coarse_inertial_number (float): inertial number of the shearing after ``fine_until_strain``
        (dimensionless), in [0, 0.1]; the platens change speed linearly over ``shear_ramp_strain``. 0 keeps
        ``inertial_number`` throughout. Default 0.
      shear_ramp_strain (float): axial strain (dimensionless) at which the platens reach full speed after
        a linear ramp from rest, in [0, 0.1]; 0 starts them at full speed (a step change, whose stress
        wave shows as a spurious peak). Default 1e-2 (see membrax.defaults.SHEAR_RAMP_STRAIN).
      symmetric_loading (bool): both platens close at half the rate each (true), or the bottom one
        stays and the top one closes at the full rate. Default true.
      membrane_contact_offset_factor (float): where membrane nodes touch spheres, as a fraction of
        t_m/2 outside the sphere surface, in [0, 1]: 0 the sphere surface (the paper's nodes "lie on the
        surface of the respective particle"), 1 the membrane's inner face touches it (nodes on the
        mid-surface, t_m/2 off). Default 1.
      membrane_contact_model (str): where the spheres meet the membrane: "nodes" (its nodes, the
        paper's) or "faces" (its faces, edges and nodes: the closest point of its mid-surface, so a
        deeply indented sheet cannot pass between its nodes through a sphere; a compiled CPU kernel
        forward, slower per step than node contact). Default "nodes".
      imperfection_fraction (float): seeded imperfection, the largest radius reduction as a fraction of
        the particle diameter, in [0, 0.01]; each sphere's radius is reduced by a uniform random fraction
        of it (the lattice's centres stay). Default 0 (a perfect lattice).
      imperfection_seed (int): seed of the imperfection's random numbers, in [0, inf). Default 0.
      packing (str): ``"fcc"`` (the lattice of ``particles_across`` × ``layers``) or ``"random"`` (spheres
        compacted in a mould, :mod:`membrax.spheres.compaction`). Default ``"fcc"``.
      packing_seed (int): a random packing's seed, in [0, inf). Default 0.
      specimen_diameter_mm (float): a random specimen's diameter, mm, in (0, inf). Default 250.
      specimen_height_mm (float): a random specimen's height, mm, in (0, inf). Default 500. The compacted
        specimen keeps the sampled sizes and comes out within a few per cent of the size asked for.
      grading (array): a random specimen's particle sizes as [size mm, percent passing by mass] pairs,
        sizes increasing, from 0 to 100 %; ``[]`` (the default) for equal spheres of
        ``particle_diameter_mm``.
      compaction_friction_deg (float): interparticle friction during a random specimen's compaction,
        degrees, in [0, 90]: 0 the densest state, larger looser. Default 0.
      consolidation_tolerance (float): unbalanced-force ratio ending consolidation (dimensionless), in
        [0, inf); 0 takes the default for the dtype (1e-3 in float64, 5e-3 in float32). Default 0.
      consolidation_max_steps (int): most time steps of consolidation, in [1, inf). Default 200000.
      record_every_fine (int): steps between records while the axial strain is below
        ``fine_until_strain``, in [1, inf). Default 25.
      fine_until_strain (float): axial strain (dimensionless) up to which records are fine, in [0, 1).
        Default 0.01.
      record_every_coarse (int): steps between records after ``fine_until_strain``, in [1, inf).
        Default 250.
      chunk_steps (int): time steps per compiled chunk, in [1, inf). Default 2000.
      checkpoint_every_chunks (int): chunks between checkpoints, in [1, inf). Default 10.
      vtk_every_steps (int): steps between VTK snapshots, in [0, inf); 0 writes none. Default 0.
      float64 (bool): run in double precision. Default false.
      float32_shearing (bool): with ``float64``: consolidate in double precision (the stresses at the start
        of shearing, Table 3) and shear in single precision (faster); no effect without ``float64``.
        Default false.
      dt_safety (float): time step as a fraction of the critical one (dimensionless), in (0, 1].
        Default 0.5.
      viscous_damping (bool): the smooth mode for gradients through a rollout: mass-proportional viscous
        damping γ = 2αω/π (ω = √(k_n/m), α = 0.3; DampingParams.equivalent_viscous) on spheres and
        membrane nodes instead of the paper's Cundall local damping α = 0.3, whose sign(v) makes the
        discrete step discontinuous in the state. Default false (the paper's damping).
      damping_frame (str): the velocities the damping acts on, spheres and membrane nodes alike:
        ``"affine"``, the velocity relative to the affine field of the platens while they shear the
        specimen (membrax.defaults.DAMPING_FRAME: the damping's drag on the moving spheres no longer loads
        the platens), or ``"absolute"``, the velocity itself (the paper's practice, whose drag raised the
        platen stress 1.8 % above the Love–Weber stress in a paper-size rigid box at 10 kPa and I = 1e-3,
        ``examples/damping_artefact.py``). The same law in consolidation. Default ``"affine"``.
      cell (str): ``"membrane"``, the membrane cell (the reference study's test), or ``"periodic"``, the
        boundary-free element test of the same spheres (:mod:`membrax.triaxial.periodic`): a random packing
        of ``periodic_particles`` spheres made in a periodic box as the mould's (same grading, seed and
        compaction friction), consolidated to the cell pressure and compressed at the inertial number with
        the lateral stresses servo-held; the membrane and mould fields are not used, and shearing needs no
        start-up ramp (``shear_ramp_strain``) since the box moves every sphere with it. Default
        ``"membrane"``.
      periodic_particles (int): spheres of the periodic element, in [64, inf). Default 500.

    Raises:
      ConfigError: on construction, listing every field that is of the wrong type or out of range.
    """

    name: str = "membrax"
    particle_diameter_mm: float = 1e3 * defaults.PARTICLE_DIAMETER
    particles_across: int = defaults.PARTICLES_ACROSS
    layers: int = defaults.LAYERS
    particle_density_kg_m3: float = 2650.0
    friction_angle_deg: float = defaults.FRICTION_ANGLE_DEG
    particle_stiffness_n_m: float = 1.0e7
    cell_pressure_kpa: float = 10.0
    membrane_thickness_mm: float = 5.0
    membrane_modulus_kpa: float = defaults.MEMBRANE_MODULUS / 1e3
    membrane_friction_angle_deg: float = 25.0
    membrane_edges_per_diameter: float = 5.0
    membrane_bending_factor: float = 0.0
    membrane_law: str = "neo-hookean"
    membrane_locking_jm: float = defaults.GENT_LOCKING_JM
    target_axial_strain: float = 0.10
    inertial_number: float = 1.0e-3
    coarse_inertial_number: float = 0.0
    shear_ramp_strain: float = defaults.SHEAR_RAMP_STRAIN
    symmetric_loading: bool = True
    membrane_contact_offset_factor: float = 1.0
    membrane_contact_model: str = "nodes"
    imperfection_fraction: float = 0.0
    imperfection_seed: int = 0
    packing: str = "fcc"
    packing_seed: int = 0
    specimen_diameter_mm: float = 250.0
    specimen_height_mm: float = 500.0
    grading: tuple = ()
    compaction_friction_deg: float = 0.0
    consolidation_tolerance: float = 0.0
    consolidation_max_steps: int = 200000
    record_every_fine: int = 25
    fine_until_strain: float = 0.01
    record_every_coarse: int = 250
    chunk_steps: int = 2000
    checkpoint_every_chunks: int = 10
    vtk_every_steps: int = 0
    float64: bool = False
    float32_shearing: bool = False
    dt_safety: float = 0.5
    viscous_damping: bool = False
    damping_frame: str = defaults.DAMPING_FRAME
    cell: str = "membrane"
    periodic_particles: int = 500

    def __post_init__(self):
        values, errors = _check_fields({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})
        if errors:
            raise ConfigError(errors)
        for key, value in values.items():  # store floats as float, integral floats as int
            object.__setattr__(self, key, value)

    def validate(self) -> TriaxialConfig:
        """Check every field again and return ``self``.

        Returns:
          this configuration, unchanged.

        Raises:
          ConfigError: listing every bad field (cannot happen for an instance built normally, since
            construction already checks; kept for instances altered with ``object.__setattr__``).
        """
        _, errors = _check_fields(config_to_dict(self))
        if errors:
            raise ConfigError(errors)
        return self

    # The SI values the simulator uses, each a field in laboratory units converted once (:func:`to_si`).
    particle_diameter = _in_si("particle_diameter_mm", "Sphere diameter, m.")
    specimen_diameter = _in_si("specimen_diameter_mm", "A random specimen's requested diameter, m.")
    specimen_height = _in_si("specimen_height_mm", "A random specimen's requested height, m.")
    cell_pressure = _in_si("cell_pressure_kpa", "Cell pressure, Pa.")
    membrane_thickness = _in_si("membrane_thickness_mm", "Membrane thickness, m.")
    membrane_modulus = _in_si("membrane_modulus_kpa", "Membrane Young's modulus, Pa.")

    @property
    def particle_grading(self) -> Grading:
        """The grading a random specimen samples: ``grading``, or equal spheres of the particle diameter."""
        return grading_of(self.grading) if self.grading else Grading.equal(self.particle_diameter)

    @property
    def compaction_friction_coefficient(self) -> float:
        """The compaction's friction coefficient, tan ``compaction_friction_deg``."""
        return math.tan(math.radians(self.compaction_friction_deg))

    @property
    def particle_radius(self) -> float:
        """Sphere radius, m."""
        return 0.5 * self.particle_diameter

    @property
    def stretching_model(self) -> str:
        """The simulator's name of ``membrane_law`` (:data:`membrax.defaults.MEMBRANE_LAWS`)."""
        return defaults.MEMBRANE_LAWS[self.membrane_law]

    @property
    def membrane_edge_length(self) -> float:
        """Target edge length of the membrane mesh, m: particle diameter / ``membrane_edges_per_diameter``."""
        return self.particle_diameter / self.membrane_edges_per_diameter

    @property
    def friction_coefficient(self) -> float:
        """Interparticle friction coefficient, tan(``friction_angle_deg``)."""
        return math.tan(math.radians(self.friction_angle_deg))

    @property
    def membrane_friction_coefficient(self) -> float:
        """Membrane–particle friction coefficient, tan(``membrane_friction_angle_deg``)."""
        return math.tan(math.radians(self.membrane_friction_angle_deg))

    @property
    def consolidation_tolerance_or_none(self) -> float | None:
        """``consolidation_tolerance``, or ``None`` (the simulator's default for the dtype) when it is 0."""
        return self.consolidation_tolerance if self.consolidation_tolerance > 0.0 else None


FIELD_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(TriaxialConfig))
_DEFAULTS: dict[str, Any] = {f.name: f.default for f in dataclasses.fields(TriaxialConfig)}
assert set(FIELD_NAMES) == set(_SPECS), "every field needs a spec"

#: (stem, field) for each field with a unit suffix, longest stem first, e.g.
#: ``("cell_pressure", "cell_pressure_kpa")``.
_STEMS = sorted(
    (
        (field[: -len(suffix)], field)
        for field in FIELD_NAMES
        for suffix in UNIT_SUFFIXES
        if field.endswith(suffix)
    ),
    key=lambda pair: -len(pair[0]),
)


def _shown(value: Any) -> str:
    """A value as the user wrote it, for messages."""
    if isinstance(value, bool | np.bool_):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array"
    if isinstance(value, numbers.Real):
        return repr(value)
    return f"a {type(value).__name__}"


def _example(key: str) -> str:
    """``key = <default>`` in TOML, as a fix to show."""
    return f"{key} = {toml_value(_DEFAULTS[key])}"


def _check_name(value: Any) -> tuple[Any, str | None]:
    spec = _SPECS["name"]
    if not isinstance(value, str):
        return value, f'name must be {spec.describe()}; got {_shown(value)}. Write e.g. name = "membrax".'
    bad = (
        not value
        or value in (".", "..")
        or any(sep in value for sep in ("/", "\\"))
        or any(ord(char) < 32 or ord(char) == 127 for char in value)
    )
    if bad:
        return value, f"name = {value!r} is not usable in file names; give {spec.describe()}, {spec.hint}."
    return value, None


def _check_grading(value: Any) -> tuple[Any, str | None]:
    """A grading as an array of [size mm, percent passing] pairs: normalised to a tuple of float pairs."""
    fix = (
        "Write e.g. grading = [[20.0, 0.0], [25.0, 40.0], [31.5, 100.0]] (mm, % passing), or [] for equal "
        "spheres."
    )
    if not isinstance(value, list | tuple):
        return (
            value,
            f"grading must be an array of [size mm, percent passing] pairs; got {_shown(value)}. {fix}",
        )
    if len(value) == 0:
        return (), None
    pairs = []
    for number, point in enumerate(value, start=1):
        good = (
            isinstance(point, list | tuple)
            and len(point) == 2
            and all(isinstance(x, numbers.Real) and not isinstance(x, bool | np.bool_) for x in point)
        )
        if not good:
            return value, f"grading: point {number} is {_shown(point)}, not a [size mm, percent] pair. {fix}"
        pairs.append((float(point[0]), float(point[1])))
    try:  # checked in mm, so that the messages quote the user's numbers
        Grading(
            sizes=tuple(size for size, _ in pairs), passing=tuple(percent / 100.0 for _, percent in pairs)
        )
    except ValueError as error:
        message = str(error).replace(" m ", " mm ").replace(" m;", " mm;").replace(" m,", " mm,")
        return value, f"{message} {fix}"
    return tuple(pairs), None


def grading_of(pairs) -> Grading:
    """The :class:`~membrax.spheres.grading.Grading` of [size mm, percent passing] pairs.

    mm and % are converted here, once.
    """
    sizes = tuple(to_si("size_mm", size) for size, _ in pairs)
    return Grading(sizes=sizes, passing=tuple(percent / 100.0 for _, percent in pairs))


def _check_value(key: str, value: Any) -> tuple[Any, str | None]:
    """``(normalised value, None)`` if ``value`` is valid for field ``key``, else ``(value, message)``."""
    spec = _SPECS[key]
    if spec.kind is tuple:
        return _check_grading(value)
    if spec.kind is str and spec.choices:
        if value in spec.choices:
            return value, None
        return (
            value,
            f'{key} must be {spec.describe()}; got {_shown(value)}. Write e.g. {key} = "{spec.choices[0]}".',
        )
    if spec.kind is str:
        return _check_name(value)
    wrong_type = f"{key} must be {spec.describe()}; got {_shown(value)}."
    if spec.kind is bool:
        if isinstance(value, bool | np.bool_):
            return bool(value), None
        return value, f"{wrong_type} Write {key} = true or {key} = false (no quotes)."
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        return value, f"{wrong_type} Write it as a number without quotes, e.g. {_example(key)}."
    if spec.kind is int:
        if not isinstance(value, numbers.Integral):
            if not (math.isfinite(value) and float(value).is_integer()):
                return value, f"{wrong_type} Give a whole number, e.g. {_example(key)}."
        value = int(value)
    else:
        try:
            value = float(value)
        except OverflowError:
            value = math.inf if value > 0 else -math.inf
    hint = f"Unit: {spec.unit.strip('()')}." + (f" Hint: {spec.hint}." if spec.hint else "")
    try:
        check_range(
            key,
            value,
            lower=spec.lower,
            lower_open=spec.lower_open,
            upper=spec.upper,
            upper_open=spec.upper_open,
            hint=hint,
        )
    except OverflowError:  # an integer too large for a float
        shown = f"{str(value)[:12]}... ({len(str(value))} digits)"
        return value, f"{key} = {shown} is too large; accepted range is {spec.interval()}. {hint}"
    except ValueError as error:
        return value, str(error)
    return value, None


def _check_fields(values: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """Check and normalise every field of ``values`` (all known keys); return the values and the errors."""
    normalised, errors = {}, []
    for key in FIELD_NAMES:
        value, error = _check_value(key, values[key])
        normalised[key] = value
        if error is not None:
            errors.append(error)
    if not errors and normalised["cell"] == "periodic":
        if normalised["packing"] != "random":
            errors.append(
                f"cell = 'periodic' with packing = {normalised['packing']!r}: the periodic element is a "
                "random packing made in its box; set packing = 'random'."
            )
        return normalised, errors  # no mould and no membrane to check
    if not errors and normalised["packing"] == "random":
        errors.extend(_random_specimen_errors(normalised))
    if not errors and not normalised["grading"] and inflation_ratio(normalised) >= 1.0:
        errors.append(_inflation_message(normalised))
    return normalised, errors


def inflation_ratio(values: Mapping[str, Any]) -> float:
    """σc over the membrane's limit pressure across a square window of the particles, p_max (0 if none).

    p_max, by ``membrane_law``: :func:`membrax.theory.membrane_limit_pressure` (E_m, t_m, a) for the
    neo-Hookean law, :func:`membrax.theory.gent_membrane_limit_pressure` (E_m, t_m, a, J_m) for Gent's
    (infinite, so a ratio of 0, for J_m below :data:`membrax.theory.GENT_MONOTONIC_LOCKING_JM`); the SVK
    law has no limit point (its bulge pressure rises monotonically), a ratio of 0. a = (√2 − 1) D/2 (the
    window between four touching spheres, :data:`membrax.theory.SQUARE_WINDOW_RATIO`), D the particle
    diameter or, for a grading, its largest size (an upper bound on the windows, which smaller particles
    partly fill).

    Args:
      values: the configuration's fields (a mapping, or ``config_to_dict`` of a configuration).
    """
    membrane = (values["membrane_modulus_kpa"], values["membrane_thickness_mm"])
    aperture_mm = _window_radius_mm(values)
    law = values["membrane_law"]
    if law == "svk":
        return 0.0
    if law == "gent":
        limit_kpa = theory.gent_membrane_limit_pressure(*membrane, aperture_mm, values["membrane_locking_jm"])
    else:
        limit_kpa = theory.membrane_limit_pressure(*membrane, aperture_mm)
    return float(values["cell_pressure_kpa"] / limit_kpa)


def _inflation_message(values: Mapping[str, Any]) -> str:
    """Why a membrane this thin and soft cannot hold the cell pressure, and what to change."""
    ratio = inflation_ratio(values)
    limit = values["cell_pressure_kpa"] / ratio
    stiffness = values["membrane_modulus_kpa"] * values["membrane_thickness_mm"]
    return (
        f"cell_pressure_kpa = {values['cell_pressure_kpa']:g} exceeds {limit:.3g} kPa, the most that "
        f"membrane_thickness_mm = {values['membrane_thickness_mm']:g} of membrane_modulus_kpa = "
        f"{values['membrane_modulus_kpa']:g} can hold over the windows between "
        f"{values['particle_diameter_mm']:g} mm spheres ({_limit_statement(values, limit)}, with "
        f"a = 0.414 D/2; docs/model.md): it would balloon into the specimen and {_runaway(values)}. "
        f"Raise the membrane's thickness or modulus (E_m t_m above {stiffness * ratio:.3g} kPa·mm) or lower "
        "the cell pressure. (A latex measured to stiffen sooner may be given as membrane_law = 'gent' with "
        f"its membrane_locking_jm: below J_m = {theory.GENT_MONOTONIC_LOCKING_JM:g} there is no inflation "
        "limit.)"
    )


def _runaway(values: Mapping[str, Any]) -> str:
    """What ballooning does to a run: with node contact it goes non-finite, with face contact it does not."""
    if values["membrane_contact_model"] == "faces":
        return (
            "rest on the spheres behind the windows, a bulge deeper than the mesh resolves (face contact "
            "keeps the run finite, not the bulge right)"
        )
    return "the run go non-finite"


def _window_radius_mm(values: Mapping[str, Any]) -> float:
    """The radius a = (√2 − 1) D/2 of the particles' square window, mm (D: a grading's largest size)."""
    pairs = values["grading"]
    diameter_mm = grading_of(pairs).largest * 1e3 if pairs else values["particle_diameter_mm"]
    return 0.5 * theory.SQUARE_WINDOW_RATIO * diameter_mm


def _limit_statement(values: Mapping[str, Any], limit_kpa: float) -> str:
    """The law's inflation limit as c (E_m/3) t_m / a, for the refusal."""
    tension_scale = values["membrane_modulus_kpa"] / 3.0 * values["membrane_thickness_mm"]
    coefficient = limit_kpa * _window_radius_mm(values) / tension_scale
    if values["membrane_law"] == "gent":
        law = f"a Gent sheet's inflation limit at J_m = {values['membrane_locking_jm']:g}"
    else:
        law = "a neo-Hookean sheet's inflation limit"
    return f"{law}, {coefficient:.3g} (E_m/3) t_m / a"


def _random_specimen_errors(values: Mapping[str, Any]) -> list[str]:
    """A random specimen must hold a few of its largest particles across and along."""
    pairs = values["grading"]
    largest_mm = grading_of(pairs).largest * 1e3 if pairs else values["particle_diameter_mm"]
    errors = []
    for key in ("specimen_diameter_mm", "specimen_height_mm"):
        if values[key] < SMALLEST_RANDOM_SPECIMEN * largest_mm:
            errors.append(
                f"{key} = {values[key]:g} mm holds fewer than {SMALLEST_RANDOM_SPECIMEN:g} of the largest "
                f"particles ({largest_mm:g} mm); make it at least {SMALLEST_RANDOM_SPECIMEN * largest_mm:g} "
                "mm (laboratories keep the largest particle below 1/6 of the diameter)."
            )
    return errors


def _unknown_key_message(key: Any) -> str:
    """Why ``key`` is not a field, with the closest field: the same quantity in our unit, or a typo."""
    text = str(key)
    lowered = text.lower()
    for stem, field in _STEMS:
        if lowered == stem or lowered.startswith(stem + "_"):
            unit = _SPECS[field].unit
            return (
                f"unknown key `{text}`: did you mean `{field}` ({unit})? Fields carry their unit in their "
                f"name; give the value in {unit}."
            )
    close = difflib.get_close_matches(lowered, FIELD_NAMES, n=1, cutoff=0.75)
    if close:
        return f"unknown key `{text}`: did you mean `{close[0]}`?"
    return f"unknown key `{text}`; the known keys are: {', '.join(FIELD_NAMES)}."


def config_from_dict(
    mapping: Mapping[str, Any],
    *,
    base: TriaxialConfig | None = None,
    source: str | os.PathLike | None = None,
) -> TriaxialConfig:
    """Build a configuration from a flat mapping of field names to values, with every check.

    Args:
      mapping: field name → value; fields left out keep their value in ``base``. Units are those in the
        field names (kPa, mm, degrees, kg/m³, N/m).
      base: the configuration to start from; ``None`` means the defaults.
      source: where ``mapping`` came from (a file path), named in the error message.

    Returns:
      the new, valid configuration.

    Raises:
      ConfigError: listing every unknown key (with a suggestion) and every bad value.
    """
    if not isinstance(mapping, Mapping):
        raise ConfigError(
            f"the configuration must be a table of key = value pairs; got {_shown(mapping)}.", source
        )
    errors = [_unknown_key_message(key) for key in mapping if key not in _SPECS]
    values = dict(_DEFAULTS) if base is None else config_to_dict(base)
    values.update({key: value for key, value in mapping.items() if key in _SPECS})
    normalised, field_errors = _check_fields(values)
    errors.extend(field_errors)
    if errors:
        raise ConfigError(errors, source)
    return TriaxialConfig(**normalised)


def config_to_dict(cfg: TriaxialConfig) -> dict[str, Any]:
    """The fields of ``cfg`` as a plain dict, in field order (str, float, int and bool values)."""
    return {key: getattr(cfg, key) for key in FIELD_NAMES}


def with_overrides(cfg: TriaxialConfig, **fields: Any) -> TriaxialConfig:
    """A copy of ``cfg`` with ``fields`` replaced, checked like a file (unknown keys get suggestions).

    Raises:
      ConfigError: listing every unknown key and every bad value.
    """
    return config_from_dict(fields, base=cfg)


def load_config(path: str | os.PathLike) -> TriaxialConfig:
    """Read a configuration from a TOML file (flat, or all under ``[triaxial]``; see the module docstring).

    Args:
      path: the TOML file.

    Returns:
      the configuration; keys left out take their defaults.

    Raises:
      ConfigError: naming the file when it is missing, unreadable or malformed TOML, or mixes the flat and
        the ``[triaxial]`` layouts; otherwise listing every unknown key and bad value.
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as file:
            data = tomllib.load(file)
    except FileNotFoundError:
        raise ConfigError(
            f"configuration file {path!r} does not exist; check the path (relative paths are taken from "
            f"the working directory {os.getcwd()!r})."
        ) from None
    except OSError as error:
        raise ConfigError(f"cannot read configuration file {path!r}: {error.strerror or error}.") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"malformed TOML in {path!r}: {error}. Fix the file's syntax.") from None
    if TABLE_NAME in data:
        table = data[TABLE_NAME]
        if not isinstance(table, dict):
            raise ConfigError(f"`{TABLE_NAME}` must be a table ([{TABLE_NAME}]); got {_shown(table)}.", path)
        others = [key for key in data if key != TABLE_NAME]
        if others:
            raise ConfigError(
                f"keys {', '.join(f'`{key}`' for key in others)} sit outside the [{TABLE_NAME}] table; put "
                f"every key under [{TABLE_NAME}], or remove the [{TABLE_NAME}] header and keep them flat.",
                path,
            )
        data = table
    return config_from_dict(data, source=path)


def _toml_string(text: str) -> str:
    escaped = []
    for char in text:
        if char == "\\":
            escaped.append("\\\\")
        elif char == '"':
            escaped.append('\\"')
        elif ord(char) < 32 or ord(char) == 127:
            escaped.append(f"\\u{ord(char):04x}")
        else:
            escaped.append(char)
    return '"' + "".join(escaped) + '"'


def toml_value(value: Any) -> str:
    """A configuration value as TOML text that reads back to the same value (floats: shortest repr)."""
    if isinstance(value, tuple):
        return (
            "["
            + ", ".join(toml_value(list(item) if isinstance(item, tuple) else item) for item in value)
            + "]"
        )
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)  # shortest repr that reads back exactly; finite by construction
    return _toml_string(value)


def dump_config_toml(cfg: TriaxialConfig, *, table: bool = False) -> str:
    """The configuration as TOML text, one commented line per field, that :func:`load_config` reads back.

    Args:
      cfg: the configuration.
      table: put every key under a ``[triaxial]`` table instead of the top level.

    Returns:
      the TOML text; loading it gives a configuration equal to ``cfg``.
    """
    lines = ["# membrax triaxial test configuration; units are in the key names."]
    if table:
        lines.append(f"[{TABLE_NAME}]")
    for key in FIELD_NAMES:
        lines.append(f"{key} = {toml_value(getattr(cfg, key))}  # {_SPECS[key].describe()}".rstrip())
    return "\n".join(lines) + "\n"


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """Parse ``key=value`` strings (the CLI's ``--set``) into a mapping for :func:`config_from_dict`.

    Each value is read as a TOML value (``20``, ``2.5``, ``true``, ``"run 1"``); a value that is not valid
    TOML is kept as a string, so ``name=run1`` works and ``cell_pressure_kpa=abc`` is reported by
    :func:`config_from_dict` as a wrong type.

    Raises:
      ConfigError: for items without ``=`` or with an empty key.
    """
    result, errors = {}, []
    for item in items:
        key, sep, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key:
            errors.append(f"override {item!r} is not of the form key=value, e.g. cell_pressure_kpa=40.")
            continue
        try:
            parsed = tomllib.loads(f"value = {text}")
            value = parsed["value"] if list(parsed) == ["value"] else text
        except tomllib.TOMLDecodeError:
            value = text
        result[key] = value
    if errors:
        raise ConfigError(errors)
    return result
