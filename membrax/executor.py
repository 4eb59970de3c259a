"""The batched executor: members of one compiled batch, stacked, with one Δt and one mesh topology.

Contract. :func:`build_batch` builds the members of a group (:class:`BatchedTest`: states stacked on a
member axis, one Δt, one mesh topology, per-member budgets) from their configurations through
:mod:`membrax.assemble`, planned by :mod:`membrax.planning` (the shared Δt and mesh, each member's work,
their order over devices); :func:`float32_batch` and :func:`cast_state` change a batch's precision
for the shearing. It runs nothing: :func:`membrax.runner.run_group` drives a batch through the protocol.

Batching. Members that differ only in :data:`membrax.assemble.BATCHED_FIELDS` (traced parameters) form one
batch; each chunk of steps is **one** compiled call, ``lax.map`` over the members on a CPU (each member's
arrays stay in cache; :mod:`membrax.batch`) or ``vmap`` on a GPU, sharded over devices with
``jax.shard_map``. Each member carries a step budget for the current phase; a record block of a member whose
budget is spent is skipped (``lax.cond``: no work on a CPU) and its state frozen, so every member takes
exactly the steps it would take alone with the same Δt and mesh (tests/test_sweep.py checks batched =
alone). :class:`StackedMembers` holds what every batch shares (the chunk, the budgets, the driver's loop).

Periodic elements. :func:`build_periodic_batch` stacks ``cell = "periodic"`` members of one packing
(:class:`PeriodicBatch`: one cell, Δt and neighbour-list shape; each member its own σc, servo targets,
rates, contact law, stage budgets and stop test); :func:`membrax.runner.run_group` drives it through
the protocol (a single element is a batch of one). Its records equal those of each member run alone to
the bit on one device with ``lax.map`` (the same program per member: tests/test_periodic_batch.py). Under
``vmap`` (the GPU's mode) the reductions over spheres and pairs are vectorised across members and sum in
another order, and sharded over several CPU devices XLA compiles the per-device program otherwise (measured
on 64 spheres in float64: 1e-12 of σc over 1,000 steps with viscous damping); either way the members
start apart at round-off, which local damping's sign(u) (flipping on round-off where u ≈ 0) and the
granular dynamics amplify over thousands of steps (1e-9 of σc after 100 steps, ~1e-4 after 2,000), as in a
membrane sweep sharded over devices. A list that overflows in any member, or a box
that outgrows its cells, grows every member's list together, from the chunk's start (one shape); a member
whose list would not have grown alone then rebuilds its list at another step than alone, which reorders
its pairs and sums: round-off again, not bits.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import functools
import math
import types
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native
from membrax.assemble import run_settings
from membrax.batch import stack
from membrax.config import TriaxialConfig
from membrax.driver import budgeted_blocks, drive, grow_tables, record_slots
from membrax.errors import OVERFLOWS, ErrorCode, SimulationError, describe
from membrax.membrane.candidates import (
    CandidateCapacities,
    candidate_capacities,
    cell_grid,
    fitted_candidate_capacities,
    grown_candidate_capacities,
)
from membrax.membrane.coupled import grow_candidates
from membrax.planning import balanced_order, check_batch, checked_order, plan_members, plan_periodic_members
from membrax.spheres.neighbors import allocate_shared
from membrax.triaxial.protocol import PHASES

__all__ = [
    "GEOMETRY_FIELDS",
    "BatchedTest",
    "PeriodicBatch",
    "StackedMembers",
    "build_batch",
    "build_periodic_batch",
    "cast_state",
    "describe_failure",
    "batch_template",
    "float32_batch",
    "table_capacities",
]


#: Mesh arrays that depend on the thickness (the rest geometry); the rest of the mesh is shared.
GEOMETRY_FIELDS = (
    "reference_position",
    "reference_inverse",
    "reference_area",
    "rest_dihedral",
    "edge_weight",
)


def _members(tree, count: int) -> list:
    """The first ``count`` members of a stacked pytree, as host (numpy) pytrees.

    The stacked arrays are copied to the host first, shard by shard: indexing a member out of an array
    sharded over devices would compile an SPMD gather with a cross-device all-reduce, which waits for every
    device, so a device still busy with its part of a chunk (launched asynchronously) stalls it, and XLA ends
    the process after 40 s. Host copies need no collective.
    """
    host = jax.device_get(tree)
    return [jax.tree_util.tree_map(lambda leaf, b=b: np.asarray(leaf)[b], host) for b in range(count)]


# ----------------------------------------------------------------------------------------------------------
# The batched test
# ----------------------------------------------------------------------------------------------------------


@pydataclasses.dataclass(kw_only=True)
class StackedMembers:
    """What every batch shares: members stacked on a leading axis, one compiled chunk, the driver's loop.

    A batch (:class:`BatchedTest`, the membrane cell's; :class:`PeriodicBatch`, the periodic element's) says
    what one member's chunk is (``_member_chunk``), how its tables grow (``grow``) and where a stacked state
    keeps its steps and error bits (``member_steps``, ``member_errors``). The rest is written here once: the
    chunk, ``lax.map`` (CPU) or ``vmap`` (GPU) over the members and sharded over devices with
    ``jax.shard_map``, and :meth:`run_phase` through :func:`membrax.driver.drive`.

    Attributes:
      settings: the members' :class:`membrax.assemble.RunSettings` (name, loading, chunk steps, ...).
      tests: the members' tests (built with the common Δt: each one alone runs the steps of its member).
      dt: the common time step, s.
      num_devices: devices the member axis is sharded over.
      mode: ``"map"`` (``lax.map``, CPU) or ``"vmap"`` (GPU).
      params: the members' stacked step parameters, padded to a multiple of ``num_devices``.
      members: stacked per-member constants.
      initial_state: stacked states at the start of consolidation.
      order: member b of the batch is the ``order[b]``-th configuration its builder was given.
      reallocations: table growths so far.
      failures: member → {"error", "step", "phase"} of the members a run froze (``isolate_failures``).
    """

    settings: list
    tests: list
    dt: float
    num_devices: int
    mode: str
    params: object
    members: dict
    initial_state: object
    order: list = pydataclasses.field(default_factory=list)
    reallocations: int = 0
    failures: dict = pydataclasses.field(default_factory=dict)

    def __post_init__(self):
        self._chunk = jax.jit(
            self._chunk_impl,
            static_argnames=("slots",),
            compiler_options=native.compiler_options(),
        )

    @property
    def num_members(self) -> int:
        """B, the real members (padding excluded)."""
        return len(self.tests)

    @property
    def num_padded(self) -> int:
        """Members including the frozen padding copies."""
        return int(np.shape(self.member_steps(self.initial_state))[0])

    def _member_chunk(self, state, params, member, left, num_records, record_every, slots: int):
        """One member's chunk: ``(state, left, records, valid)`` (a subclass's), :func:`budgeted_blocks`."""
        raise NotImplementedError

    def _chunk_impl(self, states, params, members, left, num_records, record_every, slots: int):
        """Every member's chunk: ``num_records`` blocks of ``record_every`` steps (both traced) in ``slots``.

        The cadence is an argument, not a constant, so every phase of a run (consolidation, the fine and
        the coarse shearing, each with its own record interval) runs the one compiled program.
        """

        def members_chunk(states, params, members, left, num_records, record_every):
            def one(state, param, member, budget):
                return self._member_chunk(state, param, member, budget, num_records, record_every, slots)

            if self.mode == "vmap":
                return jax.vmap(one)(states, params, members, left)
            return jax.lax.map(lambda xs: one(*xs), (states, params, members, left))

        if self.num_devices > 1:
            devices = np.asarray(jax.local_devices()[: self.num_devices])
            spec = jax.sharding.PartitionSpec("members")
            shared = jax.sharding.PartitionSpec()
            members_chunk = jax.shard_map(
                members_chunk,
                mesh=jax.sharding.Mesh(devices, ("members",)),
                in_specs=(spec, spec, spec, spec, shared, shared),
                out_specs=spec,
                check_vma=False,
            )
        return members_chunk(states, params, members, left, num_records, record_every)

    def restack(self, states: list):
        """Stack per-member states (real members) back, padding with frozen copies of member 0."""
        padded = list(states) + [states[0]] * (self.num_padded - len(states))
        return stack(padded)

    def unstack(self, states) -> list:
        """The real members' states of a stacked state."""
        return _members(states, self.num_members)

    def member_steps(self, states):
        """(B,) steps each member (padding included) of a stacked state has taken."""
        return states.dem.step

    def member_errors(self, states):
        """(B,) error bits of each member (padding included) of a stacked state."""
        return states.dem.error

    def overflow_tables(self, states):
        """What of an overflowing chunk's end states :meth:`grow` reads: the node candidate tables."""
        return states.membrane.candidates

    def run_phase(
        self,
        states,
        budgets,
        chunk_steps: int,
        record_every: int,
        stop_fn: Callable | None = None,
        on_chunk: Callable | None = None,
        on_failure: Callable | None = None,
        slots: int = 0,
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
          slots: record slots of the compiled chunk, at least this phase's records per chunk: the same
            for every phase of a run (the most records per chunk of any), so they run one program.

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

        slots = max(slots, record_slots(chunk_steps, [record_every]))

        def chunk(states, left, num_records):
            return self._chunk(
                states,
                self.params,
                self.members,
                jnp.asarray(left),
                np.int32(num_records),
                np.int32(record_every),
                slots=slots,
            )

        def fail(error, new, states):
            bad = int(np.flatnonzero(error[:num])[0])
            return SimulationError(
                f"member {bad} ({self.settings[bad].name}) stopped in the chunk ending at step "
                f"{int(np.asarray(self.member_steps(new))[bad])}: " + "; ".join(describe(error[bad])),
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
            steps = np.asarray(self.member_steps(new))
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
            errors=lambda s: np.asarray(self.member_errors(s)) & real_bits,
            grow=lambda s, error, overflowed: self.grow(s, error, self.overflow_tables(overflowed)),
            fail=fail,
            accept=accept,
            isolate=None if on_failure is None else isolate,
            # Under lax.map a spent budget's blocks are skipped by their cond (budgeted_blocks), so a stage's
            # last chunk can be a whole one, with no program of its own; under vmap they would run.
            whole_chunks=self.mode == "map",
        )
        return states, left[:num]


@pydataclasses.dataclass(kw_only=True)
class BatchedTest(StackedMembers):
    """Members of one compiled batch (built by :func:`build_batch`); arrays stacked on a member axis.

    Attributes (beside :class:`StackedMembers`'):
      configs: the members' configurations (handed to :mod:`membrax.assemble` only, never read here).
      nodes_around: the common n_θ.

    ``tests`` are the members' :class:`MembraneTest` (the common Δt and n_θ), ``params`` the stacked
    :class:`membrax.membrane.coupled.CoupledParams`, ``members`` the mesh's rest geometry and the initial
    inner volume of each, ``initial_state`` the stacked states at the start of consolidation (servo on);
    member b is ``configs[order[b]]`` of :func:`build_batch`'s argument.
    """

    configs: list
    nodes_around: int

    def _member_chunk(self, state, params, member, left, num_records, record_every, slots: int):
        template = self.tests[0]
        mesh = template.mesh.set(**{name: member[name] for name in GEOMETRY_FIELDS})
        # The Gent stiffening check at the strictest member's limit (each member's own Δt_crit, one Δt).
        step = template.make_step(mesh, min(t.tangent_limit for t in self.tests))
        record = template.make_record(mesh, member["initial_volume"])
        return budgeted_blocks(step, record, state, params, left, num_records, record_every, slots)

    def grow(self, states, error, overflowed):
        """Every member's tables that overflowed grown to one larger capacity (:func:`grow_tables`).

        Args:
          states: the stacked states (padded) to grow.
          error: the members' error bits, (B,) or ORed.
          overflowed: the overflowing chunk's end candidate tables (stacked), or None.

        Returns:
          The grown stacked states.
        """

        def grow_membrane(members, end):
            return self._with_capacities(members, grown_candidate_capacities(states.membrane.candidates, end))

        members = grow_tables(
            _members(states, self.num_padded),
            int(np.bitwise_or.reduce(np.atleast_1d(error))),
            self.tests[0].runner.neighbor_frame,
            dem_of=lambda state: state.dem,
            with_dem=lambda state, dem: state.set(dem=dem),
            grow_membrane=grow_membrane,
            overflowed=overflowed,
        )
        self.reallocations += 1
        return stack(members)

    def fitted(self, states):
        """``states`` with node candidate rows no wider than the members' largest count + 2.

        For a resumed batch, whose tables may have been grown for a passing need
        (:func:`membrax.membrane.candidates.fitted_candidate_capacities`). The width changes no bit; the same
        states where nothing is cut.
        """
        capacities = fitted_candidate_capacities(states.membrane.candidates)
        if capacities == candidate_capacities(states.membrane.candidates):
            return states
        return stack(self._with_capacities(_members(states, self.num_padded), capacities))

    def _with_capacities(self, members, capacities) -> list:
        """Each member's state (padded ones too) with a node candidate table of ``capacities``."""
        particles, mesh = self.tests[0].particles, self.tests[0].mesh
        thickness = np.asarray(self.params.membrane.contact_thickness)
        return [grow_candidates(m, particles, capacities, thickness[b], mesh) for b, m in enumerate(members)]


@pydataclasses.dataclass(kw_only=True)
class PeriodicBatch(StackedMembers):
    """Periodic elements of one packing stacked in one compiled batch (built by :func:`build_periodic_batch`).

    Every member is the same cell (:class:`membrax.triaxial.periodic.PeriodicTest`: spheres, Δt, neighbour
    frame) with its own parameters (contact law, damping: traced), its own box controls in its state (σc,
    the servo's rate limit, the shearing rate) and its own stages' budgets and stop tests (its test's
    ``phase_plan`` and ``is_consolidated``). The members' neighbour lists have one shape: one cell grid and
    one capacity (:meth:`membrax.spheres.neighbors.PeriodicNeighborFn.reallocate_shared`), grown together
    through :func:`membrax.driver.grow_tables` with the cell's ``allocate`` hook
    (:meth:`membrax.triaxial.periodic.PeriodicRunner.allocate_list`) when any member's list overflows or its
    box outgrows the cells.

    :class:`StackedMembers`' attributes: ``tests`` the members'
    :class:`~membrax.triaxial.periodic.PeriodicTest` (one packing), ``params`` their stacked
    :class:`membrax.spheres.integrate.DEMParams`, ``members`` none (an empty dict), ``initial_state`` the
    stacked :class:`~membrax.triaxial.periodic.PeriodicState` at the start of consolidation.
    """

    def _member_chunk(self, state, params, member, left, num_records, record_every, slots: int):
        del member
        runner = self.tests[0].runner
        return budgeted_blocks(
            runner.step_fn, runner.record_fn, state, params, left, num_records, record_every, slots
        )

    def member_steps(self, states):
        """(B,) steps of each member: the cell's state holds them itself."""
        return states.step

    def member_errors(self, states):
        """(B,) error bits of each member: the cell's state holds them itself."""
        return states.error

    def overflow_tables(self, states):
        """The overflowing chunk's end states (their lists and boxes size the new lists)."""
        return states

    def grow(self, states, error, overflowed):
        """Every member's list allocated afresh in one shape (:func:`grow_tables`, the cell's ``allocate``).

        Args:
          states: the stacked states (padded) at the chunk's start.
          error: the members' error bits, (B,) or ORed.
          overflowed: the overflowing chunk's end states (stacked).

        Returns:
          The grown stacked states.
        """
        runner = self.tests[0].runner
        members = grow_tables(
            _members(states, self.num_padded),
            int(np.bitwise_or.reduce(np.atleast_1d(error))),
            runner.neighbor_frame,
            with_dem=runner.with_list_at_box,
            overflowed=_members(overflowed, self.num_padded),
            capacity_growth=runner.capacity_growth,
            allocate=runner.allocate_list,
        )
        self.reallocations += 1
        return stack(members)

    def list_shape(self, states) -> dict:
        """What fixes the shape of the members' lists (:meth:`template`'s argument), plain values."""
        return self.tests[0].list_shape(_members(states, 1)[0])

    def template(self, list_shape: dict):
        """The stacked initial state with lists of ``list_shape`` (a checkpoint's template)."""
        return stack([self.tests[0].template(**list_shape)] * self.num_padded)


def build_periodic_batch(
    configs: Sequence[TriaxialConfig],
    num_devices: int | None = None,
    mode: str | None = None,
    order: Sequence[int] | None = None,
) -> PeriodicBatch:
    """Build the periodic elements of one batch: ``cell = "periodic"`` members of one packing.

    The members may differ in :data:`membrax.assemble.BATCHED_FIELDS` but in neither the particle stiffness
    (it makes the packing and Δt) nor whether the spheres are frictionless (the rattler rule of z*):
    :func:`membrax.assemble.structure_key` holds both for a periodic cell.

    Args:
      configs: the members' configurations.
      num_devices: devices to shard the member axis over (default: every local device, at most one a member).
      mode: ``"map"`` or ``"vmap"`` (default: ``"vmap"`` on a GPU, ``"map"`` otherwise).
      order: the members' order on the batch axis (default :func:`membrax.planning.balanced_order` of their
        planned steps).

    Raises:
      ValueError: no members, members of different structure, a bad mode or device count.
    """
    configs = list(configs)
    mode, num_devices = check_batch(configs, num_devices, mode)
    tests, _, work = plan_periodic_members(configs)
    settings = [run_settings(c) for c in configs]
    if order is None:
        order = balanced_order(work, num_devices)
    order = checked_order(order, len(configs))
    tests, settings = [tests[i] for i in order], [settings[i] for i in order]
    # The members start at the protocol's first phase, their lists rebuilt from one template.
    states = [t.start_phase(PHASES[0], t.initial_state) for t in tests]
    cells = functools.reduce(jnp.minimum, [s.cell_length for s in states])
    lists = tests[0].runner.neighbor_frame.reallocate_shared(
        [s.fraction for s in states], [s.box_length for s in states], cells
    )
    states = [s.set(neighbors=nl, cell_length=cells) for s, nl in zip(states, lists, strict=True)]
    num_padded = num_devices * math.ceil(len(tests) / num_devices)
    slots = list(range(len(tests))) + [0] * (num_padded - len(tests))
    return PeriodicBatch(
        settings=settings,
        tests=tests,
        dt=float(tests[0].dt),
        num_devices=num_devices,
        mode=mode,
        params=stack([tests[b].params for b in slots]),
        members={},
        initial_state=stack([states[b] for b in slots]),
        order=order,
    )


def describe_failure(failure: dict) -> str:
    """A failed member's record as one line: the error's name, the phase and the step."""
    return f"{failure['error']} in {failure['phase']} (chunk ending at step {failure['step']})"


def _common_candidate_tables(states, particles, thicknesses, mesh=None) -> list:
    """The members' node candidate tables on one grid, one reach and one set of capacities, so they stack.

    A table's grid and reach are static (they shape the compiled step), and under face contact each
    member's reach adds its own mesh's longest edge, which differs with t_m (the mesh sits at t_m/2 off
    the specimen): members of one batch then cannot be stacked. Every table is rebuilt with the largest
    reach and capacities of them all, on the grid :func:`membrax.membrane.candidates.cell_grid` gives the
    spheres for it (a longer reach only adds candidates, never drops one); states whose tables already
    agree are returned as they are.

    Args:
      states: the members' states (their spheres on the same positions: one specimen).
      particles: sphere properties.
      thicknesses: each member's contact thickness f t_m, m.
      mesh: the membrane's topology (for states with feature contacts).
    """
    states = list(states)
    tables = [s.membrane.candidates for s in states]
    if (
        len({(t.grid, t.extra_reach) for t in tables}) <= 1
        and len({candidate_capacities(t) for t in tables}) <= 1
    ):
        return states
    reach = max(float(t.extra_reach) for t in tables)
    capacities = CandidateCapacities(*(max(c) for c in zip(*map(candidate_capacities, tables), strict=True)))
    grid = cell_grid(states[0].dem.position, particles.radius, float(tables[0].skin) + reach)
    return [
        grow_candidates(s, particles, capacities, thickness, mesh, grid=grid, extra_reach=reach)
        for s, thickness in zip(states, thicknesses, strict=True)
    ]


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
        :func:`membrax.planning.balanced_order` of each member's planned shear steps plus two chunks of
        consolidation).
        The batch's ``configs`` and ``tests`` are in this order, and ``BatchedTest.order`` keeps it.
      time_step: the common Δt, s (default: the smallest of the members' own).
      nodes_around: the common n_θ (default: :func:`membrax.assemble.common_nodes_around`).

    Raises:
      ValueError: no members, members that differ in a field outside :data:`BATCHED_FIELDS`, a bad mode
        or device count.
    """
    configs = list(configs)
    mode, num_devices = check_batch(configs, num_devices, mode)
    tests, dt, nodes_around, work = plan_members(configs, time_step, nodes_around)
    if order is None:
        order = balanced_order(work, num_devices)
    order = checked_order(order, len(configs))
    configs, tests = [configs[i] for i in order], [tests[i] for i in order]
    # The members start at the protocol's first phase; membrax.runner.run_group enters the others.
    states = [t.start_phase(PHASES[0], t.initial_state) for t in tests]
    # One grid, reach and capacities for the members' node tables (face contact's reach differs with t_m).
    states = _common_candidate_tables(
        states, tests[0].particles, [t.params.membrane.contact_thickness for t in tests], tests[0].mesh
    )
    lists = allocate_shared(tests[0].runner.neighbor_frame, [s.dem.position for s in states])
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
        settings=[run_settings(c) for c in configs],
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
# Tables and precision (what a checkpoint and the float32 shearing need)
# ----------------------------------------------------------------------------------------------------------


def table_capacities(states) -> dict:
    """The capacities of a stacked state's tables (neighbour pairs, cells, node candidates), by name."""
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


def batch_template(batch: BatchedTest, capacities: dict):
    """The batch's initial state grown to a checkpoint's capacities (the loader's shape template)."""
    states = batch.initial_state
    if table_capacities(states) == capacities:
        return states
    members = _members(states, batch.num_padded)
    thickness = np.asarray(batch.params.membrane.contact_thickness)
    particles = batch.tests[0].particles
    members = [
        grow_candidates(m, particles, _node_capacities(capacities), thickness[b], batch.tests[0].mesh)
        for b, m in enumerate(members)
    ]
    lists = allocate_shared(
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
