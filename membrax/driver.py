"""The chunk driver: a Python loop over jitted ``lax.scan`` chunks, the one long-run loop of membrax.

Contract. :func:`drive` is the one long-run loop of membrax. It advances a state (one specimen, or a
stack of batch members each with its own step budget) by whole compiled chunks and, between chunks, on
the host:

- checks the error bits of the state (:mod:`membrax.errors`);
- on a neighbour-list or candidate-table overflow, grows the tables from the *chunk's starting state*
  (the neighbour list reallocated, contact history carried over by partner id) and reruns the chunk —
  contacts are never silently dropped;
- on any other error raises :class:`SimulationError` naming the step and a hint, with the state and the
  records of the completed chunks attached so nothing computed so far is lost;
- hands each accepted chunk to a hook (records, progress bars, checkpoints, VTK) that may end members'
  budgets early (a consolidation stop test).

Its users: :class:`ChunkRunner` (one state: the stages of :class:`membrax.triaxial.protocol.StagedTest`,
interactive use) and :class:`membrax.executor.BatchedTest` (stacked members: every run of
:mod:`membrax.run` and :mod:`membrax.sweep`).

The compiled chunk body is written once, here, and every loop over time steps in membrax is one of its
two pieces: :func:`advance` (``num_steps`` steps, a ``lax.fori_loop``) and :func:`record_blocks`
(``num_records`` blocks, each advancing and recording, a ``lax.scan``). The runners, the sensitivities'
relaxation and the gradient rollouts differ in what they carry (a step budget, a checkpointed window),
not in the loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import numpy as np

from membrax import native
from membrax.errors import OVERFLOWS, ErrorCode, SimulationError, describe
from membrax.spheres.neighbors import PairNeighborFn, remap_pair_history

__all__ = [
    "advance",
    "record_blocks",
    "ChunkRunner",
    "drive",
    "concatenate_records",
    "run_phases",
    "two_rate_plan",
]


def advance(step: Callable, state, params, num_steps: int, unroll: int = 1):
    """``num_steps`` steps of ``step(state, params)``: the inner loop of every compiled chunk.

    Args:
      step: the time step, ``(state, params) → state``.
      state: the state to advance (any pytree).
      params: the step's parameters (any pytree; traced).
      num_steps: steps (static).
      unroll: steps per iteration of the ``lax.fori_loop``; ``num_steps`` or more: a Python loop, the steps
        written out with no loop at all (what a checkpointed gradient window may want,
        :func:`membrax.gradients.checkpoint_window`).

    Returns:
      The state after ``num_steps`` steps.
    """
    if unroll >= num_steps:
        for _ in range(num_steps):
            state = step(state, params)
        return state
    return jax.lax.fori_loop(0, num_steps, lambda _, s: step(s, params), state, unroll=unroll)


def record_blocks(block: Callable, carry, num_records: int):
    """``num_records`` blocks of ``block(carry) → (carry, record)``: the outer loop of every compiled chunk.

    Args:
      block: one block, typically :func:`advance` by the record interval then a record of the state.
      carry: what the blocks pass on (a state, or a state and its step budget).
      num_records: blocks (static).

    Returns:
      (the final carry, the records stacked along a leading axis of ``num_records``).
    """
    return jax.lax.scan(lambda current, _: block(current), carry, None, length=num_records)


def concatenate_records(chunks):
    """Join a list of record pytrees (leading axis: time) into one pytree of numpy arrays."""
    if not chunks:
        return None
    return jax.tree_util.tree_map(lambda *xs: np.concatenate([np.asarray(x) for x in xs], axis=0), *chunks)


class ChunkRunner:
    """Runs a step function in jitted chunks with error checks and neighbour-list reallocation.

    Args:
      step_fn: ``step_fn(state, params) -> state``.
      neighbor_frame: the neighbour-list factory used to reallocate.
      record_fn: ``record_fn(state, params) -> pytree`` recorded every ``record_every`` steps.
      num_particles: N (for the history remap).
      capacity_growth: the factor by which the pair capacity grows on each reallocation.
      grow_membrane: for a coupled state (:class:`membrax.membrane.coupled.CoupledState`),
        ``grow_membrane(state, overflowed) -> state`` with a node candidate table large enough for the
        overflowing chunk's end state ``overflowed`` (its table's ``max_count`` per node,
        ``max_sphere_count`` per sphere, ``max_cell_count`` per cell of its cell list; see
        :func:`membrax.membrane.coupled.grow_candidates`).
      dem_of: ``dem_of(state) -> DEMState``, the sphere state whose neighbour list the runner rebuilds
        (default: the state itself; a coupled test passes ``lambda s: s.dem``).
      with_dem: ``with_dem(state, dem) -> state``, the state with that sphere state put back (default: the
        sphere state itself). The test tells the runner where its spheres are; the runner never inspects
        the state's type.
    """

    def __init__(
        self,
        step_fn: Callable,
        neighbor_frame: PairNeighborFn,
        record_fn: Callable,
        num_particles: int,
        capacity_growth: float = 1.5,
        grow_membrane: Callable | None = None,
        dem_of: Callable | None = None,
        with_dem: Callable | None = None,
    ):
        self.step_fn = step_fn
        self.neighbor_frame = neighbor_frame
        self.record_fn = record_fn
        self.num_particles = num_particles
        self.capacity_growth = capacity_growth
        self.grow_membrane = grow_membrane
        self.dem_of = (lambda state: state) if dem_of is None else dem_of
        self.with_dem = (lambda state, dem: dem) if with_dem is None else with_dem
        self.reallocations = 0
        self._chunk = jax.jit(
            self._chunk_impl,
            static_argnames=("num_records", "record_every"),
            compiler_options=native.compiler_options(),
        )

    def _chunk_impl(self, state, params, num_records: int, record_every: int):
        def block(s):
            s = advance(self.step_fn, s, params, record_every)
            return s, self.record_fn(s, params)

        return record_blocks(block, state, num_records)

    def reallocate(self, state, capacity_growth: float | None = None):
        """A copy of ``state`` with a rebuilt neighbour list and its contact history carried over.

        Args:
          state: the state whose sphere state (``dem_of``) holds the list to rebuild.
          capacity_growth: spare capacity as a fraction of the old capacity (default: the runner's, for an
            overflow); 1.0 rebuilds without growing, so the compiled chunk is reused.
        """
        dem = self.dem_of(state)
        old = dem.neighbors
        growth = self.capacity_growth if capacity_growth is None else capacity_growth
        extra = int(np.ceil((growth - 1.0) * old.idx.shape[1]))
        new = self.neighbor_frame.allocate(dem.position, extra_capacity=extra)
        spring = remap_pair_history(old.idx, new.idx, dem.pair_spring, self.num_particles)
        self.reallocations += 1
        return self.with_dem(state, dem.set(neighbors=new, pair_spring=spring))

    def run(
        self,
        state,
        params,
        num_steps: int,
        chunk_steps: int = 1000,
        record_every: int = 25,
        stop_fn: Callable | None = None,
        on_chunk: Callable | None = None,
    ):
        """Advance ``state`` by up to ``num_steps`` steps (whole records), through :func:`drive`.

        Args:
          state: the starting state.
          params: traced step parameters.
          num_steps: steps to take (stops earlier if ``stop_fn`` returns True after a chunk).
          chunk_steps: steps per compiled chunk (rounded to a multiple of ``record_every``).
          record_every: steps between records.
          stop_fn: ``stop_fn(state, records_of_chunk) -> bool``, checked after each chunk.
          on_chunk: ``on_chunk(state, records_of_chunk)``, called after each accepted chunk.

        Returns:
          (final state, records: pytree of numpy arrays with a leading time axis, or None).
        """
        chunks = []

        def chunk(current, left, num_records):
            new, records = self._chunk(current, params, num_records=num_records, record_every=record_every)
            return new, left - num_records * record_every, records, None

        def grow(current, error, overflowed):
            membrane_overflow = error[0] & ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW
            if membrane_overflow and self.grow_membrane is None:
                return None
            if error[0] & ErrorCode.NEIGHBOR_OVERFLOW:
                current = self.reallocate(current)
            if membrane_overflow:
                current = self.grow_membrane(current, overflowed)
                self.reallocations += 1
            return current

        def fail(error, new, current):
            return SimulationError(
                f"simulation stopped in the chunk ending at step {int(new.step)}: "
                + "; ".join(describe(error[0])),
                state=current,
                records=concatenate_records(chunks),
            )

        def accept(new, records, _valid, _left):
            chunks.append(jax.device_get(records))
            if on_chunk is not None:
                on_chunk(new, chunks[-1])
            return [0] if stop_fn is not None and stop_fn(new, chunks[-1]) else []

        state, _ = drive(
            chunk,
            state,
            [num_steps],
            record_every,
            chunk_steps,
            errors=lambda s: np.atleast_1d(np.asarray(s.error)),
            grow=grow,
            fail=fail,
            accept=accept,
        )
        return state, concatenate_records(chunks)


def drive(
    chunk, state, budgets, record_every: int, chunk_steps: int, *, errors, grow, fail, accept, isolate=None
):
    """The chunk loop: every long run of membrax (a test's stage, a batch's phase) goes through it.

    Each pass launches one compiled chunk of up to ``chunk_steps`` steps (whole records of
    ``record_every`` steps) for every member that still has steps in its budget, then on the host:

    1. reads the error bits; on a table overflow (:data:`membrax.errors.OVERFLOWS`) grows the tables from
       the chunk's *starting* state and reruns the chunk, so contacts are never dropped;
    2. on any other error raises what ``fail`` builds (the state before the chunk is attached there), or,
       given ``isolate``, ends the budgets of the members in error and reruns the chunk for the others;
    3. accepts the chunk: ``accept`` stores its records, reports progress, writes checkpoints and names the
       members that stop early (their budgets end).

    Args:
      chunk: ``chunk(state, left, num_records) -> (state, left, records, valid)``: advances the members
        by ``num_records`` record blocks at most, ``left`` (B,) the steps each still takes; ``valid`` (B, T)
        marks the blocks each member ran (None: all).
      state: the starting state.
      budgets: (B,) steps for each member, rounded up to whole records.
      record_every: steps between records.
      chunk_steps: steps per compiled chunk (rounded to whole records, at least one).
      errors: ``errors(state) -> (B,) int`` error bits per member.
      grow: ``grow(state, error, overflowed) -> state`` with larger tables (``overflowed`` the chunk's end
        state, whose tables say how large), or None if it cannot grow them (then ``fail``).
      fail: ``fail(error, new_state, state) -> Exception`` for error bits that growing does not clear.
      accept: ``accept(state, records, valid, left) -> members`` after each good chunk: the members
        (indices) whose budgets end now.
      isolate: ``isolate(error, new_state, left) -> left``: the budgets with those of the members in
        error ended (it reports them, and raises when none is left to go on); the chunk is then run again
        from its starting state, so the failed members stay at their last good state and records, before
        any table growth (a blown-up member's tables overflow too). None: ``fail``.

    Returns:
      (state, left): the final state and the steps each member had left (0 unless stopped by errors).
    """
    left = np.ceil(np.asarray(budgets, dtype=np.float64) / record_every).astype(np.int64) * record_every
    records_per_chunk = max(1, chunk_steps // record_every)
    while left.max(initial=0) > 0:
        count = min(records_per_chunk, math.ceil(left.max() / record_every))
        new_state, new_left, records, valid = chunk(state, left, count)
        error = errors(new_state)
        if isolate is not None and np.any(error & ~OVERFLOWS):
            left = np.asarray(isolate(error & ~OVERFLOWS, new_state, left), dtype=np.int64).copy()
            continue
        if np.any(error & OVERFLOWS):
            grown = grow(state, error, new_state)
            if grown is not None:
                state = grown
                continue
        if np.any(error):
            raise fail(error, new_state, state)
        state = new_state
        left = np.asarray(new_left, dtype=np.int64).copy()
        for member in accept(state, records, valid, left):
            left[member] = 0
    return state, left


def two_rate_plan(
    steps_per_strain: float,
    target_strain: float,
    fine_until_strain: float,
    ramp_strain: float = 0.0,
    coarse_steps_per_strain: float | None = None,
) -> tuple[int, int]:
    """Steps of the two recording phases of a strain-controlled stage: (fine, coarse).

    The strain grows by 1/``steps_per_strain`` per step once the platens are at speed: the fine phase runs
    to ``fine_until_strain`` (capped at the target), the coarse phase to ``target_strain``. A linear ramp
    from rest that ends at strain ``ramp_strain`` (:func:`membrax.spheres.walls.set_control`) lasts 2 ε_ramp/ε̇
    and so delays every later strain by ε_ramp/ε̇: the fine phase takes that many steps more.

    A coarse phase at another rate (``coarse_steps_per_strain`` = 1/(ε̇₂ Δt)) starts with a linear change of
    speed over the strain ε_t = min(``ramp_strain``, coarse strain)
    (:func:`membrax.spheres.walls.change_speed`): it covers ε_t at the mean rate (ε̇₁ + ε̇₂)/2 and the
    rest at ε̇₂, so it takes (ε_coarse − ε_t)/(ε̇₂ Δt) + 2 ε_t/((ε̇₁ + ε̇₂) Δt) steps.
    """
    fine_strain = min(fine_until_strain, target_strain)
    fine = math.ceil((fine_strain + ramp_strain) * steps_per_strain)
    coarse_strain = max(target_strain - fine_strain, 0.0)
    if coarse_steps_per_strain is None or coarse_steps_per_strain == steps_per_strain:
        return fine, math.ceil(coarse_strain * steps_per_strain)
    change = min(ramp_strain, coarse_strain)
    mean_rate_dt = 0.5 * (1.0 / steps_per_strain + 1.0 / coarse_steps_per_strain)  # (ε̇₁ + ε̇₂) Δt / 2
    coarse = math.ceil((coarse_strain - change) * coarse_steps_per_strain + change / mean_rate_dt)
    return fine, coarse


def run_phases(runner: ChunkRunner, state, params, phases, chunk_steps: int, on_chunk=None):
    """Run ``phases`` = [(steps, record_every), ...] one after another; the records joined.

    Returns:
      (state, records) with the records of all phases with steps > 0 concatenated.
    """
    parts = []
    for steps, record_every in phases:
        if steps > 0:
            state, records = runner.run(state, params, steps, chunk_steps, record_every, on_chunk=on_chunk)
            parts.append(records)
    return state, concatenate_records([part for part in parts if part is not None])
