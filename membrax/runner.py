"""The runner: a batch of tests from configurations, through consolidation and shearing.

Contract. Every test that runs to a results folder goes through here, alone or in a grid, a membrane cell
or a periodic element: a single test (:func:`membrax.run.run_test`) is a batch of one, a sweep
(:func:`membrax.sweep.run_sweep`) runs its grid as batches. :func:`membrax.executor.build_batch` builds the
members of one compiled batch (:class:`~membrax.executor.BatchedTest`: states stacked on a member axis, one
Δt, one mesh topology, each member's plain :class:`~membrax.assemble.RunSettings`; the runner never reads a
configuration), :func:`membrax.executor.build_periodic_batch` those of periodic elements of one packing
(:class:`~membrax.executor.PeriodicBatch`), and :func:`run_group`, the one phase loop, takes either through
the protocol's stage sequence (:data:`membrax.triaxial.protocol.PHASES`,
each phase started by :meth:`~membrax.triaxial.protocol.StagedTest.start_phase`, each member's steps and
record intervals from :meth:`~membrax.triaxial.protocol.StagedTest.phase_plan` of its loading):

- ``consolidation``: the ram servo on (a periodic element's: its box's), until each member's own stop
  test holds (:meth:`membrax.triaxial.membrane_cell.MembraneTest.is_consolidated`) or it reaches
  ``consolidation_max_steps``;
- ``shear_fine`` and ``shear_coarse``: drained shearing at the strain rate of ``inertial_number``
  (ramped from rest), recorded every ``record_every_fine`` steps below ``fine_until_strain`` and every
  ``record_every_coarse`` steps after, to ``target_axial_strain``; after ``fine_until_strain`` at the
  rate of ``coarse_inertial_number`` where it is set (the speed changed linearly over
  ``shear_ramp_strain``).

Every phase runs the one compiled chunk: its record interval and blocks per chunk are arguments, its record
slots those of the phase with the most records per chunk (:func:`membrax.driver.budgeted_blocks`).
The loop (:func:`membrax.driver.drive`) reallocates tables and checks error bits; :func:`run_group` adds
what a long run needs: a progress bar per phase, a checkpoint (stacked state, records so far, budgets)
every ``checkpoint_every_chunks`` chunks and at each phase's end, ``resume`` continuing to results
identical to an uninterrupted run, a runaway-energy stop (kinetic energy above
:data:`RUNAWAY_KINETIC_FRACTION` × σc V₀) that raises :class:`RunError` with the records so far, and an
``after_chunk`` hook (VTK snapshots). :mod:`membrax.run_records` turns a member's records into the shearing
and consolidation datasets (strains and areas counted from the start of shearing).

Batching: :mod:`membrax.executor`; configurations become tests in :mod:`membrax.assemble`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from membrax.driver import record_slots
from membrax.errors import RunError, SimulationError
from membrax.executor import (
    PeriodicBatch,
    StackedMembers,
    batch_template,
    cast_state,
    float32_batch,
    table_capacities,
)
from membrax.io import load_checkpoint, read_checkpoint_host, save_checkpoint
from membrax.run_records import join_records, records_from_host, records_to_host
from membrax.triaxial import analysis
from membrax.triaxial.protocol import PHASES

__all__ = [
    "CHECKPOINT_NAME",
    "RUNAWAY_KINETIC_FRACTION",
    "phase_bar",
    "run_group",
    "stop_runaways",
]


#: Kinetic energy above this fraction of σc V₀ stops the run (a quasi-static test stays below 1e-4).
RUNAWAY_KINETIC_FRACTION = 0.05


CHECKPOINT_NAME = "checkpoint.npz"


#: Records a single test's progress bar reads (axial strain and the paper's §4.3 stresses).
_PROGRESS = (
    "axial_strain",
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
)


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
    batch: StackedMembers,
    folder: Path,
    resume: bool = False,
    progress: bool = True,
    interrupt_after_chunks: int | None = None,
    chunk_counter: list | None = None,
    after_chunk: Callable | None = None,
    isolate_failures: bool = False,
):
    """Run one batch through the three phases of :data:`PHASES` (module docstring): the one phase loop.

    A batch of membrane cells (:class:`~membrax.executor.BatchedTest`) and one of periodic elements
    (:class:`~membrax.executor.PeriodicBatch`) take the same steps, each a function below:
    :func:`_start_group` (afresh, or from the checkpoint), then for each phase :func:`_enter_phase` (the
    protocol's :meth:`~membrax.triaxial.protocol.StagedTest.start_phase` on every member, the budgets of its
    :meth:`~membrax.triaxial.protocol.StagedTest.phase_plan`) and :func:`_advance_phase` (the driver's loop,
    watched chunk by chunk by :func:`_on_chunk`), a checkpoint at each phase's end (:func:`_save`). What the
    two cells do differently (the checkpoint's table shapes, the start of shearing, the bar's postfix) their
    groups say: :class:`_MembraneGroup`, :class:`_PeriodicGroup`.

    With ``float32_shearing`` (and ``float64``) a membrane batch consolidates in float64 and shears in
    float32: at the start of shearing the batch is rebuilt in float32 (:func:`float32_batch`) and the state
    carried over (:func:`cast_state`); the rest runs inside ``jax.enable_x64(False)``.

    Args:
      batch: from :func:`build_batch` or :func:`membrax.executor.build_periodic_batch`.
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
      shearing per member: height, volume and platen area (None for a periodic element, whose records count
      their strains themselves); the elapsed seconds).

    Raises:
      RunError: a member blew up (error bits or runaway kinetic energy); ``error.records`` holds the
        records so far, as returned.
    """
    hooks = _Hooks(
        progress=progress,
        isolate_failures=isolate_failures,
        after_chunk=after_chunk,
        chunk_counter=[0] if chunk_counter is None else chunk_counter,
        interrupt_after_chunks=interrupt_after_chunks,
    )
    # scope holds the float32 shearing's enable_x64(False) until the group ends.
    with contextlib.ExitStack() as scope:
        group = _start_group(batch, folder / CHECKPOINT_NAME, resume, scope)
        while group.phase_index < len(PHASES):
            phase = PHASES[group.phase_index]
            if group.budgets is None:
                _enter_phase(group, phase, scope)
            _advance_phase(group, phase, hooks)
            group.phase_index += 1
            group.budgets = None
            _save(group, group.states, None)
        group.elapsed += time.perf_counter() - group.clock
        return group.records, group.shear_starts(), group.elapsed


@dataclasses.dataclass(frozen=True)
class _Hooks:
    """What a caller of :func:`run_group` adds to the run (its arguments of the same names)."""

    progress: bool
    isolate_failures: bool
    after_chunk: Callable | None
    chunk_counter: list
    interrupt_after_chunks: int | None


@dataclasses.dataclass
class _Group:
    """Where a group stands in the protocol, shared by :func:`run_group`'s steps (what a checkpoint keeps).

    ``plans`` (each member's :meth:`~membrax.triaxial.protocol.StagedTest.phase_plan`) and ``volume_work``
    (σc V₀, the runaway scale) are the batch's at the start of this call; ``clock`` the wall clock at its
    start. A kind of batch says the rest in a subclass: what its checkpoint keeps beside the states and the
    records (:meth:`host_values`, :meth:`template`, :meth:`restore`), what changes at a phase's start beside
    the protocol's switch (:meth:`enter`), the bar's postfix and each member's start of shearing.
    """

    #: The checkpoint's names of the phase index and of the elapsed seconds.
    phase_key = "phase_index"
    elapsed_key = "elapsed_s"
    #: What to lower beside ``dt_safety`` when a member blows up.
    stiffness_advice = "particle_stiffness_n_m"

    batch: StackedMembers
    checkpoint: Path
    states: object
    records: dict
    failures: dict
    plans: list = dataclasses.field(default_factory=list)
    volume_work: np.ndarray | None = None
    phase_index: int = 0
    elapsed: float = 0.0
    budgets: np.ndarray | None = None
    clock: float = 0.0

    @property
    def settings(self):
        """The settings the members share (chunk steps, checkpoints, precision: not batched fields)."""
        return self.batch.settings[0]

    def host_values(self, current) -> dict:
        """The checkpoint's values of this kind: what sizes :meth:`template`, what :meth:`restore` reads."""
        raise NotImplementedError

    def template(self, host: dict, scope):
        """The stacked states a checkpoint with ``host`` loads into."""
        raise NotImplementedError

    def restore(self, host: dict) -> None:
        """Put back this kind's values of a checkpoint's ``host`` (none by default)."""

    def enter(self, phase: str, scope) -> None:
        """What changes at ``phase``'s start before the protocol switches the members (nothing by default)."""

    def postfix(self, phase: str, current, chunk: dict, left) -> dict:
        """The bar's postfix after a chunk: where the group stands (tqdm sorts the keys)."""
        raise NotImplementedError

    def shear_starts(self) -> list:
        """Each member's start of shearing, as :func:`run_group` returns it."""
        raise NotImplementedError


@dataclasses.dataclass
class _MembraneGroup(_Group):
    """A batch of membrane cells (:class:`~membrax.executor.BatchedTest`) in :func:`run_group`.

    ``batch`` is the float32 rebuild once the float32 shearing has begun; ``shear_height`` and
    ``shear_volume`` each member's at the start of shearing (strains count from them).
    """

    stiffness_advice = (
        "particle_stiffness_n_m; a membrane modulus far above the paper's 1400 kPa also shortens the "
        "stable step"
    )

    shear_height: np.ndarray | None = None
    shear_volume: np.ndarray | None = None

    def __post_init__(self):
        self.shear_height = np.zeros(self.batch.num_members)
        self.shear_volume = np.zeros(self.batch.num_members)

    @property
    def float32_shearing(self) -> bool:
        return self.settings.float64 and self.settings.float32_shearing

    def host_values(self, current) -> dict:
        """The tables' capacities, the precision and the start of shearing."""
        return {
            "capacities": table_capacities(current),
            "shear_height": self.shear_height,
            "shear_volume": self.shear_volume,
            "dtype": str(np.dtype(current.dem.position.dtype)),
        }

    def template(self, host: dict, scope):
        """The batch's states with the checkpoint's capacities (in float32 where its shearing was)."""
        if self.float32_shearing and host.get("dtype") == "float32":
            _to_float32(self, scope)
        return batch_template(self.batch, host["capacities"])

    def restore(self, host: dict) -> None:
        """The start of shearing of each member, and node candidate tables no wider than they need be.

        A width grown for a passing need changes no bit but would slow every step left
        (:meth:`membrax.executor.BatchedTest.fitted`).
        """
        self.shear_height = np.asarray(host["shear_height"])
        self.shear_volume = np.asarray(host["shear_volume"])
        self.states = self.batch.fitted(self.states)

    def enter(self, phase: str, scope) -> None:
        """At the start of shearing the float32 shearing begins and each member's height and volume are kept.

        Strains count from them (:func:`rebase_to_shear_start`).
        """
        if phase == "shear_fine" and self.float32_shearing:
            capacities = table_capacities(self.states)
            _to_float32(self, scope)
            self.states = cast_state(self.states, batch_template(self.batch, capacities))
        if phase == "shear_fine":
            for b in range(self.batch.num_members):
                if b not in self.failures:  # frozen: it never shears
                    self.shear_height[b] = _last_member_value(self.records["consolidation"], "height", b)
                    self.shear_volume[b] = _last_member_value(self.records["consolidation"], "volume", b)

    def postfix(self, phase: str, current, chunk: dict, left) -> dict:
        """Where the group stands after a chunk.

        In consolidation the worst member's unbalanced-force ratio against the stop value; in a single
        test's shearing its axial strain and φ' (the paper's Fig. 5); in a batch's the members still going.
        """
        num = self.batch.num_members
        active = int(np.sum(left > 0))
        if phase == "consolidation":
            ratio = chunk["unbalanced_force_ratio"].reshape(num, chunk["valid"].shape[1], -1)[..., 0]
            last = [ratio[b][chunk["valid"][b]][-1] for b in range(num) if chunk["valid"][b].any()]
            return {
                "unbalanced": f"{max(last, default=0.0):.1e}",
                "until": f"{min(s.consolidation_tolerance for s in self.batch.settings):.0e}",
                **({} if num == 1 else {"active": active}),
            }
        if num > 1:
            return {"active": active, "step": int(np.max(np.asarray(self.batch.member_steps(current))))}
        valid = chunk["valid"][0]
        last = {name: float(chunk[name][0][valid][-1].ravel()[0]) for name in _PROGRESS}
        external, internal = analysis.friction_angle_deg(
            [last["external_axial_stress"], last["internal_axial_stress"]],
            [last["external_radial_stress"], last["internal_radial_stress"]],
        )
        return {
            "strain": f"{100 * last['axial_strain']:.3f}%",
            "phi_ext": f"{external:.1f}",
            "phi_int": f"{internal:.1f}",
        }

    def shear_starts(self) -> list[dict]:
        """Each member's height, volume and platen area at the start of shearing."""
        return [
            {"height": self.shear_height[b], "volume": self.shear_volume[b], "platen_area": test.platen_area}
            for b, test in enumerate(self.batch.tests)
        ]


@dataclasses.dataclass
class _PeriodicGroup(_Group):
    """A batch of periodic elements (:class:`~membrax.executor.PeriodicBatch`) in :func:`run_group`.

    Its checkpoint names the phase ``phase`` and the elapsed seconds ``elapsed`` and keeps the shape of the
    members' lists (:meth:`PeriodicBatch.list_shape`); nothing changes at a phase's start beside the
    protocol's switch, and its records count their strains themselves
    (:func:`membrax.run.periodic_datasets`).
    """

    phase_key = "phase"
    elapsed_key = "elapsed"

    def host_values(self, current) -> dict:
        """The shape of the members' lists."""
        return {"list_shape": self.batch.list_shape(current)}

    def template(self, host: dict, scope):
        """The batch's states with lists of the checkpoint's shape."""
        return self.batch.template(host["list_shape"])

    def postfix(self, phase: str, current, chunk: dict, left) -> dict:
        """The chunk's largest unbalanced-force ratio and the members still going."""
        ratio = chunk["unbalanced_force_ratio"][chunk["valid"]]
        return {"ufr": f"{np.max(ratio, initial=0.0):.1e}", "active": int(np.sum(left > 0))}

    def shear_starts(self) -> list:
        """None for each member."""
        return [None] * self.batch.num_members


def _start_group(batch: StackedMembers, checkpoint: Path, resume: bool, scope) -> _Group:
    """The group at the start of consolidation, or where the checkpoint left it (``resume``)."""
    kind = _PeriodicGroup if isinstance(batch, PeriodicBatch) else _MembraneGroup
    group = kind(
        batch=batch,
        checkpoint=checkpoint,
        states=batch.initial_state,
        records={phase: [] for phase in PHASES},
        failures={},
    )
    batch.failures = group.failures
    if resume and checkpoint.exists():
        _load(group, scope)
    tests, settings = group.batch.tests, group.batch.settings
    group.plans = [t.phase_plan(s.loading) for t, s in zip(tests, settings, strict=True)]
    group.volume_work = np.array([t.cell_pressure * t.initial_volume for t in tests])
    group.clock = time.perf_counter()
    return group


def _load(group: _Group, scope) -> None:
    """Restore ``group`` from its checkpoint."""
    template = group.template(read_checkpoint_host(group.checkpoint), scope)
    group.states, host = load_checkpoint(group.checkpoint, template)
    group.phase_index, group.elapsed = host[group.phase_key], host[group.elapsed_key]
    group.budgets = None if host["budgets"] is None else np.asarray(host["budgets"], dtype=np.int64)
    group.failures.update({int(b): failure for b, failure in host.get("failures", {}).items()})
    group.records.update(records_from_host(host))
    group.restore(host)


def _save(group: _Group, current, budgets) -> None:
    """A checkpoint of ``current`` (stacked states) with the records so far and the phase's budgets."""
    num = group.batch.num_members
    host = {
        group.phase_key: group.phase_index,
        group.elapsed_key: group.elapsed + time.perf_counter() - group.clock,
        # None at a phase's end: the next phase computes its budgets (and starts shearing) on resume.
        "budgets": None if budgets is None else [int(v) for v in budgets],
        "member_steps": [int(v) for v in np.asarray(group.batch.member_steps(current))[:num]],
        "failures": {str(b): failure for b, failure in group.failures.items()},
        **group.host_values(current),
        **records_to_host(group.records),
    }
    save_checkpoint(group.checkpoint, current, host)


def _to_float32(group: _MembraneGroup, scope) -> None:
    """Rebuild the batch in float32 and run the rest in float32 (once)."""
    if np.dtype(group.batch.initial_state.dem.position.dtype) == np.float32:
        return
    scope.enter_context(jax.enable_x64(False))
    group.batch = float32_batch(group.batch)


def _enter_phase(group: _Group, phase: str, scope) -> None:
    """Start ``phase``: the group's own start, every member not frozen switched, each one's step budget.

    What the group's kind changes comes first (:meth:`_Group.enter`), then the protocol's switch. The
    batch was built at the first phase's start (:func:`membrax.executor.build_batch`,
    :func:`membrax.executor.build_periodic_batch`).
    """
    group.enter(phase, scope)
    if phase != PHASES[0]:
        group.states = _start_members(group, phase)
    group.budgets = np.array([plan[phase][0] for plan in group.plans], dtype=np.int64)
    group.budgets[list(group.failures)] = 0  # a failed member stays frozen


def _start_members(group: _Group, phase: str):
    """The stacked states with each member not frozen switched to ``phase``'s start (its own loading)."""
    batch = group.batch
    members = batch.unstack(group.states)
    started = [
        member if b in group.failures else test.start_phase(phase, member, settings.loading)
        for b, (member, test, settings) in enumerate(zip(members, batch.tests, batch.settings, strict=True))
    ]
    if all(new is old for new, old in zip(started, members, strict=True)):
        return group.states  # nothing changes at this phase's start (no member changes its rate)
    return batch.restack(started)


def _advance_phase(group: _Group, phase: str, hooks: _Hooks) -> None:
    """Run ``phase`` until every member's budget is spent (the driver's loop), a bar showing progress."""
    settings, num = group.settings, group.batch.num_members
    record_every = group.plans[0][phase][1]  # not a batched field: the same for every member
    total = int(np.ceil(np.max(group.budgets, initial=0) / record_every) * record_every)
    bar = phase_bar(phase, num, total, hooks.progress)

    def on_failure(b, names, step):
        group.failures[b] = {"error": names, "step": step, "phase": phase}

    def on_chunk(current, chunk, left):
        return _on_chunk(group, phase, hooks, bar, on_failure, current, chunk, left)

    stop_fn = None
    if phase == "consolidation":
        tolerances = [s.consolidation_tolerance for s in group.batch.settings]

        def stop_fn(b, mine):
            return group.batch.tests[b].is_consolidated(mine, tolerances[b])

    try:
        group.states, group.budgets = group.batch.run_phase(
            group.states,
            group.budgets,
            settings.chunk_steps,
            record_every,
            stop_fn=stop_fn,
            on_chunk=on_chunk,
            on_failure=on_failure if hooks.isolate_failures else None,
            # Room for the most records per chunk of any phase: every phase runs the one compiled chunk.
            slots=record_slots(settings.chunk_steps, [every for _, every in group.plans[0].values()]),
        )
    except SimulationError as error:
        raise RunError(
            f"{error}. Lower dt_safety (now {settings.dt_safety}) or {group.stiffness_advice}.",
            group.records,
        ) from error
    except RunError as error:
        error.records = group.records
        raise
    finally:
        bar.close()


def _on_chunk(group: _Group, phase: str, hooks: _Hooks, bar, on_failure, current, chunk, left) -> list:
    """After each accepted chunk: the runaway check, the records, the bar, the hook and the checkpoint."""
    stop = _runaways(group, phase, hooks, on_failure, current, chunk)
    # A member frozen by this chunk has no steps left, in the checkpoint too: resumed, it stays frozen.
    left = left.copy()
    left[stop] = 0
    group.budgets = left
    group.records[phase].append(chunk)
    bar.update(int(chunk["valid"].any(axis=0).sum()) * group.plans[0][phase][1])  # the blocks that ran
    bar.set_postfix(**group.postfix(phase, current, chunk, left))
    if hooks.after_chunk is not None:
        hooks.after_chunk(current, phase)
    hooks.chunk_counter[0] += 1
    if hooks.chunk_counter[0] % group.settings.checkpoint_every_chunks == 0:
        _save(group, current, left)
    if hooks.interrupt_after_chunks is not None and hooks.chunk_counter[0] >= hooks.interrupt_after_chunks:
        raise KeyboardInterrupt(f"interrupted after {hooks.chunk_counter[0]} chunks (testing aid)")
    return stop


def _runaways(group: _Group, phase: str, hooks: _Hooks, on_failure, current, chunk) -> list[int]:
    """Members whose kinetic energy ran away in ``chunk``: frozen (``isolate_failures``) or raised."""
    return stop_runaways(
        chunk,
        group.volume_work,
        group.failures,
        [s.name for s in group.batch.settings],
        np.asarray(group.batch.member_steps(current)),
        group.settings.dt_safety,
        on_failure if hooks.isolate_failures else None,
        [_membrane_hint(test) for test in group.batch.tests],
    )


def stop_runaways(
    chunk: dict, volume_work, frozen, names, steps, dt_safety: float, on_failure=None, hints=None
) -> list:
    """The runaway-energy stop of a batch's chunk: members whose kinetic energy ran away, frozen or raised.

    A member runs away when the kinetic energy of its chunk's last record is not finite or exceeds
    :data:`RUNAWAY_KINETIC_FRACTION` × σc V₀ (the work scale of the cell pressure). Every group of
    :func:`run_group` checks its chunks with it, membrane cells and periodic elements alike.

    Args:
      chunk: the chunk's stacked records (``kinetic_energy`` (B, T, ...) and ``valid`` (B, T), writable).
      volume_work: (B,) each member's σc V₀, J.
      frozen: members already failed (not checked again).
      names: the members' names, for the message.
      steps: (B,) each member's steps at the chunk's end.
      dt_safety: the members' ``dt_safety``, for the message's hint.
      on_failure: ``on_failure(member, "RUNAWAY_KINETIC_ENERGY", step)``: failure isolation, the member's
        records of the chunk are masked (``valid`` False: frozen at its last good records) and it is returned
        to be stopped. None: the first runaway raises.
      hints: each member's further advice for the message (a Gent membrane's stable stretch), or None.

    Returns:
      The members to stop now.

    Raises:
      RunError: a runaway without ``on_failure``, naming the member, its energy and the bound.
    """
    volume_work = np.asarray(volume_work, dtype=np.float64)
    num = volume_work.size
    kinetic = chunk["kinetic_energy"].reshape(num, chunk["valid"].shape[1], -1)[:, -1, 0]
    limit = RUNAWAY_KINETIC_FRACTION * volume_work
    runaway = ~np.isfinite(kinetic) | (kinetic > limit)
    runaway[list(frozen)] = False
    stop = []
    for b in np.flatnonzero(runaway):
        message = (
            f"member {b} ({names[b]}): kinetic energy {kinetic[b]:.3g} J exceeds "
            f"{RUNAWAY_KINETIC_FRACTION} σc V₀ = {limit[b]:.3g} J: the run is unstable. Lower dt_safety "
            f"(now {dt_safety}) or the stiffness." + (hints[b] if hints is not None else "")
        )
        if on_failure is None:
            raise RunError(message)
        chunk["valid"][b] = False  # frozen at its last good records
        stop.append(int(b))
        on_failure(int(b), "RUNAWAY_KINETIC_ENERGY", int(np.asarray(steps)[b]))
    return stop


def _membrane_hint(test) -> str:
    """For a Gent membrane, its stable stretch: the membrane stiffens toward its lock (docs/model.md)."""
    stable = getattr(test, "stable_locking_ratio", math.inf)
    if math.isinf(stable):
        return ""
    return (
        f" The membrane (Gent) is stable to (I1 - 3)/J_m = {stable:.3f} at this step "
        "(ErrorCode.MEMBRANE_STIFFENED past it): raise membrane_locking_jm or lower the cell pressure."
    )
