"""The runner: a batch of membrane tests from configurations, through consolidation and shearing.

Contract. Every membrane test that runs to a results folder goes through here, alone or in a grid: a single
test (:func:`membrax.run.run_test`) is a batch of one, a sweep (:func:`membrax.sweep.run_sweep`) runs its
grid as batches. :func:`build_batch` builds the members of one compiled batch (:class:`BatchedTest`:
states stacked on a member axis, one Δt, one mesh topology) and :func:`run_group` takes them through the
protocol's stage sequence (:data:`membrax.triaxial.protocol.PHASES`, each member's steps and record
intervals from :meth:`~membrax.triaxial.protocol.StagedTest.phase_plan` of its :func:`loading`):

- ``consolidation``: the ram servo on, until each member's own stop test holds
  (:meth:`membrax.triaxial.membrane_cell.MembraneTest.is_consolidated`) or it reaches
  ``consolidation_max_steps``;
- ``shear_fine`` and ``shear_coarse``: drained shearing at the strain rate of ``inertial_number``
  (ramped from rest), recorded every ``record_every_fine`` steps below ``fine_until_strain`` and every
  ``record_every_coarse`` steps after, to ``target_axial_strain``; after ``fine_until_strain`` at the
  rate of ``coarse_inertial_number`` where it is set (the speed changed linearly over
  ``shear_ramp_strain``).

The loop (:func:`membrax.driver.drive`) reallocates tables and checks error bits; :func:`run_group` adds
what a long run needs: a progress bar per phase, a checkpoint (stacked state, records so far, budgets)
every ``checkpoint_every_chunks`` chunks and at each phase's end, ``resume`` continuing to results
identical to an uninterrupted run, a runaway-energy stop (kinetic energy above
:data:`RUNAWAY_KINETIC_FRACTION` × σc V₀) that raises :class:`RunError` with the records so far, and an
``after_chunk`` hook (VTK snapshots). :func:`results_datasets` turns a member's records into the shearing
and consolidation datasets (strains and areas counted from the start of shearing).

Batching. Members that differ only in :data:`BATCHED_FIELDS` (traced parameters) form one batch; each
chunk of steps is **one** compiled call, ``lax.map`` over the members on a CPU (each member's arrays stay
in cache; :mod:`membrax.batch`) or ``vmap`` on a GPU, sharded over devices with ``jax.shard_map``. Each
member carries a step budget for the current phase; a record block of a member whose budget is spent is
skipped (``lax.cond``: no work on a CPU) and its state frozen, so every member takes exactly the steps it
would take alone with the same Δt and mesh (tests/test_sweep.py checks batched = alone).
"""

from __future__ import annotations

import contextlib
import dataclasses as pydataclasses
import hashlib
import itertools
import math
import os
import platform
import time
import types
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax_md.partition import NeighborListFormat

from membrax import __version__, native, theory
from membrax.batch import stack
from membrax.config import INFLATION_WARNING_RATIO, TriaxialConfig, config_to_dict, inflation_ratio
from membrax.defaults import COMPACTION_STRESS, default_consolidation_tolerance
from membrax.driver import advance, drive, record_blocks
from membrax.errors import OVERFLOWS, ErrorCode, RunError, SimulationError, describe
from membrax.io import load_checkpoint, read_checkpoint_host, records_to_dataset, save_checkpoint
from membrax.membrane.contact import MembraneContactParams
from membrax.membrane.coupled import (
    CandidateCapacities,
    candidate_capacities,
    grow_candidates,
    grown_candidate_capacities,
)
from membrax.membrane.measure import right_cylinder_stresses
from membrax.membrane.mesh import rounded_offset_path
from membrax.spheres.compaction import Compaction, random_packing
from membrax.spheres.contact import ContactParams
from membrax.spheres.integrate import DampingParams
from membrax.spheres.neighbors import remap_pair_history
from membrax.spheres.packing import Specimen, fcc_specimen, particle_mass, with_imperfection
from membrax.spheres.random_packing import RandomSpecimen, mass_fractions
from membrax.triaxial import analysis
from membrax.triaxial.membrane_cell import MembraneTest, membrane_test
from membrax.triaxial.protocol import CONSOLIDATION_RECORD_EVERY, PHASES, Loading

__all__ = [
    "BATCHED_FIELDS",
    "BOOKKEEPING_FIELDS",
    "CHECKPOINT_NAME",
    "RUNAWAY_KINETIC_FRACTION",
    "BatchedTest",
    "balanced_order",
    "build_batch",
    "build_test",
    "consolidation_tolerance",
    "damping_params",
    "loading",
    "join_records",
    "member_chunk_records",
    "plan_members",
    "rebase_to_shear_start",
    "results_datasets",
    "run_group",
    "run_metadata",
    "structure_key",
]

#: Kinetic energy above this fraction of σc V₀ stops the run (a quasi-static test stays below 1e-4).
RUNAWAY_KINETIC_FRACTION = 0.05
CHECKPOINT_NAME = "checkpoint.npz"


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
#: Mesh arrays that depend on the thickness (the rest geometry); the rest of the mesh is shared.
GEOMETRY_FIELDS = (
    "reference_position",
    "reference_inverse",
    "reference_area",
    "rest_dihedral",
    "edge_weight",
)
#: Records a single test's progress bar reads (axial strain and the paper's §4.3 stresses).
_PROGRESS = (
    "axial_strain",
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
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
    :data:`membrax.config.INFLATION_WARNING_RATIO` of it, FCC runs went non-finite, so the run is warned.
    """
    ratio = inflation_ratio(config_to_dict(config))
    if ratio < INFLATION_WARNING_RATIO:
        return None
    return (
        f"{config.name}: the cell pressure is {ratio:.2f} of the membrane's inflation limit over the windows "
        f"between the particles (membrax.config.inflation_ratio); FCC runs went non-finite from "
        f"{INFLATION_WARNING_RATIO:g}–1 of it, the membrane ballooning into the specimen. A thicker or "
        "stiffer membrane or a lower cell pressure keeps away from it."
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


#: The modules whose code makes a compacted packing (membrax/spheres/): their text is part of the cache key.
_COMPACTION_SOURCES = ("compaction.py", "random_packing.py", "contact.py", "integrate.py")


def _compaction_cache_path(key: tuple) -> Path:
    """Where a compacted packing of ``key`` is kept between processes.

    ``specimens/`` in the cache folder (``$MEMBRAX_CACHE_DIR`` or ``~/.cache/membrax``), named by a hash of
    the key, the compaction stress and the sources of the compaction (changed code makes a new packing).
    """
    digest = hashlib.sha256(repr((key, COMPACTION_STRESS)).encode())
    for name in _COMPACTION_SOURCES:
        digest.update((Path(__file__).resolve().parent / "spheres" / name).read_bytes())
    return native.cache_dir() / "specimens" / f"compaction_{digest.hexdigest()[:20]}.npz"


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
    )


def consolidation_tolerance(config: TriaxialConfig) -> float:
    """The unbalanced-force ratio that ends consolidation.

    The configuration's, else the membrane cell's default for its precision
    (:func:`membrax.defaults.default_consolidation_tolerance`).
    """
    tolerance = config.consolidation_tolerance_or_none
    if tolerance is None:
        tolerance = default_consolidation_tolerance("membrane", config.float64)
    return tolerance


def join_records(chunks: list[dict], axis: int = 0) -> dict:
    """Join chunk dicts of records along their time axis (0 for one member, 1 for stacked members)."""
    if not chunks:
        return {}
    return {name: np.concatenate([chunk[name] for chunk in chunks], axis=axis) for name in chunks[0]}


def rebase_to_shear_start(records: dict, start: dict) -> dict:
    """Strains, area and stresses counted from the start of shearing (the paper's Table 3 and figures).

    The area A = A₀ (1 − ε_v)/(1 − ε_a) starts from the platen area A₀ at the start of shearing
    (:func:`membrax.membrane.measure.right_cylinder_stresses`), so at ε_a = 0 the external σ1 is the ram
    servo's σc. The consolidation stage's strains (from the as-built specimen, the membrane's penetration into
    the voids included) are kept in their own columns, ``consolidation_axial_strain`` and
    ``consolidation_volumetric_strain``, the same in every row.
    """
    out = dict(records)
    height, volume = np.asarray(records["height"]), np.asarray(records["volume"])
    height0, volume0 = float(start["height"]), float(start["volume"])
    out["consolidation_axial_strain"] = np.full_like(height, float(np.ravel(records["axial_strain"])[0]))
    out["consolidation_volumetric_strain"] = np.full_like(
        height, float(np.ravel(records["volumetric_strain"])[0])
    )
    out["axial_strain"] = (height0 - height) / height0
    out["volumetric_strain"] = (volume0 - volume) / volume0
    out["radial_strain"] = np.asarray(theory.radial_strain(out["axial_strain"], out["volumetric_strain"]))
    area, external_axial, internal_axial, internal_radial = right_cylinder_stresses(
        np.asarray(records["ram_force"]),
        np.asarray(records["received_axial_force"]),
        np.asarray(records["membrane_radial_force"]) + np.asarray(records["clamp_radial_force"]),
        height,
        volume,
        height0,
        volume0,
        float(start["platen_area"]),
    )
    out.update(
        platen_area=area,
        external_axial_stress=external_axial,
        internal_axial_stress=internal_axial,
        internal_radial_stress=internal_radial,
    )
    return out


def structure_key(config: TriaxialConfig) -> tuple:
    """The fields that must agree within one batch (everything not batched and not bookkeeping)."""
    return tuple(
        (field.name, getattr(config, field.name))
        for field in pydataclasses.fields(TriaxialConfig)
        if field.name not in BATCHED_FIELDS and field.name not in BOOKKEEPING_FIELDS
    )


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


def _members(tree, count: int) -> list:
    """The first ``count`` members of a stacked pytree, as host (numpy) pytrees.

    The stacked arrays are copied to the host first, shard by shard: indexing a member out of an array
    sharded over devices would compile an SPMD gather with a cross-device all-reduce, which waits for every
    device, so a device still busy with its part of a chunk (launched asynchronously) stalls it, and XLA ends
    the process after 40 s (issue 46). Host copies need no collective.
    """
    host = jax.device_get(tree)
    return [jax.tree_util.tree_map(lambda leaf, b=b: np.asarray(leaf)[b], host) for b in range(count)]


def _shared_neighbors(frame, positions: Sequence, capacity: int = 0, cell_capacity: int = 0) -> list:
    """One neighbour list per member with identical static structure (capacities), so they stack.

    jax-md keeps the list's capacity and cell-list capacity as static fields (and a fresh cell-list
    closure per allocation), so lists allocated separately do not stack. Every member's list is rebuilt
    here from one template with the largest capacities needed (at least ``capacity``/``cell_capacity``):
    the template's reference position is moved away, which makes ``update`` rebuild at the member's
    positions. Real pairs come out in the same order as an allocation of their own; only the padding differs.
    """
    positions = [jnp.asarray(p) for p in positions]
    while True:
        allocated = [frame.allocate(p) for p in positions]
        occupancy = max([capacity] + [int(nl.max_occupancy) for nl in allocated])
        cells = max([cell_capacity] + [int(nl.cell_list_capacity or 0) for nl in allocated])
        template = allocated[0]
        if cells and template.format is not NeighborListFormat.Dense:
            # A rebuild's table holds at most the cell list's candidates, N · 3^d · cell capacity
            # (jax-md truncates to the smaller), so a larger capacity than that cannot be asked for.
            count, dimension = positions[0].shape
            occupancy = min(occupancy, count * 3**dimension * cells)
        # The template's pair table must have the capacity it claims: update's rebuild and its no-rebuild
        # branch return tables of those two sizes, which lax.cond needs equal.
        padding = occupancy - template.idx.shape[-1]
        idx = jnp.pad(template.idx, ((0, 0), (0, max(padding, 0))), constant_values=positions[0].shape[0])
        template = template.set(idx=idx, max_occupancy=occupancy, cell_list_capacity=cells or None)
        away = jnp.full_like(template.reference_position, 1e6)
        lists = [frame.update(p, template.set(reference_position=away)) for p in positions]
        if not any(bool(nl.did_buffer_overflow) for nl in lists):
            return lists
        capacity, cell_capacity = math.ceil(1.5 * occupancy), math.ceil(1.5 * max(cells, 1))


# ----------------------------------------------------------------------------------------------------------
# The batched test
# ----------------------------------------------------------------------------------------------------------


@pydataclasses.dataclass
class BatchedTest:
    """Members of one compiled batch (built by :func:`build_batch`); arrays stacked on a member axis.

    Attributes:
      configs: the members' configurations.
      tests: the members' :class:`MembraneTest` (built with the common Δt and n_θ: each one alone runs the
        same steps as its member of the batch).
      dt: the common time step, s.
      nodes_around: the common n_θ.
      num_devices: devices the member axis is sharded over.
      mode: ``"map"`` (``lax.map``, CPU) or ``"vmap"`` (GPU).
      params: stacked :class:`membrax.membrane.coupled.CoupledParams`, padded to a multiple of
      ``num_devices``. members: stacked per-member constants: the mesh's rest geometry and the initial inner
      volume. initial_state: stacked states at the start of consolidation (servo on).
      order: member b of the batch is ``configs[order[b]]`` of :func:`build_batch`'s argument.
    """

    configs: list
    tests: list
    dt: float
    nodes_around: int
    num_devices: int
    mode: str
    params: object
    members: dict
    initial_state: object
    order: list = pydataclasses.field(default_factory=list)
    reallocations: int = 0
    #: member → {"error", "step", "phase"} of the members :func:`run_group` froze (``isolate_failures``).
    failures: dict = pydataclasses.field(default_factory=dict)

    def __post_init__(self):
        self._chunk = jax.jit(
            self._chunk_impl,
            static_argnames=("num_records", "record_every"),
            compiler_options=native.compiler_options(),
        )

    @property
    def num_members(self) -> int:
        """B, the real members (padding excluded)."""
        return len(self.tests)

    @property
    def num_padded(self) -> int:
        """Members including the frozen padding copies."""
        return int(np.asarray(self.params.membrane.thickness).shape[0])

    def _member_chunk(self, state, params, member, left, num_records: int, record_every: int):
        template = self.tests[0]
        mesh = template.mesh.set(**{name: member[name] for name in GEOMETRY_FIELDS})
        step = template.make_step(mesh)
        record = template.make_record(mesh, member["initial_volume"])

        def block(carry):
            s, budget = carry
            active = budget > 0
            # A spent budget freezes the member: lax.cond skips its work under lax.map.
            s = jax.lax.cond(active, lambda x: advance(step, x, params, record_every), lambda x: x, s)
            budget = jnp.where(active, budget - record_every, budget)
            return (s, budget), (record(s, params), active)

        (state, left), (records, valid) = record_blocks(block, (state, left), num_records)
        return state, left, records, valid

    def _chunk_impl(self, states, params, members, left, num_records: int, record_every: int):
        def one(state, param, member, budget):
            return self._member_chunk(state, param, member, budget, num_records, record_every)

        if self.mode == "vmap":
            batched = jax.vmap(one)
        else:

            def batched(*args):
                return jax.lax.map(lambda xs: one(*xs), args)

        if self.num_devices > 1:
            devices = np.asarray(jax.local_devices()[: self.num_devices])
            spec = jax.sharding.PartitionSpec("members")
            batched = jax.shard_map(
                batched,
                mesh=jax.sharding.Mesh(devices, ("members",)),
                in_specs=spec,
                out_specs=spec,
                check_vma=False,
            )
        return batched(states, params, members, left)

    def restack(self, states: list):
        """Stack per-member states (real members) back, padding with frozen copies of member 0."""
        padded = list(states) + [states[0]] * (self.num_padded - len(states))
        return stack(padded)

    def unstack(self, states) -> list:
        """The real members' states of a stacked state."""
        return _members(states, self.num_members)

    def _grow(self, states, error, overflowed):
        """Reallocate every member's neighbour list and/or candidate table with one larger capacity."""
        members = _members(states, self.num_padded)
        frame = self.tests[0].runner.neighbor_frame
        particles = self.tests[0].particles
        if np.any(error & ErrorCode.NEIGHBOR_OVERFLOW):
            old = states.dem.neighbors
            lists = _shared_neighbors(
                frame,
                [m.dem.position for m in members],
                capacity=math.ceil(1.5 * old.max_occupancy),
                cell_capacity=int(old.cell_list_capacity or 0),
            )
            members = [
                m.set(
                    dem=m.dem.set(
                        neighbors=nl,
                        pair_spring=remap_pair_history(
                            m.dem.neighbors.idx, nl.idx, m.dem.pair_spring, particles.num_particles
                        ),
                    )
                )
                for m, nl in zip(members, lists, strict=True)
            ]
        if np.any(error & ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW):
            capacities = grown_candidate_capacities(states.membrane.candidates, overflowed)
            thickness = np.asarray(self.params.membrane.contact_thickness)
            members = [grow_candidates(m, particles, capacities, thickness[b]) for b, m in enumerate(members)]
        self.reallocations += 1
        return stack(members)

    def run_phase(
        self,
        states,
        budgets,
        chunk_steps: int,
        record_every: int,
        stop_fn: Callable | None = None,
        on_chunk: Callable | None = None,
        on_failure: Callable | None = None,
    ):
        """Advance every member until its step budget is spent (or ``stop_fn`` ends it).

        Args:
          states: stacked states (padded).
          budgets: (B,) steps each real member still takes in this phase (rounded up to whole records).
          chunk_steps: steps per compiled chunk (rounded to whole records).
          record_every: steps between records.
          stop_fn: ``stop_fn(member, records) -> bool`` after each chunk for each member that advanced in
            it (``records``: that member's records of the chunk, a namespace of arrays); True spends its
            budget (the consolidation stop test).
          on_chunk: ``on_chunk(states, chunk, budgets)`` after each accepted chunk, ``chunk`` a dict of
            stacked (B, T, …) arrays of the real members plus ``valid`` (B, T); it may return members to
            stop now (their budgets end).
          on_failure: failure isolation: ``on_failure(member, names, step)`` (the :class:`ErrorCode` names
            joined by ``|``) for a member whose error
            bits (other than an overflow) are set after a chunk (``step``: the chunk's end); its budget
            ends and the chunk is run again without it, so it stays at its state and records before that
            chunk, and the others go on. None: the first such member raises.

        Returns:
          (states, budgets).

        Raises:
          SimulationError: a member's error bits other than an overflow, naming the member.
        """
        padded = np.zeros(self.num_padded, dtype=np.int64)
        padded[: self.num_members] = np.asarray(budgets)
        num = self.num_members
        # Every error bit of the real members; only the overflows of the padding copies (they grow too).
        real_bits = np.where(np.arange(self.num_padded) < num, -1, int(OVERFLOWS))

        def chunk(states, left, num_records):
            return self._chunk(
                states,
                self.params,
                self.members,
                jnp.asarray(left),
                num_records=num_records,
                record_every=record_every,
            )

        def fail(error, new, states):
            bad = int(np.flatnonzero(error[:num])[0])
            return SimulationError(
                f"member {bad} ({self.configs[bad].name}) stopped in the chunk ending at step "
                f"{int(np.asarray(new.dem.step)[bad])}: " + "; ".join(describe(error[bad])),
                state=states,
            )

        def accept(states, records, valid, left):
            valid = np.array(valid)[:num]  # writable: a failed member's records are masked
            chunk = {
                field.name: np.asarray(getattr(records, field.name))[:num]
                for field in pydataclasses.fields(records)
            }
            chunk["valid"] = valid
            stopped = []
            if stop_fn is not None:
                for b in np.flatnonzero(valid.any(axis=1)):
                    mine = types.SimpleNamespace(
                        **{k: v[b][valid[b]] for k, v in chunk.items() if k != "valid"}
                    )
                    if left[b] > 0 and stop_fn(int(b), mine):
                        stopped.append(int(b))
            if on_chunk is not None:
                remaining = left[:num].copy()
                remaining[stopped] = 0
                stopped.extend(int(b) for b in on_chunk(states, chunk, remaining) or ())
            return stopped

        def isolate(error, new, left):
            steps = np.asarray(new.dem.step)
            left = np.asarray(left).copy()
            for b in np.flatnonzero(error[:num]):
                left[b] = 0
                names = [code.name for code in ErrorCode if int(error[b]) & code]
                on_failure(int(b), "|".join(names), int(steps[b]))
            return left

        states, left = drive(
            chunk,
            states,
            padded,
            record_every,
            chunk_steps,
            # Overflows anywhere (padding included) grow every member's tables; other errors of real members.
            errors=lambda s: np.asarray(s.dem.error) & real_bits,
            grow=lambda s, error, overflowed: self._grow(s, error, overflowed.membrane.candidates),
            fail=fail,
            accept=accept,
            isolate=None if on_failure is None else isolate,
        )
        return states, left[:num]


def describe_failure(failure: dict) -> str:
    """A failed member's record as one line: the error's name, the phase and the step."""
    return f"{failure['error']} in {failure['phase']} (chunk ending at step {failure['step']})"


def balanced_order(work: Sequence[float], num_devices: int) -> list[int]:
    """An order of the members whose contiguous device shares carry about equal work.

    ``shard_map`` gives device d the d-th contiguous block of the (padded) member axis, and a chunk lasts
    as long as its busiest device. Low-pressure members shear for the most steps (ε̇ ∝ √σc at a fixed
    inertial number), so grid order would load one device with them. Greedy longest-first (each member,
    heaviest first, to the least-loaded block with a free slot; the last block holds the padding), then
    swaps between the busiest block and another while they lower the busiest load.

    Args:
      work: each member's expected steps.
      num_devices: devices the member axis is split over.

    Returns:
      Member indices in batch order (a permutation of ``range(len(work))``).
    """
    count = len(work)
    per_device = math.ceil(count / num_devices)
    free = [per_device] * num_devices
    free[-1] -= per_device * num_devices - count
    blocks: list[list[int]] = [[] for _ in range(num_devices)]

    def load(block):
        return sum(work[i] for i in block)

    for b in sorted(range(count), key=lambda i: (-work[i], i)):
        d = min((d for d in range(num_devices) if free[d] > 0), key=lambda d: (load(blocks[d]), d))
        blocks[d].append(b)
        free[d] -= 1
    improved = True
    while improved:
        improved = False
        busiest = max(range(num_devices), key=lambda d: load(blocks[d]))
        for d in range(num_devices):
            for i, j in itertools.product(range(len(blocks[busiest])), range(len(blocks[d]))):
                a, b = blocks[busiest][i], blocks[d][j]
                gain = work[a] - work[b]
                if gain > 0 and load(blocks[d]) + gain < load(blocks[busiest]):
                    blocks[busiest][i], blocks[d][j] = b, a
                    improved = True
                    break
            if improved:
                break
    return [b for block in blocks for b in sorted(block)]


def plan_members(
    configs: Sequence[TriaxialConfig], time_step: float | None = None, nodes_around: int | None = None
) -> tuple[list, float, int, list[int]]:
    """The members' tests on a common Δt and n_θ, and each member's expected steps (its work).

    Args:
      configs: the members' configurations (one structure).
      time_step: the common Δt, s (default: the smallest of the members' own).
      nodes_around: the common n_θ (default: :func:`common_nodes_around`).

    Returns:
      (tests, Δt, n_θ, work): shear steps are planned; consolidation stops when its test holds (unknown
      beforehand, about alike for all members), so every member is charged two chunks of it.
    """
    nodes_around = common_nodes_around(configs) if nodes_around is None else int(nodes_around)
    tests = [build_test(c, time_step, nodes_around) for c in configs]
    dt = min(t.dt for t in tests)
    tests = [
        t if t.dt == dt else build_test(c, time_step=dt, nodes_around=nodes_around)
        for t, c in zip(tests, configs, strict=True)
    ]
    plans = [t.phase_plan(loading(c)) for c, t in zip(configs, tests, strict=True)]
    work = [
        min(c.consolidation_max_steps, 2 * c.chunk_steps) + sum(plan[phase][0] for phase in PHASES[1:])
        for c, plan in zip(configs, plans, strict=True)
    ]
    return tests, float(dt), nodes_around, work


def build_batch(
    configs: Sequence[TriaxialConfig],
    num_devices: int | None = None,
    mode: str | None = None,
    order: Sequence[int] | None = None,
    time_step: float | None = None,
    nodes_around: int | None = None,
) -> BatchedTest:
    """Build the members of one batch (same structure, :data:`BATCHED_FIELDS` may differ).

    Args:
      configs: the members' configurations.
      num_devices: devices to shard the member axis over (default: every local device of the default
        backend).
      mode: ``"map"`` or ``"vmap"`` (default: ``"vmap"`` on a GPU, ``"map"`` otherwise).
      order: the members' order on the batch axis, indices into ``configs`` (default
        :func:`balanced_order` of each member's planned shear steps plus two chunks of consolidation).
        The batch's ``configs`` and ``tests`` are in this order, and ``BatchedTest.order`` keeps it.
      time_step: the common Δt, s (default: the smallest of the members' own).
      nodes_around: the common n_θ (default: :func:`common_nodes_around`).

    Raises:
      ValueError: no members, members that differ in a field outside :data:`BATCHED_FIELDS`, a bad mode
        or device count.
    """
    configs = list(configs)
    if not configs:
        raise ValueError("no members to batch; give at least one configuration.")
    keys = {structure_key(c) for c in configs}
    if len(keys) > 1:
        first = dict(structure_key(configs[0]))
        differing = sorted({name for key in keys for name, value in key if value != first[name]})
        raise ValueError(
            f"members differ in {differing}, which cannot vary within one batch; batch only members that "
            f"differ in {sorted(BATCHED_FIELDS)} (run_sweep groups the rest)."
        )
    mode = mode or ("vmap" if jax.default_backend() == "gpu" else "map")
    if mode not in ("map", "vmap"):
        raise ValueError(f"mode = {mode!r}; give 'map' (CPU) or 'vmap' (GPU).")
    available = jax.local_device_count()
    num_devices = available if num_devices is None else int(num_devices)
    if not 1 <= num_devices <= available:
        raise ValueError(f"num_devices = {num_devices}; this process has {available} device(s).")
    num_devices = min(num_devices, len(configs))
    tests, dt, nodes_around, work = plan_members(configs, time_step, nodes_around)
    if order is None:
        order = balanced_order(work, num_devices)
    order = [int(i) for i in order]
    if sorted(order) != list(range(len(configs))):
        raise ValueError(f"order = {order}; give a permutation of range({len(configs)}).")
    configs, tests = [configs[i] for i in order], [tests[i] for i in order]
    states = [t.start_consolidation(t.initial_state) for t in tests]
    lists = _shared_neighbors(tests[0].runner.neighbor_frame, [s.dem.position for s in states])
    states = [s.set(dem=s.dem.set(neighbors=nl)) for s, nl in zip(states, lists, strict=True)]
    num_padded = num_devices * math.ceil(len(tests) / num_devices)
    slots = list(range(len(tests))) + [0] * (num_padded - len(tests))
    members = [
        {
            **{name: getattr(tests[b].mesh, name) for name in GEOMETRY_FIELDS},
            "initial_volume": jnp.asarray(tests[b].initial_volume, tests[b].mesh.reference_area.dtype),
        }
        for b in slots
    ]
    return BatchedTest(
        configs=configs,
        tests=tests,
        dt=float(dt),
        nodes_around=nodes_around,
        num_devices=num_devices,
        mode=mode,
        params=stack([tests[b].params for b in slots]),
        members=stack(members),
        initial_state=stack([states[b] for b in slots]),
        order=order,
    )


# ----------------------------------------------------------------------------------------------------------
# Running a group (progress, checkpoints, resume)
# ----------------------------------------------------------------------------------------------------------


def _capacities(states) -> dict:
    nl = states.dem.neighbors
    candidates = states.membrane.candidates
    return {
        "neighbor_pairs": int(nl.max_occupancy),
        "cell_capacity": int(nl.cell_list_capacity or 0),
        **dict(zip(_NODE_CAPACITY_KEYS, candidate_capacities(candidates), strict=True)),
    }


# The checkpoint's names of the node candidate table's capacities (K, M, C: CandidateCapacities).
_NODE_CAPACITY_KEYS = ("node_candidates", "sphere_slots", "membrane_cell_spheres")


def _node_capacities(capacities: dict) -> CandidateCapacities:
    return CandidateCapacities(*(capacities[key] for key in _NODE_CAPACITY_KEYS))


def _template(batch: BatchedTest, capacities: dict):
    """The batch's initial state grown to a checkpoint's capacities (the loader's shape template)."""
    states = batch.initial_state
    if _capacities(states) == capacities:
        return states
    members = _members(states, batch.num_padded)
    thickness = np.asarray(batch.params.membrane.contact_thickness)
    particles = batch.tests[0].particles
    members = [
        grow_candidates(m, particles, _node_capacities(capacities), thickness[b])
        for b, m in enumerate(members)
    ]
    lists = _shared_neighbors(
        batch.tests[0].runner.neighbor_frame,
        [m.dem.position for m in members],
        capacities["neighbor_pairs"],
        capacities["cell_capacity"],
    )
    members = [
        m.set(dem=m.dem.set(neighbors=nl, pair_spring=jnp.zeros((nl.idx.shape[1], 3), m.dem.position.dtype)))
        for m, nl in zip(members, lists, strict=True)
    ]
    return stack(members)


def float32_batch(batch: BatchedTest) -> BatchedTest:
    """The batch rebuilt in float32 (call inside ``jax.enable_x64(False)``), for ``float32_shearing``.

    Same configurations, order, Δt, n_θ, devices and mode: only the arrays' precision differs, so a state
    of ``batch`` carried over by :func:`cast_state` goes on with the same steps.
    """
    shear = build_batch(
        batch.configs,
        batch.num_devices,
        batch.mode,
        order=list(range(batch.num_members)),
        time_step=batch.dt,
        nodes_around=batch.nodes_around,
    )
    shear.order = list(batch.order)
    shear.failures = batch.failures
    return shear


def cast_state(state, like):
    """``state``'s values in the dtypes (and static structure) of ``like``, a template of the same shapes.

    Where a body keeps its position as a compensated pair (``position`` + ``position_compensation``:
    spheres, walls, membrane nodes), the float64 sum is split anew into a float32 high part and the
    rounding residual, so the narrower pair still carries the position to about float64 resolution.
    """

    def split(body, like_body):
        dtype = np.dtype(like_body.position.dtype)
        if np.dtype(body.position.dtype) == dtype:
            return body
        exact = np.asarray(body.position, np.float64) + np.asarray(body.position_compensation, np.float64)
        high = exact.astype(dtype)
        return body.set(position=high.astype(np.float64), position_compensation=exact - high)

    walls = split(state.dem.walls, like.dem.walls)
    dem = split(state.dem, like.dem).set(walls=walls)
    state = state.set(dem=dem, membrane=split(state.membrane, like.membrane))
    leaves = jax.tree_util.tree_leaves(state)
    like_leaves, structure = jax.tree_util.tree_flatten(like)
    if len(leaves) != len(like_leaves):
        raise ValueError(f"cast_state: {len(leaves)} leaves against the template's {len(like_leaves)}.")
    cast = []
    for value, template in zip(leaves, like_leaves, strict=True):
        if np.shape(value) != np.shape(template):
            raise ValueError(
                f"cast_state: shape {np.shape(value)} against the template's {np.shape(template)}."
            )
        dtype = getattr(template, "dtype", None)
        cast.append(value if dtype is None else jnp.asarray(np.asarray(value).astype(dtype)))
    return jax.tree_util.tree_unflatten(structure, cast)


def member_chunk_records(records: dict, b: int) -> dict:
    """Member b's records of every phase, as :func:`membrax.run.results_datasets` takes them."""
    out = {}
    for phase in PHASES:
        joined = join_records(records[phase], axis=1)
        if not joined:
            out[phase] = []
            continue
        valid = joined["valid"][b]
        if not valid.any():  # a member that never reached this phase (it failed before)
            out[phase] = []
            continue
        out[phase] = [{name: value[b][valid] for name, value in joined.items() if name != "valid"}]
    return out


def _last_member_value(chunks: list[dict], name: str, b: int) -> float:
    joined = join_records(chunks, axis=1)
    values = joined[name][b][joined["valid"][b]]
    return float(np.asarray(values)[-1].ravel()[0])


def phase_bar(phase: str, num: int, total: int, progress: bool):
    """The tqdm bar of one phase of :func:`run_group`.

    Consolidation ends on its criterion, not on its step cap: its bar counts steps with no total (no
    made-up ETA) and shows the unbalanced-force ratio against its stop value. A phase with no steps to run
    shows no bar; a single test's bar does not count members.
    """
    from tqdm.auto import tqdm

    return tqdm(
        total=None if phase == "consolidation" else total,
        desc=phase if num == 1 else f"{phase} ({num} members)",
        unit="step",
        disable=not progress or total == 0,
        leave=False,
    )


def run_group(
    batch: BatchedTest,
    folder: Path,
    resume: bool = False,
    progress: bool = True,
    interrupt_after_chunks: int | None = None,
    chunk_counter: list | None = None,
    after_chunk: Callable | None = None,
    isolate_failures: bool = False,
):
    """Run one batch through the three phases of :data:`PHASES` (module docstring).

    With ``float32_shearing`` (and ``float64``) consolidation runs in float64 and the shearing in float32:
    at the start of shearing the batch is rebuilt in float32 (:func:`float32_batch`) and the state carried
    over (:func:`cast_state`); the rest runs inside ``jax.enable_x64(False)``.

    Args:
      batch: from :func:`build_batch`.
      folder: where ``checkpoint.npz`` is written (and read with ``resume``).
      resume: continue from the folder's checkpoint, if there is one.
      progress: a tqdm bar per phase.
      interrupt_after_chunks: testing aid: ``KeyboardInterrupt`` after this many chunks (counted in
        ``chunk_counter``, after that chunk's checkpoint), as a killed process would stop.
      chunk_counter: a one-element list counting chunks across groups (default: this call's own).
      after_chunk: ``after_chunk(states, phase)`` after each accepted chunk (e.g. VTK snapshots).
      isolate_failures: a member that blows up (error bits, or a runaway kinetic energy) is frozen at its
        last good records and the others go on; ``batch.failures`` maps it to its error, step and phase
        (kept in checkpoints); the group runs on even when every member has failed (the caller judges: a
        sweep fails only when all its members did). False: the first raises.

    Returns:
      (records by phase: lists of chunk dicts of stacked (B, T, ...) arrays with ``valid``; the start of
      shearing per member: height, volume and platen area; the elapsed seconds).

    Raises:
      RunError: a member blew up (error bits or runaway kinetic energy); ``error.records`` holds the
        records so far, as returned.
    """
    # scope holds the float32 shearing's enable_x64(False) until the group ends.
    with contextlib.ExitStack() as scope:
        chunk_counter = [0] if chunk_counter is None else chunk_counter
        failures: dict[int, dict] = {}
        batch.failures = failures
        float32_shearing = batch.configs[0].float64 and batch.configs[0].float32_shearing

        def to_float32():
            """Rebuild the batch in float32 and run the rest in float32 (once)."""
            nonlocal batch
            if np.dtype(batch.initial_state.dem.position.dtype) == np.float32:
                return
            scope.enter_context(jax.enable_x64(False))
            batch = float32_batch(batch)

        config = batch.configs[0]
        checkpoint_path = folder / CHECKPOINT_NAME
        num = batch.num_members
        records: dict[str, list[dict]] = {phase: [] for phase in PHASES}
        phase_index, elapsed = 0, 0.0
        budgets = None
        shear_height = np.zeros(num)
        shear_volume = np.zeros(num)
        states = batch.initial_state
        if resume and checkpoint_path.exists():
            host = read_checkpoint_host(checkpoint_path)
            if float32_shearing and host.get("dtype") == "float32":
                to_float32()
            states, host = load_checkpoint(checkpoint_path, _template(batch, host["capacities"]))
            phase_index, elapsed = host["phase_index"], host["elapsed_s"]
            budgets = None if host["budgets"] is None else np.asarray(host["budgets"], dtype=np.int64)
            shear_height, shear_volume = np.asarray(host["shear_height"]), np.asarray(host["shear_volume"])
            failures.update({int(b): failure for b, failure in host.get("failures", {}).items()})
            for phase in PHASES:
                names = host.get(f"names_{phase}", [])
                if names:
                    records[phase] = [{name: np.asarray(host[f"rec_{phase}_{name}"]) for name in names}]
        tolerances = [consolidation_tolerance(c) for c in batch.configs]
        volume_work = np.array([t.cell_pressure * t.initial_volume for t in batch.tests])
        clock = time.perf_counter()

        def save(current, current_budgets):
            host = {
                "phase_index": phase_index,
                "elapsed_s": elapsed + time.perf_counter() - clock,
                "capacities": _capacities(current),
                # None at a phase's end: the next phase computes its budgets (and starts shearing) on resume.
                "budgets": None if current_budgets is None else [int(v) for v in current_budgets],
                "shear_height": shear_height,
                "shear_volume": shear_volume,
                "member_steps": [int(step) for step in np.asarray(current.dem.step)[:num]],
                "dtype": str(np.dtype(current.dem.position.dtype)),
                "failures": {str(b): failure for b, failure in failures.items()},
            }
            for phase in PHASES:
                joined = join_records(records[phase], axis=1)
                host[f"names_{phase}"] = list(joined)
                host.update({f"rec_{phase}_{name}": value for name, value in joined.items()})
            save_checkpoint(checkpoint_path, current, host)

        # The protocol's stage sequence (membrax.triaxial.protocol): each member's steps and record interval
        # per phase. The record interval is shared: it is not a batched field, so all members have the same.
        plans = [t.phase_plan(loading(c)) for t, c in zip(batch.tests, batch.configs, strict=True)]
        while phase_index < len(PHASES):
            phase = PHASES[phase_index]
            if budgets is None:
                if phase == "shear_fine" and float32_shearing:
                    capacities = _capacities(states)
                    to_float32()
                    states = cast_state(states, _template(batch, capacities))
                if phase == "shear_fine":
                    members = batch.unstack(states)
                    for b, test in enumerate(batch.tests):
                        if b in failures:  # frozen: it never shears
                            continue
                        shear_height[b] = _last_member_value(records["consolidation"], "height", b)
                        shear_volume[b] = _last_member_value(records["consolidation"], "volume", b)
                        c = batch.configs[b]
                        members[b] = test.start_shear(
                            members[b], c.inertial_number, c.shear_ramp_strain, c.symmetric_loading
                        )
                    states = batch.restack(members)
                elif phase == "shear_coarse" and any(c.coarse_inertial_number for c in batch.configs):
                    members = batch.unstack(states)
                    for b, test in enumerate(batch.tests):
                        c = batch.configs[b]
                        if b not in failures and c.coarse_inertial_number:
                            members[b] = test.change_shear_rate(
                                members[b], c.inertial_number, c.coarse_inertial_number, c.shear_ramp_strain
                            )
                    states = batch.restack(members)
                budgets = np.array([plan[phase][0] for plan in plans], dtype=np.int64)
                budgets[list(failures)] = 0  # a failed member stays frozen
            record_every = plans[0][phase][1]
            total = int(np.ceil(np.max(budgets, initial=0) / record_every) * record_every)
            bar = phase_bar(phase, num, total, progress)

            def on_chunk(current, chunk, left, phase=phase, bar=bar, record_every=record_every):
                nonlocal budgets
                budgets = left
                kinetic = chunk["kinetic_energy"].reshape(num, chunk["valid"].shape[1], -1)[:, -1, 0]
                runaway = ~np.isfinite(kinetic) | (kinetic > RUNAWAY_KINETIC_FRACTION * volume_work)
                runaway[list(failures)] = False
                stop = []
                for b in np.flatnonzero(runaway):
                    message = (
                        f"member {b} ({batch.configs[b].name}): kinetic energy {kinetic[b]:.3g} J exceeds "
                        f"{RUNAWAY_KINETIC_FRACTION} σc V₀ = "
                        f"{RUNAWAY_KINETIC_FRACTION * volume_work[b]:.3g} J: "
                        f"the run is unstable. Lower dt_safety (now {config.dt_safety}) or the stiffness."
                    )
                    if not isolate_failures:
                        raise RunError(message)
                    chunk["valid"][b] = False  # frozen at its last good records
                    stop.append(int(b))
                    on_failure(int(b), "RUNAWAY_KINETIC_ENERGY", int(np.asarray(current.dem.step)[b]), phase)
                records[phase].append(chunk)
                bar.update(chunk["valid"].shape[1] * record_every)
                postfix = {"active": int(np.sum(left > 0)), "step": int(np.max(np.asarray(current.dem.step)))}
                if phase == "consolidation":
                    # The worst member's unbalanced-force ratio against the stop value (tqdm sorts the keys).
                    ratio = chunk["unbalanced_force_ratio"].reshape(num, chunk["valid"].shape[1], -1)[..., 0]
                    last = [ratio[b][chunk["valid"][b]][-1] for b in range(num) if chunk["valid"][b].any()]
                    postfix = {
                        "unbalanced": f"{max(last, default=0.0):.1e}",
                        "until": f"{min(tolerances):.0e}",
                        **({} if num == 1 else {"active": postfix["active"]}),
                    }
                elif num == 1:
                    # A single test (run_test) shows where it stands, as in the paper's Fig. 5.
                    valid = chunk["valid"][0]
                    last = {name: float(chunk[name][0][valid][-1].ravel()[0]) for name in _PROGRESS}
                    external, internal = analysis.friction_angle_deg(
                        [last["external_axial_stress"], last["internal_axial_stress"]],
                        [last["external_radial_stress"], last["internal_radial_stress"]],
                    )
                    postfix = {
                        "strain": f"{100 * last['axial_strain']:.3f}%",
                        "phi_ext": f"{external:.1f}",
                        "phi_int": f"{internal:.1f}",
                    }
                bar.set_postfix(**postfix)
                if after_chunk is not None:
                    after_chunk(current, phase)
                chunk_counter[0] += 1
                if chunk_counter[0] % config.checkpoint_every_chunks == 0:
                    save(current, left)
                if interrupt_after_chunks is not None and chunk_counter[0] >= interrupt_after_chunks:
                    raise KeyboardInterrupt(f"interrupted after {chunk_counter[0]} chunks (testing aid)")
                return stop

            def on_failure(b, names, step, phase=phase):
                failures[b] = {"error": names, "step": step, "phase": phase}

            stop_fn = None
            if phase == "consolidation":

                def stop_fn(b, mine):
                    return batch.tests[b].is_consolidated(mine, tolerances[b])

            try:
                states, budgets = batch.run_phase(
                    states,
                    budgets,
                    config.chunk_steps,
                    record_every,
                    stop_fn=stop_fn,
                    on_chunk=on_chunk,
                    on_failure=on_failure if isolate_failures else None,
                )
            except SimulationError as error:
                raise RunError(
                    f"{error}. Lower dt_safety (now {config.dt_safety}) or particle_stiffness_n_m; a "
                    "membrane modulus far above the paper's 1400 kPa also shortens the stable step.",
                    records,
                ) from error
            except RunError as error:
                error.records = records
                raise
            finally:
                bar.close()
            phase_index += 1
            budgets = None
            save(states, None)
        elapsed += time.perf_counter() - clock
        shear_start = [
            {"height": shear_height[b], "volume": shear_volume[b], "platen_area": batch.tests[b].platen_area}
            for b in range(num)
        ]
        return records, shear_start, elapsed


def run_metadata(config, test, records, build_seconds, elapsed, tolerance) -> dict:
    """The attributes of a run's datasets: configuration, version, sizes, Δt, steps, timings, machine."""
    consolidation = join_records(records["consolidation"])
    shear_steps = (
        sum(len(c["step"]) for c in records["shear_fine"]) * config.record_every_fine
        + sum(len(c["step"]) for c in records["shear_coarse"]) * config.record_every_coarse
    )
    return {
        "membrax_version": __version__,
        "config": config_to_dict(config),
        "num_particles": int(test.particles.num_particles),
        "num_membrane_nodes": int(test.mesh.num_nodes),
        "num_triangles": int(test.mesh.triangles.shape[0]),
        "dt_s": test.dt,
        "critical_dt_s": {key: float(value) for key, value in test.critical_dt.items()},
        "consolidation_steps": int(len(consolidation.get("step", [])) * CONSOLIDATION_RECORD_EVERY),
        "consolidation_tolerance": tolerance,
        "shear_steps": int(shear_steps),
        "build_s": build_seconds,
        "run_s": elapsed,
        "dtype": precision_name(config),
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
        "specimen": specimen_metadata(test.specimen),
    }


def precision_name(config: TriaxialConfig) -> str:
    """The run's precision: ``"float64"``, ``"float32"`` or ``"float64 consolidation, float32 shearing"``."""
    if not config.float64:
        return "float32"
    return "float64 consolidation, float32 shearing" if config.float32_shearing else "float64"


def specimen_metadata(specimen) -> dict:
    """The specimen's record for a run's attributes: packing, size, solid fraction, grading.

    For a random specimen sampled from a grading: the sieve sizes (mm) and percent passing beside the
    percent passing of the sampled spheres (:func:`membrax.spheres.random_packing.mass_fractions`).
    """
    radius = np.asarray(specimen.radius, dtype=float)
    solid = float(np.sum(4.0 / 3.0 * np.pi * radius**3))
    record = {
        "packing": "random" if specimen.cross_section == "circle" else "fcc",
        "num_spheres": int(radius.size),
        "width_mm": 1e3 * specimen.width_across_flats,
        "height_mm": 1e3 * specimen.height,
        "solid_fraction": solid / (specimen.cross_section_area * specimen.height),
    }
    # A compacted packing's stress, and the jump that kept it out of the compaction's window, if any.
    measures = dict(getattr(specimen, "packing_measures", ()))
    for name in ("compaction_stress", "compaction_stress_below", "compaction_stress_above"):
        if name in measures:
            record[f"{name}_kpa"] = 1e-3 * float(measures[name])
    if specimen.cross_section == "circle" and specimen.grading:
        sizes, passing = specimen.grading
        sampled = np.concatenate([[0.0], np.cumsum(mass_fractions(2.0 * radius, sizes))])
        record.update(
            seed=specimen.seed,
            grading_size_mm=[1e3 * size for size in sizes],
            grading_percent_passing=[100.0 * value for value in passing],
            sampled_percent_passing=[float(100.0 * value) for value in sampled],
        )
    return record


def results_datasets(records: dict, shear_start: dict, metadata: dict):
    """(shear dataset or None, consolidation dataset) from the records of the three phases (module docstring).

    ``records`` maps each of :data:`PHASES` to a list of chunk dicts; ``shear_start`` holds the height and
    volume at the start of shearing (strains are rebased on them); ``metadata`` becomes the attributes.
    """
    consolidation = records_to_dataset(join_records(records["consolidation"]), attrs=metadata)
    shear = join_records(records["shear_fine"] + records["shear_coarse"])
    if not shear:
        return None, consolidation
    # The end of consolidation is the shearing's first record (strain 0: the "initial" state of Table 3).
    last = {name: value[-1:] for name, value in join_records(records["consolidation"]).items()}
    shear = {name: np.concatenate([last[name], value]) for name, value in shear.items()}
    shear = rebase_to_shear_start(shear, shear_start)
    shear.update(analysis.derived_quantities(shear))
    return records_to_dataset(shear, attrs=metadata), consolidation
