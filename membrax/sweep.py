"""Vectorised sweeps: a grid of membrane triaxial tests run as one batched, compiled simulation.

Contract. :func:`run_sweep` takes a base :class:`membrax.config.TriaxialConfig` and a grid (field name →
values, default the paper's Table 1: ``cell_pressure_kpa`` × ``membrane_thickness_mm``), runs every
member's test (:mod:`membrax.run`'s protocol: consolidation, then drained shearing) and writes one
:class:`xarray.Dataset` whose dimensions are the grid's fields plus ``record``:

- ``sweep.nc``: the shearing records of every member (the first record the end of consolidation, strains
  from the start of shearing, the derived quantities of :func:`membrax.analysis.derived_quantities`),
  NaN-padded along ``record`` to the longest member (``num_records`` says how many are real), with the
  per-member scalars ``consolidation_steps``, ``shear_steps`` and the Table 2/3 numbers
  (``sigma3_internal_kpa``, ``peak_external_friction_angle_deg``, …);
- ``sweep_consolidation.nc``: the consolidation records, padded the same way;
- ``summary.csv``: one row per member with those scalars; ``sweep.toml``: the base config and grid.

Batching. Members that differ only in :data:`BATCHED_FIELDS` (traced parameters: pressure, thickness,
modulus, friction, stiffness, rate, strain targets) form one :class:`BatchedTest`: their states are stacked
on a leading member axis and every chunk of steps is **one** compiled call, ``lax.map`` over the members
on a CPU (each member's arrays stay in cache; :mod:`membrax.batch`) or ``vmap`` on a GPU. They share one
time step (the smallest of the members' own, :func:`membrax.membrane_triaxial.membrane_test`'s rule) and
one mesh topology: n_θ nodes per ring from the members' mean perimeter, each thickness keeping its own rest
geometry (``GEOMETRY_FIELDS``, traced per member). Fields that change array shapes or compiled constants
(specimen size, mesh resolution, density, record cadence, dtype) split the grid into groups, run one after
another.

Stages per member. Each member carries a step budget for the current phase; a record block of a member
whose budget is spent is skipped (``lax.cond``: no work on a CPU) and its state frozen, so members finish
consolidation at different steps (the stop test of :meth:`MembraneTest.is_consolidated` is applied to each
member's chunk) and shear for different numbers of steps (ε̇ ∝ √σc at a fixed inertial number), while the
batch runs until the last one is done. Each member therefore follows exactly the steps it would take alone
with the same Δt and mesh (tests/test_sweep.py checks batched = serial).

Devices. With several devices the member axis is sharded across them with ``jax.shard_map`` (members
padded with frozen copies to a multiple of the device count). On a CPU this is the fast batching: one
device per core (:func:`membrax.devices.split_cpu_devices`, called before other membrax imports;
``membrax sweep`` and ``membrax reproduce`` do it) runs each core's members side by side, each member's
arrays on one core, which beats both one device using the cores for every operation and the members run
one after another (``benchmarks/bench_sweep.py``). Across several hosts, call
``jax.distributed.initialize()`` in every process before :func:`run_sweep`: ``jax.devices()`` then lists
every host's devices, but a batch shards over the local ones only: between chunks the driver reads every
member's error bits and records on the host. Give each process its share of the grid (e.g.
``jax.process_index()`` picks the pressures) and merge the ``sweep.nc`` files with
``xarray.combine_by_coords`` (README).

Long runs. Progress bars per phase (active members, steps), a checkpoint (stacked state, records so far,
budgets) every ``checkpoint_every_chunks`` chunks and at each phase's end, and ``resume=True`` continuing
to results identical to an uninterrupted sweep; finished groups are kept in ``groups/``.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import itertools
import json
import math
import time
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from membrax import __version__, analysis, paper
from membrax import io as io_lib
from membrax.batch import stack
from membrax.config import (
    ConfigError,
    TriaxialConfig,
    config_to_dict,
    dump_config_toml,
    parse_overrides,
    with_overrides,
)
from membrax.devices import cpu_cores
from membrax.driver import SimulationError
from membrax.errors import OVERFLOWS, ErrorCode, describe
from membrax.membrane import rounded_offset_path
from membrax.membrane_dem import grow_candidates
from membrax.neighbors import remap_pair_history
from membrax.packing import fcc_specimen
from membrax.run import (
    CONSOLIDATION_RECORD_EVERY,
    PHASES,
    RUNAWAY_KINETIC_FRACTION,
    RunError,
    build_test,
    consolidation_tolerance,
    results_datasets,
    run_metadata,
)

__all__ = [
    "BATCHED_FIELDS",
    "DEFAULT_GRID",
    "BatchedTest",
    "SweepResult",
    "balanced_order",
    "build_batch",
    "grid_members",
    "parse_grid",
    "run_sweep",
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
        "target_axial_strain",
        "fine_until_strain",
        "shear_ramp_strain",
        "symmetric_loading",
        "membrane_contact_offset_factor",
        "consolidation_tolerance",
        "consolidation_max_steps",
    }
)
#: The paper's Table 1 (:data:`membrax.paper.TABLE_1_GRID`).
DEFAULT_GRID = paper.TABLE_1_GRID
#: Mesh arrays that depend on the thickness (the rest geometry); the rest of the mesh is shared.
GEOMETRY_FIELDS = (
    "reference_position",
    "reference_inverse",
    "reference_area",
    "rest_dihedral",
    "edge_weight",
)
#: Fields that do not enter the simulation (never split a batch, never gridded).
_BOOKKEEPING_FIELDS = frozenset({"name", "checkpoint_every_chunks", "vtk_every_steps"})
CHECKPOINT_NAME = "checkpoint.npz"


# ----------------------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------------------


def parse_grid(items: Sequence[str]) -> dict[str, tuple]:
    """``["cell_pressure_kpa=10,40,100", "membrane_thickness_mm=2.5,5"]`` → ``{field: values}``.

    Values are converted and checked by the configuration (:func:`membrax.config.with_overrides`).

    Raises:
      ConfigError: naming the item, for a missing ``=``, an empty value list, a repeated field or a field
        that is not a configuration field.
    """
    grid: dict[str, tuple] = {}
    for item in items:
        key, sep, values = str(item).partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ConfigError(f"--grid {item!r}: write FIELD=V1,V2,... e.g. cell_pressure_kpa=10,40,100.")
        if key in grid:
            raise ConfigError(f"--grid {item!r}: {key} is given twice; list all its values in one --grid.")
        texts = [value.strip() for value in values.split(",") if value.strip()]
        # Each value read as the CLI's --set reads it (TOML numbers, booleans, strings).
        parsed = tuple(parse_overrides([f"{key}={text}"])[key] for text in texts)
        if not parsed:
            raise ConfigError(f"--grid {item!r}: no values; write {key}=V1,V2,...")
        grid[key] = parsed
    return grid


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
        if key not in fields or key in _BOOKKEEPING_FIELDS:
            raise ConfigError(
                f"grid field {key!r} is not a simulation field of TriaxialConfig; choose from "
                f"{sorted(fields - _BOOKKEEPING_FIELDS)}."
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


def _structure_key(config: TriaxialConfig) -> tuple:
    """The fields that must agree within one batch (everything not batched and not bookkeeping)."""
    return tuple(
        (field.name, getattr(config, field.name))
        for field in pydataclasses.fields(TriaxialConfig)
        if field.name not in BATCHED_FIELDS and field.name not in _BOOKKEEPING_FIELDS
    )


def _common_nodes_around(configs: Sequence[TriaxialConfig]) -> int:
    """n_θ for all members: round(mean membrane perimeter / edge length) over the members' thicknesses."""
    config = configs[0]
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


# ----------------------------------------------------------------------------------------------------------
# Stacking helpers
# ----------------------------------------------------------------------------------------------------------


def _member(tree, index: int):
    """Member ``index`` of a stacked pytree."""
    return jax.tree_util.tree_map(lambda leaf: leaf[index], tree)


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
        template = allocated[0].set(max_occupancy=occupancy, cell_list_capacity=cells or None)
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
      params: stacked :class:`membrax.membrane_dem.CoupledParams`, padded to a multiple of ``num_devices``.
      members: stacked per-member constants: the mesh's rest geometry and the initial inner volume.
      initial_state: stacked states at the start of consolidation (servo on).
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

    def __post_init__(self):
        self._chunk = jax.jit(self._chunk_impl, static_argnames=("num_records", "record_every"))

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

        def advance(s):
            return jax.lax.fori_loop(0, record_every, lambda _, x: step(x, params), s)

        def block(carry, _):
            s, budget = carry
            active = budget > 0
            # A spent budget freezes the member: lax.cond skips its work under lax.map.
            s = jax.lax.cond(active, advance, lambda x: x, s)
            budget = jnp.where(active, budget - record_every, budget)
            return (s, budget), (record(s, params), active)

        (state, left), (records, valid) = jax.lax.scan(block, (state, left), None, length=num_records)
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
        return [_member(states, b) for b in range(self.num_members)]

    def _grow(self, states, error, overflowed):
        """Reallocate every member's neighbour list and/or candidate table with one larger capacity."""
        members = [_member(states, b) for b in range(self.num_padded)]
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
            old = states.membrane.candidates
            subset = int(old.sphere_subset.shape[-1])
            capacity = max(
                int(np.max(np.asarray(overflowed.max_count))) + 2, math.ceil(1.5 * old.idx.shape[-1])
            )
            sphere_capacity = max(
                int(np.max(np.asarray(overflowed.max_sphere_count))) + 8, int(old.sphere_slots.shape[-1])
            )
            thickness = np.asarray(self.params.membrane.contact_thickness)
            members = [
                grow_candidates(m, particles, min(capacity, subset), thickness[b], sphere_capacity)
                for b, m in enumerate(members)
            ]
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
            stacked (B, T, …) arrays of the real members plus ``valid`` (B, T).

        Returns:
          (states, budgets).

        Raises:
          SimulationError: a member's error bits other than an overflow, naming the member.
        """
        padded = np.zeros(self.num_padded, dtype=np.int64)
        padded[: self.num_members] = np.ceil(np.asarray(budgets) / record_every) * record_every
        records_per_chunk = max(1, chunk_steps // record_every)
        while padded.max() > 0:
            count = min(records_per_chunk, math.ceil(padded.max() / record_every))
            new_states, left, records, valid = self._chunk(
                states,
                self.params,
                self.members,
                jnp.asarray(padded),
                num_records=count,
                record_every=record_every,
            )
            error = np.asarray(new_states.dem.error)
            if np.any(error & OVERFLOWS):
                states = self._grow(states, error, new_states.membrane.candidates)
                continue
            if np.any(error[: self.num_members]):
                bad = int(np.flatnonzero(error[: self.num_members])[0])
                raise SimulationError(
                    f"member {bad} ({self.configs[bad].name}) stopped in the chunk ending at step "
                    f"{int(np.asarray(new_states.dem.step)[bad])}: " + "; ".join(describe(error[bad])),
                    state=states,
                )
            states = new_states
            padded = np.asarray(left).astype(np.int64)
            valid = np.asarray(valid)[: self.num_members]
            chunk = {
                field.name: np.asarray(getattr(records, field.name))[: self.num_members]
                for field in pydataclasses.fields(records)
            }
            chunk["valid"] = valid
            if stop_fn is not None:
                for b in np.flatnonzero(valid.any(axis=1)):
                    mine = types.SimpleNamespace(
                        **{k: v[b][valid[b]] for k, v in chunk.items() if k != "valid"}
                    )
                    if padded[b] > 0 and stop_fn(int(b), mine):
                        padded[b] = 0
            if on_chunk is not None:
                on_chunk(states, chunk, padded[: self.num_members].copy())
        return states, padded[: self.num_members]


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


def build_batch(
    configs: Sequence[TriaxialConfig],
    num_devices: int | None = None,
    mode: str | None = None,
    order: Sequence[int] | None = None,
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

    Raises:
      ValueError: no members, members that differ in a field outside :data:`BATCHED_FIELDS`, a bad mode
        or device count.
    """
    configs = list(configs)
    if not configs:
        raise ValueError("no members to batch; give at least one configuration.")
    keys = {_structure_key(c) for c in configs}
    if len(keys) > 1:
        first = dict(_structure_key(configs[0]))
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
    nodes_around = _common_nodes_around(configs)
    tests = [build_test(c, nodes_around=nodes_around) for c in configs]
    dt = min(t.dt for t in tests)
    tests = [
        t if t.dt == dt else build_test(c, time_step=dt, nodes_around=nodes_around)
        for t, c in zip(tests, configs, strict=True)
    ]
    if order is None:
        # Shear steps are planned; consolidation stops when its test holds (unknown beforehand, about
        # alike for all members), so every member is charged two chunks of it.
        work = [
            min(c.consolidation_max_steps, 2 * c.chunk_steps)
            + sum(
                t.shear_plan(
                    c.target_axial_strain, c.inertial_number, c.fine_until_strain, c.shear_ramp_strain
                )
            )
            for c, t in zip(configs, tests, strict=True)
        ]
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
        "node_candidates": int(candidates.idx.shape[-1]),
        "sphere_slots": int(candidates.sphere_slots.shape[-1]),
    }


def _template(batch: BatchedTest, capacities: dict):
    """The batch's initial state grown to a checkpoint's capacities (the loader's shape template)."""
    states = batch.initial_state
    if _capacities(states) == capacities:
        return states
    members = [_member(states, b) for b in range(batch.num_padded)]
    thickness = np.asarray(batch.params.membrane.contact_thickness)
    particles = batch.tests[0].particles
    members = [
        grow_candidates(m, particles, capacities["node_candidates"], thickness[b], capacities["sphere_slots"])
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


def _join_chunks(chunks: list[dict]) -> dict:
    if not chunks:
        return {}
    return {name: np.concatenate([chunk[name] for chunk in chunks], axis=1) for name in chunks[0]}


def _member_records(records: dict, b: int) -> dict:
    """Member b's records of every phase, as :func:`membrax.run.results_datasets` takes them."""
    out = {}
    for phase in PHASES:
        joined = _join_chunks(records[phase])
        if not joined:
            out[phase] = []
            continue
        valid = joined["valid"][b]
        out[phase] = [{name: value[b][valid] for name, value in joined.items() if name != "valid"}]
    return out


def _last_member_value(chunks: list[dict], name: str, b: int) -> float:
    joined = _join_chunks(chunks)
    values = joined[name][b][joined["valid"][b]]
    return float(np.asarray(values)[-1].ravel()[0])


def _run_group(
    batch: BatchedTest, folder: Path, resume: bool, progress: bool, interrupt_after_chunks, chunk_counter
):
    """Run one batch through the three phases; returns (records by phase, shear_start, elapsed seconds)."""
    from tqdm.auto import tqdm

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
        host = io_lib.read_checkpoint_host(checkpoint_path)
        states, host = io_lib.load_checkpoint(checkpoint_path, _template(batch, host["capacities"]))
        phase_index, elapsed = host["phase_index"], host["elapsed_s"]
        budgets = None if host["budgets"] is None else np.asarray(host["budgets"], dtype=np.int64)
        shear_height, shear_volume = np.asarray(host["shear_height"]), np.asarray(host["shear_volume"])
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
        }
        for phase in PHASES:
            joined = _join_chunks(records[phase])
            host[f"names_{phase}"] = list(joined)
            host.update({f"rec_{phase}_{name}": value for name, value in joined.items()})
        io_lib.save_checkpoint(checkpoint_path, current, host)

    while phase_index < len(PHASES):
        phase = PHASES[phase_index]
        if budgets is None:
            if phase == "consolidation":
                budgets = np.array([c.consolidation_max_steps for c in batch.configs], dtype=np.int64)
            else:
                if phase == "shear_fine":
                    members = batch.unstack(states)
                    for b, test in enumerate(batch.tests):
                        shear_height[b] = _last_member_value(records["consolidation"], "height", b)
                        shear_volume[b] = _last_member_value(records["consolidation"], "volume", b)
                        c = batch.configs[b]
                        members[b] = test.start_shear(
                            members[b], c.inertial_number, c.shear_ramp_strain, c.symmetric_loading
                        )
                    states = batch.restack(members)
                plans = [
                    t.shear_plan(
                        c.target_axial_strain, c.inertial_number, c.fine_until_strain, c.shear_ramp_strain
                    )
                    for t, c in zip(batch.tests, batch.configs, strict=True)
                ]
                budgets = np.array([plan[phase_index - 1] for plan in plans], dtype=np.int64)
        record_every = {
            "consolidation": CONSOLIDATION_RECORD_EVERY,
            "shear_fine": config.record_every_fine,
            "shear_coarse": config.record_every_coarse,
        }[phase]
        total = int(np.ceil(np.max(budgets, initial=0) / record_every) * record_every)
        bar = tqdm(
            total=total, desc=f"{phase} ({num} members)", unit="step", disable=not progress, leave=False
        )

        def on_chunk(current, chunk, left, phase=phase, bar=bar, record_every=record_every):
            nonlocal budgets
            records[phase].append(chunk)
            budgets = left
            kinetic = chunk["kinetic_energy"].reshape(num, chunk["valid"].shape[1], -1)[:, -1, 0]
            runaway = ~np.isfinite(kinetic) | (kinetic > RUNAWAY_KINETIC_FRACTION * volume_work)
            if np.any(runaway):
                b = int(np.flatnonzero(runaway)[0])
                raise RunError(
                    f"member {b} ({batch.configs[b].name}): kinetic energy {kinetic[b]:.3g} J exceeds "
                    f"{RUNAWAY_KINETIC_FRACTION} σc V₀ = {RUNAWAY_KINETIC_FRACTION * volume_work[b]:.3g} J: "
                    f"the run is unstable. Lower dt_safety (now {config.dt_safety}) or the stiffness."
                )
            bar.update(chunk["valid"].shape[1] * record_every)
            bar.set_postfix(active=int(np.sum(left > 0)), step=int(np.max(np.asarray(current.dem.step))))
            chunk_counter[0] += 1
            if chunk_counter[0] % config.checkpoint_every_chunks == 0:
                save(current, left)
            if interrupt_after_chunks is not None and chunk_counter[0] >= interrupt_after_chunks:
                raise KeyboardInterrupt(f"interrupted after {chunk_counter[0]} chunks (testing aid)")

        stop_fn = None
        if phase == "consolidation":

            def stop_fn(b, mine):
                return batch.tests[b].is_consolidated(mine, tolerances[b])

        try:
            states, budgets = batch.run_phase(
                states, budgets, config.chunk_steps, record_every, stop_fn=stop_fn, on_chunk=on_chunk
            )
        except SimulationError as error:
            raise RunError(
                f"{error}. Lower dt_safety (now {config.dt_safety}) or particle_stiffness_n_m; a membrane "
                "modulus far above the paper's 1400 kPa also shortens the stable step."
            ) from error
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


# ----------------------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------------------


@pydataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` produced.

    Attributes:
      folder: the results folder.
      dataset: the shearing records over the grid (module docstring).
      consolidation: the consolidation records over the grid.
      files: paths written.
      seconds: wall time of the whole sweep, s.
    """

    folder: Path
    dataset: xr.Dataset
    consolidation: xr.Dataset
    files: dict
    seconds: float

    def member(self, **coordinates) -> xr.Dataset:
        """One member's shearing records, padding removed: ``result.member(cell_pressure_kpa=10, ...)``."""
        return member_records(self.dataset, **coordinates)


def member_records(dataset: xr.Dataset, **coordinates) -> xr.Dataset:
    """One member of a sweep dataset (selected by its grid coordinates), its NaN padding removed."""
    missing = [
        dim for dim in dataset.attrs.get("grid_fields", "").split(",") if dim and dim not in coordinates
    ]
    if missing:
        raise ValueError(f"give a value for every grid field; missing {missing}.")
    selected = dataset.sel(coordinates, method="nearest")
    count = int(selected["num_records"])
    return selected.isel(record=slice(0, count))


_SCALARS = (
    "sigma3_external_kpa",
    "sigma3_internal_kpa",
    "sigma1_external_kpa",
    "sigma1_internal_kpa",
    "peak_external_friction_angle_deg",
    "peak_external_axial_strain",
    "peak_internal_friction_angle_deg",
    "peak_internal_axial_strain",
)


def _member_scalars(shear: xr.Dataset) -> dict:
    values = {**analysis.initial_state(shear), **analysis.peak(shear)}
    return {name: float(values[name]) for name in _SCALARS}


def _grid_dataset(datasets: list, coordinates: dict, indices: list, extra: dict, attrs: dict) -> xr.Dataset:
    """Stack per-member datasets (dimension ``record`` first) onto the grid, NaN-padded along ``record``."""
    dims = tuple(coordinates)
    shape = tuple(len(v) for v in coordinates.values())
    length = max(ds.sizes["record"] for ds in datasets)
    variables = {}
    names = list(datasets[0].coords) + list(datasets[0].data_vars)
    for name in names:
        first = datasets[0].variables[name]
        if not first.dims or first.dims[0] != "record":
            continue
        tail = first.shape[1:]
        values = np.full((*shape, length, *tail), np.nan)
        for index, ds in zip(indices, datasets, strict=True):
            data = np.asarray(ds.variables[name].values, dtype=np.float64)
            values[index][: data.shape[0]] = data
        variables[name] = xr.Variable(dims + first.dims, values, attrs=dict(first.attrs))
    counts = np.zeros(shape, dtype=np.int32)
    for index, ds in zip(indices, datasets, strict=True):
        counts[index] = ds.sizes["record"]
    variables["num_records"] = xr.Variable(dims, counts)
    for name, per_member in extra.items():
        values = np.full(shape, np.nan)
        for index, value in zip(indices, per_member, strict=True):
            values[index] = value
        variables[name] = xr.Variable(dims, values)
    coords = {dim: np.asarray(values, dtype=np.float64) for dim, values in coordinates.items()}
    return xr.Dataset(variables, coords=coords, attrs={**attrs, "grid_fields": ",".join(dims)})


def _write_summary_csv(path: Path, coordinates: dict, configs_by_index: dict, dataset: xr.Dataset) -> None:
    names = ["consolidation_steps", "shear_steps", "num_records", *_SCALARS]
    lines = [",".join(list(coordinates) + names)]
    for index in configs_by_index:
        point = {dim: coordinates[dim][i] for dim, i in zip(coordinates, index, strict=True)}
        cells = [repr(float(v)) for v in point.values()]
        cells += [repr(float(dataset[name].values[index])) for name in names]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")


def run_sweep(
    base: TriaxialConfig,
    grid: Mapping[str, Sequence] | None = None,
    folder=None,
    resume: bool = False,
    progress: bool = True,
    num_devices: int | None = None,
    mode: str | None = None,
    interrupt_after_chunks: int | None = None,
) -> SweepResult:
    """Run every member of ``grid`` over ``base`` into ``folder`` (module docstring).

    Args:
      base: the configuration shared by all members.
      grid: field → values (default :data:`DEFAULT_GRID`, the paper's Table 1).
      folder: results folder (default ``results_{base.name}_sweep``), created.
      resume: continue from the folder's checkpoints.
      progress: tqdm progress bars.
      num_devices: devices to shard each batch over (default all; on a CPU see
        :func:`membrax.devices.split_cpu_devices`).
      mode: ``"map"``/``"vmap"`` (default by backend, :func:`build_batch`).
      interrupt_after_chunks: testing aid: ``KeyboardInterrupt`` after this many chunks of this call.

    Returns:
      A :class:`SweepResult`.

    Raises:
      ConfigError: a bad grid. RunError: a member blew up (its name and the fix in the message).
    """
    started = time.perf_counter()
    grid = dict(DEFAULT_GRID if grid is None else grid)
    coordinates, members = grid_members(base, grid)
    folder = Path(folder if folder is not None else f"results_{base.name}_sweep")
    folder.mkdir(parents=True, exist_ok=True)
    if not resume:
        (folder / "sweep.toml").write_text(
            dump_config_toml(base)
            + "\n[grid]\n"
            + "".join(f"{key} = {json.dumps(list(values))}\n" for key, values in coordinates.items())
        )
    if jax.default_backend() == "cpu" and jax.local_device_count() == 1 and cpu_cores() > 1 < len(members):
        warnings.warn(
            f"one CPU device on {cpu_cores()} cores: call membrax.devices.split_cpu_devices() before "
            "importing the rest of membrax (or any JAX operation) to run the members side by side, one "
            "per core (bench_sweep: 1.5–2.5× faster than serial on 2 cores).",
            stacklevel=2,
        )
    groups: dict[tuple, list] = {}
    for index, config in members:
        groups.setdefault(_structure_key(config), []).append((index, config))
    # The base configuration's precision, scoped to this call (thread-local), as in run_test.
    with jax.enable_x64(base.float64):
        shear_sets, consolidation_sets, indices, extra = [], [], [], {}
        chunk_counter = [0]
        for g, group in enumerate(groups.values()):
            group_folder = folder / "groups" / f"group_{g}"
            done_file = group_folder / "results.nc"
            # The batch order (balanced_order) depends on the device count: a resumed group keeps its own.
            order_file = group_folder / "members.json"
            order = None
            if resume and order_file.exists():
                order = json.loads(order_file.read_text())
            elif resume and group_folder.exists():
                order = list(range(len(group)))  # a folder written before members.json: grid order
            if resume and done_file.exists():
                group = [group[i] for i in order]
                shear_group = [io_lib.read_results(group_folder / f"shear_{k}.nc") for k in range(len(group))]
                consolidation_group = [
                    io_lib.read_results(group_folder / f"consolidation_{k}.nc") for k in range(len(group))
                ]
            else:
                build_start = time.perf_counter()
                batch = build_batch([config for _, config in group], num_devices, mode, order)
                group = [group[i] for i in batch.order]
                group_folder.mkdir(parents=True, exist_ok=True)
                order_file.write_text(json.dumps(batch.order))
                build_seconds = time.perf_counter() - build_start
                records, shear_start, elapsed = _run_group(
                    batch, group_folder, resume, progress, interrupt_after_chunks, chunk_counter
                )
                shear_group, consolidation_group = [], []
                for k, ((_, config), test) in enumerate(zip(group, batch.tests, strict=True)):
                    mine = _member_records(records, k)
                    metadata = run_metadata(
                        config, test, mine, build_seconds, elapsed, consolidation_tolerance(config)
                    )
                    metadata.update(
                        batch_members=batch.num_members,
                        batch_devices=batch.num_devices,
                        nodes_around=batch.nodes_around,
                    )
                    shear, consolidation = results_datasets(mine, shear_start[k], metadata)
                    io_lib.write_netcdf(shear, group_folder / f"shear_{k}.nc")
                    io_lib.write_netcdf(consolidation, group_folder / f"consolidation_{k}.nc")
                    shear_group.append(shear)
                    consolidation_group.append(consolidation)
                io_lib.write_netcdf(xr.Dataset(attrs={"members": len(group)}), done_file)
            for (index, _), shear, consolidation in zip(group, shear_group, consolidation_group, strict=True):
                attrs = io_lib.dataset_attrs_to_python(shear)
                indices.append(index)
                shear_sets.append(shear)
                consolidation_sets.append(consolidation)
                extra.setdefault("consolidation_steps", []).append(attrs["consolidation_steps"])
                extra.setdefault("shear_steps", []).append(attrs["shear_steps"])
                extra.setdefault("dt_s", []).append(attrs["dt_s"])
                extra.setdefault("nodes_around", []).append(attrs["nodes_around"])
                for name, value in _member_scalars(shear).items():
                    extra.setdefault(name, []).append(value)
    attrs = {
        "membrax_version": __version__,
        "base_config": config_to_dict(base),
        "grid": {key: list(values) for key, values in coordinates.items()},
        "groups": len(groups),
    }
    dataset = _grid_dataset(shear_sets, coordinates, indices, extra, attrs)
    consolidation = _grid_dataset(consolidation_sets, coordinates, indices, {}, attrs)
    seconds = time.perf_counter() - started
    dataset.attrs["run_s"] = seconds
    files = {
        "sweep": io_lib.write_netcdf(dataset, folder / "sweep.nc"),
        "consolidation": io_lib.write_netcdf(consolidation, folder / "sweep_consolidation.nc"),
    }
    _write_summary_csv(folder / "summary.csv", coordinates, dict.fromkeys(indices), dataset)
    files["summary"] = folder / "summary.csv"
    return SweepResult(folder, dataset, consolidation, files, seconds)
