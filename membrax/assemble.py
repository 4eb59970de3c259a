"""Assembly: where a configuration becomes a test.

Contract. The configuration object (:class:`membrax.config.TriaxialConfig`) is read here, in
:mod:`membrax.config` and in :mod:`membrax.run`, and nowhere below: :func:`build_test` turns it into a
:class:`~membrax.triaxial.membrane_cell.MembraneTest` (specimen, membrane, platens; nothing compiled),
:func:`build_specimen` into its specimen (the FCC lattice, or a random packing compacted once per set of
the fields that make it and cached on disk), :func:`loading` into the protocol's loading programme,
:func:`damping_params` and :func:`consolidation_tolerance` into the values the step and the stop test
take, :func:`run_settings` into the plain values the executor and the runner take (:class:`RunSettings`:
they never read a configuration). :data:`BATCHED_FIELDS` names the fields members of one compiled batch
may differ in (:func:`structure_key` groups the rest, :func:`grid_members` makes a grid's members),
:func:`common_nodes_around` the one mesh topology of a batch. For derivatives: :func:`parameter_values`
reads the parameters a derivative is taken with respect to, and :func:`thickness_derivative` the
membrane's rest geometry's derivative with respect to its thickness (tests built on either side).
"""

from __future__ import annotations

import dataclasses as pydataclasses
import hashlib
import itertools
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native
from membrax.config import (
    INFLATION_WARNING_RATIO,
    TriaxialConfig,
    characteristic_size_mm,
    config_to_dict,
    inflation_ratio,
    with_overrides,
)
from membrax.defaults import COMPACTION_STRESS, default_consolidation_tolerance
from membrax.errors import ConfigError
from membrax.io.files import atomic_write_file
from membrax.membrane.contact import MembraneContactParams
from membrax.membrane.mesh import rounded_offset_path
from membrax.spheres.compaction import Compaction, random_packing
from membrax.spheres.contact import ContactParams
from membrax.spheres.fcc import Specimen, fcc_specimen, with_imperfection
from membrax.spheres.grading import RandomSpecimen
from membrax.spheres.integrate import DampingParams
from membrax.spheres.particles import particle_mass
from membrax.spheres.periodic import sample_element
from membrax.triaxial.membrane_cell import MembraneTest, membrane_test
from membrax.triaxial.periodic import CRITICAL_STEP_BOUND, PeriodicTest, periodic_test
from membrax.triaxial.periodic_packing import compact_periodic
from membrax.triaxial.protocol import Loading

__all__ = [
    "BATCHED_FIELDS",
    "BOOKKEEPING_FIELDS",
    "RunSettings",
    "build_periodic_test",
    "build_specimen",
    "build_test",
    "common_nodes_around",
    "consolidation_tolerance",
    "damping_params",
    "grid_members",
    "inflation_warning",
    "loading",
    "parameter_values",
    "precision_scope",
    "report_values",
    "run_settings",
    "structure_key",
    "thickness_derivative",
]


#: Configuration fields that may differ between the members of one compiled batch (traced values or
#: host-side budgets). Any other field in a grid splits it into groups run one after another.
BATCHED_FIELDS = frozenset(
    {
        "cell_pressure_kpa",
        "membrane_thickness_mm",
        "membrane_modulus_kpa",
        "membrane_friction_angle_deg",
        "membrane_bending_factor",
        "friction_angle_deg",
        "particle_stiffness_n_m",
        "inertial_number",
        "coarse_inertial_number",
        "target_axial_strain",
        "fine_until_strain",
        "shear_ramp_strain",
        "symmetric_loading",
        "membrane_contact_offset_factor",
        "consolidation_tolerance",
        "consolidation_max_steps",
    }
)


#: Fields that do not enter the simulation (never split a batch, never gridded).
BOOKKEEPING_FIELDS = frozenset({"name", "checkpoint_every_chunks", "vtk_every_steps"})


def build_test(
    config: TriaxialConfig, time_step: float | None = None, nodes_around: int | None = None
) -> MembraneTest:
    """The membrane test of a configuration (specimen, membrane, platens; nothing compiled yet).

    ``time_step`` (s) and ``nodes_around`` (membrane nodes per ring) override the test's own choices, as a
    batch does (:mod:`membrax.sweep`: one Δt and one mesh topology for all its members).
    """
    warning = inflation_warning(config)
    if warning is not None:
        warnings.warn(warning, stacklevel=2)
    specimen = build_specimen(config)
    contact = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    membrane_contact = MembraneContactParams.default(friction_angle_deg=config.membrane_friction_angle_deg)
    return membrane_test(
        specimen,
        cell_pressure=config.cell_pressure,
        membrane_thickness=config.membrane_thickness,
        membrane_modulus=config.membrane_modulus,
        contact_params=contact,
        membrane_contact=membrane_contact,
        damping=damping_params(config),
        density=config.particle_density_kg_m3,
        edges_per_diameter=config.membrane_edges_per_diameter,
        dt_safety=config.dt_safety,
        bending_factor=config.membrane_bending_factor,
        time_step=time_step,
        nodes_around=nodes_around,
        contact_offset_factor=config.membrane_contact_offset_factor,
        stretching_model=config.stretching_model,
        locking_jm=config.membrane_locking_jm,
        contact_model=config.membrane_contact_model,
    )


def damping_params(config: TriaxialConfig) -> DampingParams:
    """The damping of a configuration, for spheres and membrane nodes alike.

    Cundall local damping α = 0.3 (the paper's), or with ``viscous_damping`` the viscous rate that removes
    as much per cycle of a contact oscillator (:meth:`DampingParams.equivalent_viscous`), on the velocities
    ``damping_frame`` names (:data:`membrax.defaults.DAMPING_FRAME`).

    Args:
      config: the configuration.

    Returns:
      its :class:`~membrax.spheres.integrate.DampingParams`.
    """
    if config.viscous_damping:
        mass = float(particle_mass(config.particle_radius, config.particle_density_kg_m3))
        return DampingParams.equivalent_viscous(
            config.particle_stiffness_n_m, mass, frame=config.damping_frame
        )
    return DampingParams.local(0.3, config.damping_frame)


def inflation_warning(config: TriaxialConfig) -> str | None:
    """The warning for a membrane near its inflation limit (:func:`membrax.config.inflation_ratio`), or None.

    Configurations at or above the limit are refused when built; from
    :data:`membrax.config.INFLATION_WARNING_RATIO` of it, runs went non-finite, so the run is warned.
    """
    ratio = inflation_ratio(config_to_dict(config))
    if ratio < INFLATION_WARNING_RATIO:
        return None
    return (
        f"{config.name}: the cell pressure is {ratio:.2f} of the membrane's inflation limit over the windows "
        f"between the particles (membrax.config.inflation_ratio). Every laboratory-grid run completed up to "
        f"{INFLATION_WARNING_RATIO:g} of it; above, runs went non-finite, the membrane drawn into the "
        "specimen's surface windows (docs/model.md). A thicker or stiffer membrane or a lower cell pressure "
        "keeps away from it."
    )


def build_specimen(config: TriaxialConfig) -> Specimen | RandomSpecimen:
    """The configuration's specimen: the FCC lattice, or a random packing compacted in its mould.

    A random packing is compacted once for a given set of the fields that make it (a sweep's members share
    it), to :data:`membrax.defaults.COMPACTION_STRESS`, and kept in this process and on disk
    (:func:`_compaction_cache_path`): a later run of the same specimen loads it instead of compacting again.
    """
    if config.packing == "fcc":
        specimen = fcc_specimen(config.particle_diameter, config.particles_across, config.layers)
        if config.imperfection_fraction > 0.0:
            specimen = with_imperfection(specimen, config.imperfection_fraction, config.imperfection_seed)
        return specimen
    key = tuple(
        getattr(config, name)
        for name in (
            "grading",
            "particle_diameter_mm",
            "specimen_diameter_mm",
            "specimen_height_mm",
            "packing_seed",
            "compaction_friction_deg",
            "particle_density_kg_m3",
            "particle_stiffness_n_m",
            "float64",
        )
    )
    if key not in _RANDOM_SPECIMENS:
        grading = config.particle_grading
        cached = _compaction_cache_path(key)
        if cached.exists():
            try:
                _RANDOM_SPECIMENS[key] = Compaction.load(cached).specimen(grading)
                return _RANDOM_SPECIMENS[key]
            except (OSError, ValueError, KeyError, TypeError):  # a partial or older file: compact afresh
                pass
        compaction = random_packing(
            grading,
            config.specimen_diameter,
            config.specimen_height,
            seed=config.packing_seed,
            target_stress=COMPACTION_STRESS,
            friction_coefficient=config.compaction_friction_coefficient,
            contact_params=ContactParams.paper(
                normal_stiffness=config.particle_stiffness_n_m,
                tangential_stiffness=0.5 * config.particle_stiffness_n_m,
            ),
            density=config.particle_density_kg_m3,
        )
        _RANDOM_SPECIMENS[key] = compaction.specimen(grading)
        if compaction.stress_jump is not None:
            jump = compaction.stress_jump
            warnings.warn(
                f"The random specimen (seed {config.packing_seed}) was compacted to "
                f"{1e-3 * compaction.stress:.3g} kPa instead of {1e-3 * COMPACTION_STRESS:.3g} kPa ± 2 %: "
                f"its relaxed stress jumps from {1e-3 * jump['stress_below']:.3g} to "
                f"{1e-3 * jump['stress_above']:.3g} kPa between neighbouring growths, and the state at rest "
                "nearest the target was kept (membrax.spheres.compaction, 'Stress jumps'). Consolidation "
                "brings it to the cell pressure; another packing_seed gives another packing.",
                stacklevel=2,
            )
        cached.parent.mkdir(parents=True, exist_ok=True)
        partial = cached.with_suffix(f".{os.getpid()}.npz")
        compaction.save(partial)
        os.replace(partial, cached)  # atomic: a concurrent reader sees the whole file or none
    return _RANDOM_SPECIMENS[key]


#: Random specimens compacted in this process, by the fields that make them (:func:`build_specimen`).
_RANDOM_SPECIMENS: dict[tuple, RandomSpecimen] = {}


#: The modules whose code makes a compacted packing in a mould (in membrax/): their text is part of the
#: cache key.
_COMPACTION_SOURCES = tuple(
    f"spheres/{name}"
    for name in (
        "compaction.py",
        "fire.py",
        "mould.py",
        "grading.py",
        "contact.py",
        "_kernels.py",
        "integrate.py",
    )
)
#: The same for a packing made in the periodic cell.
_PERIODIC_COMPACTION_SOURCES = (
    "triaxial/periodic.py",
    "spheres/periodic.py",
    "spheres/neighbors.py",
    "spheres/grading.py",
    "spheres/contact.py",
    "spheres/integrate.py",
)


def _compaction_cache_path(key: tuple, sources: Sequence[str] = _COMPACTION_SOURCES) -> Path:
    """Where a compacted packing of ``key`` is kept between processes.

    ``specimens/`` in the cache folder (``$MEMBRAX_CACHE_DIR`` or ``~/.cache/membrax``), named by a hash of
    the key, the compaction stress and the sources of the compaction (changed code makes a new packing).
    """
    digest = hashlib.sha256(repr((key, COMPACTION_STRESS)).encode())
    for name in sources:
        digest.update((Path(__file__).resolve().parent / name).read_bytes())
    return native.cache_dir() / "specimens" / f"compaction_{digest.hexdigest()[:20]}.npz"


def build_periodic_test(config: TriaxialConfig) -> PeriodicTest:
    """The periodic element test of a configuration (``cell = "periodic"``; nothing compiled yet).

    Its packing: ``periodic_particles`` diameters of the configuration's grading
    (:func:`membrax.spheres.periodic.sample_element`, seed ``packing_seed``) compacted in the periodic cell
    as a mould's are (:func:`membrax.triaxial.periodic_packing.compact_periodic`: from a gas to
    :data:`membrax.defaults.COMPACTION_STRESS` at the compaction friction; frictionless packings overloaded
    and unloaded), once per set of the fields that make it, kept on disk as the mould's. The test holds it
    at the cell pressure with the configuration's contact law, density and damping (the affine frame is
    the cell's own: ``damping_frame`` is not read), its time step ``dt_safety`` × the closed-form bound on
    the critical step (:data:`membrax.triaxial.periodic.CRITICAL_STEP_BOUND`).
    """
    dtype = np.float64 if config.float64 else np.float32
    law = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    fields = (
        "periodic_particles",
        "grading",
        "particle_diameter_mm",
        "packing_seed",
        "compaction_friction_deg",
        "particle_density_kg_m3",
        "particle_stiffness_n_m",
        "float64",
    )
    key = ("periodic", *(getattr(config, name) for name in fields))
    cached = _compaction_cache_path(key, _PERIODIC_COMPACTION_SOURCES)
    packing = None
    if cached.exists():
        try:
            with np.load(cached) as data:
                packing = {name: np.asarray(data[name]) for name in ("fraction", "length", "diameter")}
        except (OSError, ValueError, KeyError):  # a partial or older file: compact afresh
            packing = None
    if packing is None:
        diameters = sample_element(config.particle_grading, config.periodic_particles, config.packing_seed)
        compaction, state, _ = compact_periodic(
            diameters,
            COMPACTION_STRESS,
            friction_coefficient=config.compaction_friction_coefficient,
            seed=config.packing_seed,
            dtype=dtype,
            contact_params=law,  # its friction replaced by the compaction's
            density=config.particle_density_kg_m3,
        )
        packing = {
            "fraction": np.asarray(state.fraction + state.fraction_compensation),
            "length": np.asarray(state.box_length, dtype=float),
            "diameter": 2.0 * np.asarray(compaction.particles.radius, dtype=float),
        }
        cached.parent.mkdir(parents=True, exist_ok=True)
        # Atomic: a concurrent reader sees the whole file or none.
        atomic_write_file(cached, lambda handle: np.savez(handle, **packing))
    return periodic_test(
        jnp.asarray(packing["fraction"], dtype),
        packing["length"],
        0.5 * packing["diameter"],
        config.cell_pressure,
        contact_params=law,
        damping=damping_params(config),
        density=config.particle_density_kg_m3,
        dt_safety=config.dt_safety * CRITICAL_STEP_BOUND,
    )


def loading(config: TriaxialConfig) -> Loading:
    """The loading programme of a configuration (:class:`membrax.triaxial.protocol.Loading`)."""
    return Loading(
        consolidation_max_steps=config.consolidation_max_steps,
        target_axial_strain=config.target_axial_strain,
        inertial_number=config.inertial_number,
        fine_until_strain=config.fine_until_strain,
        ramp_strain=config.shear_ramp_strain,
        record_every_fine=config.record_every_fine,
        record_every_coarse=config.record_every_coarse,
        coarse_inertial_number=config.coarse_inertial_number or None,
        symmetric=config.symmetric_loading,
    )


def consolidation_tolerance(config: TriaxialConfig) -> float:
    """The unbalanced-force ratio that ends consolidation.

    The configuration's, else its cell's default for its precision
    (:func:`membrax.defaults.default_consolidation_tolerance`).
    """
    tolerance = config.consolidation_tolerance_or_none
    if tolerance is None:
        tolerance = default_consolidation_tolerance(config.cell, config.float64)
    return tolerance


@pydataclasses.dataclass(frozen=True)
class RunSettings:
    """What a run takes from its configuration besides the test: plain values (:func:`run_settings`).

    Attributes:
      name: the configuration's name (messages, member names).
      loading: the protocol's loading programme (:func:`loading`).
      consolidation_tolerance: the unbalanced-force ratio that ends consolidation
        (:func:`consolidation_tolerance`).
      chunk_steps: steps per compiled chunk.
      checkpoint_every_chunks: chunks between checkpoints.
      dt_safety: the time step's safety factor (named in a runaway's message).
      float64: consolidation (and, without ``float32_shearing``, everything) in float64.
      float32_shearing: with ``float64``, the shearing in float32.
      provenance: the configuration as written (:func:`membrax.config.config_to_dict`), for results.
      cell: ``"membrane"`` or ``"periodic"`` (:func:`membrax.run.run_test` runs either).
    """

    name: str
    loading: Loading
    consolidation_tolerance: float
    chunk_steps: int
    checkpoint_every_chunks: int
    dt_safety: float
    float64: bool
    float32_shearing: bool
    provenance: dict = pydataclasses.field(compare=False)
    cell: str = "membrane"

    @property
    def precision(self) -> str:
        """``"float64"``, ``"float32"`` or ``"float64 consolidation, float32 shearing"``."""
        if not self.float64:
            return "float32"
        return "float64 consolidation, float32 shearing" if self.float32_shearing else "float64"


def run_settings(config: TriaxialConfig) -> RunSettings:
    """The plain values a run of ``config`` takes besides its test (:class:`RunSettings`)."""
    return RunSettings(
        name=config.name,
        loading=loading(config),
        consolidation_tolerance=consolidation_tolerance(config),
        chunk_steps=config.chunk_steps,
        checkpoint_every_chunks=config.checkpoint_every_chunks,
        dt_safety=config.dt_safety,
        float64=config.float64,
        float32_shearing=config.float32_shearing,
        provenance=config_to_dict(config),
        cell=config.cell,
    )


def report_values(config: TriaxialConfig) -> dict:
    """The values a report quotes about a configuration's test, as a plain dict (reports never read one).

    The fields in the configuration's units (:func:`membrax.config.config_to_dict`), and
    ``particle_radius``, ``particle_diameter`` (m, the configuration's own conversion),
    ``characteristic_size_mm`` (:func:`membrax.config.characteristic_size_mm`: d50, or the diameter) and
    ``precision`` (:attr:`RunSettings.precision`).
    """
    values = config_to_dict(config)
    return {
        **values,
        "particle_radius": config.particle_radius,
        "particle_diameter": config.particle_diameter,
        "characteristic_size_mm": characteristic_size_mm(values),
        "precision": run_settings(config).precision,
    }


def precision_scope(config: TriaxialConfig):
    """The configuration's precision as a context (``jax.enable_x64``), scoped to the calling thread.

    The process's global setting, the entry point's (:mod:`membrax.cli`) or the user's, is never changed.
    """
    return jax.enable_x64(config.float64)


def structure_key(config: TriaxialConfig) -> tuple:
    """The fields that must agree within one batch (everything not batched and not bookkeeping).

    A periodic element's members also share the particle stiffness (it makes their packing and Δt) and
    whether the spheres are frictionless (the rattler rule of z*, a compiled constant).
    """
    key = tuple(
        (field.name, getattr(config, field.name))
        for field in pydataclasses.fields(TriaxialConfig)
        if field.name not in BATCHED_FIELDS and field.name not in BOOKKEEPING_FIELDS
    )
    if config.cell == "periodic":
        key += (
            ("particle_stiffness_n_m", config.particle_stiffness_n_m),
            ("frictionless", config.friction_angle_deg == 0.0),
        )
    return key


def grid_members(base: TriaxialConfig, grid: Mapping[str, Sequence]) -> tuple[dict, list]:
    """Every combination of ``grid`` applied to ``base``, in row-major order (the last field fastest).

    Returns:
      (coordinates: {field: tuple of the field's values, converted}, members: list of
      (index tuple, TriaxialConfig named ``{base.name}_{k}``)).

    Raises:
      ConfigError: an unknown or bookkeeping field, a repeated value, or a value out of range (the
        configuration's own message).
    """
    if not grid:
        raise ConfigError("the grid is empty; give at least one field, e.g. cell_pressure_kpa=10,40,100.")
    fields = {field.name for field in pydataclasses.fields(TriaxialConfig)}
    coordinates: dict[str, tuple] = {}
    for key, values in grid.items():
        if key not in fields or key in BOOKKEEPING_FIELDS:
            raise ConfigError(
                f"grid field {key!r} is not a simulation field of TriaxialConfig; choose from "
                f"{sorted(fields - BOOKKEEPING_FIELDS)}."
            )
        converted = tuple(getattr(with_overrides(base, **{key: value}), key) for value in values)
        if len(set(converted)) != len(converted):
            raise ConfigError(f"grid field {key!r} repeats a value ({list(values)}); give distinct values.")
        coordinates[key] = converted
    members = []
    for k, index in enumerate(itertools.product(*(range(len(v)) for v in coordinates.values()))):
        overrides = {key: coordinates[key][i] for key, i in zip(coordinates, index, strict=True)}
        members.append((index, with_overrides(base, name=f"{base.name}_{k}", **overrides)))
    return coordinates, members


def common_nodes_around(configs: Sequence[TriaxialConfig]) -> int:
    """n_θ for all members: round(mean membrane perimeter / edge length) over the members' thicknesses."""
    config = configs[0]
    if config.packing == "random":
        diameter = build_specimen(config).diameter
        perimeters = [
            math.pi * (diameter + c.membrane_contact_offset_factor * c.membrane_thickness) for c in configs
        ]
        return max(3, round(float(np.mean(perimeters)) / config.membrane_edge_length))
    specimen = fcc_specimen(config.particle_diameter, config.particles_across, config.layers)
    perimeters = [
        rounded_offset_path(
            specimen.outline_vertices,
            0.5 * c.membrane_contact_offset_factor * c.membrane_thickness,
            config.particle_radius,
        )[1]
        for c in configs
    ]
    return max(3, round(float(np.mean(perimeters)) / config.membrane_edge_length))


def parameter_values(config: TriaxialConfig, names: Sequence[str]) -> np.ndarray:
    """The configuration's values of the fields ``names``, in its units (kPa, mm, degrees, N/m), float64."""
    return np.asarray([float(getattr(config, name)) for name in names])


def thickness_derivative(
    config: TriaxialConfig, test: MembraneTest, fields: Sequence[str], relative_step: float = 1e-4
) -> dict:
    """d(field)/d t_m per mm of the membrane mesh's arrays ``fields``, by central differences.

    The configuration's test is built again with the membrane thickness t_m ± h, h = ``relative_step`` ×
    t_m, at ``test``'s time step and node ring (so the meshes have one topology), and each field is
    differenced: (f(t_m + h) − f(t_m − h)) / 2h. The clamp rings follow from ``reference_position``'s
    ring rows.
    """
    around = int(np.asarray(test.mesh.bottom_ring).size)
    thickness = config.membrane_thickness_mm
    h = relative_step * thickness
    meshes = [
        build_test(
            pydataclasses.replace(config, membrane_thickness_mm=thickness + sign * h),
            time_step=test.dt,
            nodes_around=around,
        ).mesh
        for sign in (1.0, -1.0)
    ]
    return {name: (getattr(meshes[0], name) - getattr(meshes[1], name)) / (2.0 * h) for name in fields}
