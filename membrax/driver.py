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

Its users, each handing it a chunk and callbacks: :class:`ChunkRunner` (one state: the stages of
:class:`membrax.triaxial.protocol.StagedTest` and of the periodic cell,
:class:`membrax.triaxial.periodic.PeriodicRunner`; interactive use), :class:`membrax.executor.BatchedTest`
and :class:`membrax.executor.PeriodicBatch` (stacked members: every run of :mod:`membrax.run` and
:mod:`membrax.sweep`), the compaction of a random
packing and its FIRE relaxations (:mod:`membrax.spheres.compaction`, :mod:`membrax.spheres.fire`: a
chunk, then a measure that may end the budget), the continuation differences of
:mod:`membrax.sensitivities` (relax until balanced) and the gradient rollouts of :mod:`membrax.gradients`
(the whole compiled rollout is one chunk: an overflow grows the start states' tables and runs it again).
``tests/test_architecture.py`` holds that no other loop launches a chunk or reads error bits. Every table
grows through :func:`grow_tables`, which all of them call from :func:`drive`'s ``grow``; a periodic cell
hands it the allocation of its list (``allocate``: cells sized for a shrinking box), not a growth of its
own.

The compiled chunk body is written once, here, and every loop over time steps in membrax is one of its
two pieces: :func:`advance` (``num_steps`` steps, a ``lax.fori_loop``, or a ``lax.while_loop`` where the
count is traced) and :func:`record_blocks` (``num_records`` blocks, each advancing and recording, a
``lax.scan``). The runners, the sensitivities' relaxation and the gradient rollouts differ in what they
carry (a step budget, a checkpointed window), not in the loop. A run's chunk takes its record interval and
its blocks as arguments (:func:`budgeted_blocks` with ``slots``), so its phases share one program.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native
from membrax.errors import OVERFLOWS, ErrorCode, SimulationError, describe
from membrax.spheres.neighbors import PairNeighborFn, allocate_shared, remap_pair_history

__all__ = [
    "TABLE_GROWTH",
    "TABLE_GROWTHS",
    "advance",
    "record_blocks",
    "budgeted_blocks",
    "ChunkRunner",
    "drive",
    "grow_tables",
    "concatenate_records",
    "record_slots",
    "run_phases",
    "two_rate_plan",
]


def advance(step: Callable, state, params, num_steps: int, unroll: int = 1):
    """``num_steps`` steps of ``step(state, params)``: the inner loop of every compiled chunk.

    Args:
      step: the time step, ``(state, params) → state``.
      state: the state to advance (any pytree).
      params: the step's parameters (any pytree; traced).
      num_steps: steps: a Python int, or a traced integer (a loop whose trip count is an argument, so one
        program serves every record interval; the steps and their bits are the same).
      unroll: steps per iteration of the ``lax.fori_loop``; ``num_steps`` or more (static ``num_steps``): a
        Python loop, the steps written out with no loop at all (what a checkpointed gradient window may
        want, :func:`membrax.gradients.checkpoint_window`).

    Returns:
      The state after ``num_steps`` steps.
    """
    if not isinstance(num_steps, int):
        # A while loop whose condition is this call's own closure: ``fori_loop``'s condition is one shared
        # function, by which JAX looks the loop's trace up and then compares the state's tree structure
        # with the cached ones, and jax-md keeps a jax array among a periodic list's static fields (its
        # cell size), which compares to a tracer, not a bool, under a trace.
        def body(carry):
            taken, current = carry
            return taken + 1, step(current, params)

        start = jnp.zeros_like(num_steps)
        return jax.lax.while_loop(lambda carry: carry[0] < num_steps, body, (start, state))[1]
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


def record_slots(chunk_steps: int, intervals) -> int:
    """Record slots of a chunk of ``chunk_steps`` steps for phases recorded every ``intervals`` steps.

    The most records per chunk of any of them, at least one (:func:`drive`'s count): phases whose chunks
    hold this many slots run one compiled program (:func:`budgeted_blocks`).
    """
    return max([1] + [chunk_steps // every for every in intervals])


def budgeted_blocks(
    step: Callable,
    record: Callable,
    state,
    params,
    left,
    num_records,
    record_every,
    slots: int | None = None,
):
    """``num_records`` blocks of ``record_every`` steps of ``step``, each recorded, within a step budget.

    A block runs while the budget ``left`` is positive; past it the state is frozen: ``lax.cond`` skips the
    block's steps (under ``vmap``, where ``left`` differs between members, both branches run and the frozen
    state is selected), and ``record`` records the frozen state.

    Given ``slots``, ``num_records`` and ``record_every`` may be traced: the chunk holds ``slots`` record
    slots, runs and records its ``num_records`` blocks in the last ones and leaves the first empty (zeros,
    ``valid`` False, no step and no record computed: the slot index is the same for every member, so the
    ``cond`` stays one under ``vmap``), so the last slot records the chunk's end state, as without
    ``slots``. One compiled program then serves every phase of a run, whatever its record interval, where
    a static interval compiled one per phase (3.3 s each on the demo).

    Args:
      step: the time step, ``(state, params) → state``.
      record: ``(state, params) → record``.
      state: the starting state.
      params: the step's parameters (traced).
      left: the steps still to take (the budget; blocks past it are frozen).
      num_records: blocks to run (static, or traced up to ``slots``).
      record_every: steps per block (static, or traced).
      slots: record slots of the chunk (static); None: ``num_records`` (then static).

    Returns:
      (state, left, records, valid): ``records`` has ``slots`` entries, ``valid`` marks the blocks that ran.
    """
    if slots is None:
        slots = num_records
    if not isinstance(record_every, int):  # traced: counted down from the budget in the budget's dtype
        record_every = jnp.asarray(record_every, dtype=jnp.result_type(left))

    def block(carry):
        s, budget, slot = carry
        scheduled = slot >= slots - num_records
        active = scheduled & (budget > 0)
        s = jax.lax.cond(active, lambda x: advance(step, x, params, record_every), lambda x: x, s)
        budget = jnp.where(active, budget - record_every, budget)
        if isinstance(num_records, int) and slots == num_records:
            recorded = record(s, params)  # every slot scheduled: no empty branch to compile
        else:
            # The empty branch's zeros take the record's shapes; XLA drops the record's unused arithmetic.
            recorded = jax.lax.cond(
                scheduled,
                lambda x: record(x, params),
                lambda x: jax.tree.map(jnp.zeros_like, record(x, params)),
                s,
            )
        return (s, budget, slot + 1), (recorded, active)

    (state, left, _), (records, valid) = record_blocks(block, (state, left, jnp.int32(0)), slots)
    return state, left, records, valid


#: The factor by which a neighbour list's pair capacity grows on an overflow.
TABLE_GROWTH = 1.5

#: Growths in a row, with no chunk accepted between them, after which :func:`drive` gives up: a chunk that
#: still overflows tables 1.5^8 ≈ 26 times as large has run away (a sphere flung out, positions no longer
#: finite), not outgrown them.
TABLE_GROWTHS = 8


def _itself(state):
    return state


def _replaced(_state, dem):
    return dem


def grow_tables(
    states,
    error: int,
    frame: PairNeighborFn,
    *,
    dem_of: Callable = _itself,
    with_dem: Callable = _replaced,
    grow_membrane: Callable | None = None,
    overflowed=None,
    capacity_growth: float = TABLE_GROWTH,
    allocate: Callable | None = None,
):
    """The one table growth of membrax: larger neighbour lists and node candidate tables for ``states``.

    On :attr:`ErrorCode.NEIGHBOR_OVERFLOW` every state's neighbour list is allocated afresh at its positions
    with one shared capacity, at least ``capacity_growth`` × the old one (:func:`allocate_shared`: the lists
    of a batch's members keep one shape, so they stack; a periodic cell's ``allocate`` builds its own), and
    the tangential springs move to the new slots by partner id (:func:`remap_pair_history`); on
    :attr:`ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW` ``grow_membrane`` grows the node candidate tables
    (:func:`membrax.membrane.coupled.grow_candidates`). The runs' drivers (:meth:`ChunkRunner.grow`, so
    also the periodic cell's :class:`membrax.triaxial.periodic.PeriodicRunner`;
    :meth:`membrax.executor.BatchedTest.grow`), FIRE's relaxation and the compaction call it from
    :func:`drive`'s ``grow``.

    Args:
      states: the states to grow (a list: one state, or the members of a batch).
      error: the error bits (ORed over the members).
      frame: the neighbour-list factory.
      dem_of: ``dem_of(state)``: the sphere state, with ``position``, ``neighbors`` and ``pair_spring``
        (None: no contact history, as in FIRE).
      with_dem: ``with_dem(state, dem)``: the state with that sphere state put back.
      grow_membrane: ``grow_membrane(states, overflowed) -> states`` with larger candidate tables, or None
        (then a candidate overflow cannot be grown).
      overflowed: the overflowing chunk's end state (its tables say how large the new ones must be).
      capacity_growth: the pair capacity's growth factor; 1.0 rebuilds at the same capacity (the compiled
        chunk is reused).
      allocate: ``allocate(dems, capacity, overflowed) -> lists``: new neighbour lists for the sphere
        states ``dems`` with at least ``capacity`` pair slots (``overflowed`` as given here), or None:
        :func:`allocate_shared` with ``frame`` at their positions.

    Returns:
      The grown states (a list), or None if a table cannot be grown.
    """
    states = list(states)
    if error & ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW and grow_membrane is None:
        return None
    if error & ErrorCode.NEIGHBOR_OVERFLOW:
        dems = [dem_of(state) for state in states]
        old = dems[0].neighbors
        capacity = math.ceil(capacity_growth * int(old.max_occupancy))
        if allocate is None:
            lists = allocate_shared(
                frame,
                [dem.position for dem in dems],
                capacity=capacity,
                cell_capacity=int(old.cell_list_capacity or 0),
            )
        else:
            lists = allocate(dems, capacity, overflowed)
        states = [
            with_dem(
                state,
                dem.set(
                    neighbors=new,
                    pair_spring=None
                    if dem.pair_spring is None
                    else remap_pair_history(
                        dem.neighbors.idx, new.idx, dem.pair_spring, int(np.shape(dem.position)[0])
                    ),
                ),
            )
            for state, dem, new in zip(states, dems, lists, strict=True)
        ]
    if error & ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW:
        states = list(grow_membrane(states, overflowed))
    return states


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
      allocate: the new neighbour lists of an overflow, :func:`grow_tables`' ``allocate`` (default
        :func:`allocate_shared`; a periodic cell's runner passes its own).
      explain: ``explain(error, end_state, start_state, params) -> str``, appended to the message of a run
        stopped on ``error`` (e.g. how far the membrane was stretched); default none.
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
        allocate: Callable | None = None,
        explain: Callable | None = None,
    ):
        self.step_fn = step_fn
        self.explain = explain
        self.neighbor_frame = neighbor_frame
        self.record_fn = record_fn
        self.num_particles = num_particles
        self.capacity_growth = capacity_growth
        self.grow_membrane = grow_membrane
        self.dem_of = _itself if dem_of is None else dem_of
        self.with_dem = _replaced if with_dem is None else with_dem
        self.allocate = allocate
        self.reallocations = 0
        self._chunk = jax.jit(
            self._chunk_impl,
            static_argnames=("slots",),
            compiler_options=native.compiler_options(),
        )

    def _chunk_impl(self, state, params, left, num_records, record_every, slots: int):
        """(state, left, records, valid): :func:`budgeted_blocks` within ``left`` steps.

        ``num_records`` and ``record_every`` are traced: stages with other record intervals run the same
        program. The blocks past ``left`` or ``num_records`` (``valid`` False) are dropped by :meth:`run`.
        """
        return budgeted_blocks(
            self.step_fn, self.record_fn, state, params, left, num_records, record_every, slots
        )

    def reallocate(self, state, capacity_growth: float | None = None):
        """A copy of ``state`` with a rebuilt neighbour list and its contact history carried over.

        Args:
          state: the state whose sphere state (``dem_of``) holds the list to rebuild.
          capacity_growth: the capacity's growth factor (default: the runner's, for an overflow); 1.0
            rebuilds without growing, so the compiled chunk is reused.
        """
        growth = self.capacity_growth if capacity_growth is None else capacity_growth
        # No chunk overflowed: the state's own list says how large.
        return self._grown(state, ErrorCode.NEIGHBOR_OVERFLOW, state, growth)

    def grow(self, state, error, overflowed):
        """``state`` with the tables that overflowed (``error``) grown (:func:`grow_tables`), or None.

        ``overflowed`` is the overflowing chunk's end state; :func:`drive`'s ``grow``.
        """
        return self._grown(state, int(error[0]), overflowed, self.capacity_growth)

    def _grown(self, state, error: int, overflowed, capacity_growth: float):
        """``state`` with the tables ``error`` names grown through the runner's hooks, or None.

        The one call of :func:`grow_tables` for :meth:`reallocate` and :meth:`grow`.
        """
        grow_membrane = None
        if self.grow_membrane is not None:

            def grow_membrane(states, end):
                return [self.grow_membrane(s, end) for s in states]

        grown = grow_tables(
            [state],
            error,
            self.neighbor_frame,
            dem_of=self.dem_of,
            with_dem=self.with_dem,
            grow_membrane=grow_membrane,
            overflowed=overflowed,
            capacity_growth=capacity_growth,
            allocate=self.allocate,
        )
        if grown is None:
            return None
        self.reallocations += 1
        return grown[0]

    def run(
        self,
        state,
        params,
        num_steps: int,
        chunk_steps: int = 1000,
        record_every: int = 25,
        stop_fn: Callable | None = None,
        on_chunk: Callable | None = None,
        slots: int = 0,
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
          slots: record slots of the compiled chunk, at least its records per chunk; stages that pass the
            same run one program (:func:`run_phases`).

        Returns:
          (final state, records: pytree of numpy arrays with a leading time axis, or None).
        """
        chunks = []
        slots = max(slots, record_slots(chunk_steps, [record_every]))

        def chunk(current, left, num_records):
            # A whole chunk's program (drive's whole_chunks) within the budget: the stage's last chunk
            # compiles nothing new; the frozen blocks' records are dropped here.
            new, new_left, records, valid = self._chunk(
                current, params, np.int32(left[0]), np.int32(num_records), np.int32(record_every), slots=slots
            )
            valid = np.asarray(valid)
            records = jax.tree.map(lambda r: r[valid], jax.device_get(records))
            return new, np.asarray([int(new_left)], dtype=np.int64), records, None

        def fail(error, new, current):
            return SimulationError(
                f"simulation stopped in the chunk ending at step {int(new.step)}: "
                + "; ".join(describe(error[0]))
                + ("" if self.explain is None else self.explain(int(error[0]), new, current, params)),
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
            grow=self.grow,
            fail=fail,
            accept=accept,
            whole_chunks=True,
        )
        return state, concatenate_records(chunks)


def drive(
    chunk,
    state,
    budgets,
    record_every: int,
    chunk_steps: int,
    *,
    errors,
    grow,
    fail,
    accept,
    isolate=None,
    whole_chunks: bool = False,
):
    """The chunk loop: every long run of membrax (a test's stage, a batch's phase) goes through it.

    Each pass launches one compiled chunk of up to ``chunk_steps`` steps (whole records of
    ``record_every`` steps) for every member that still has steps in its budget, then on the host:

    1. reads the error bits; on a table overflow (:data:`membrax.errors.OVERFLOWS`) grows the tables from
       the chunk's *starting* state (``grow``, :func:`grow_tables`) and reruns the chunk, so contacts are
       never dropped. An overflow beside another error is grown and rerun too, once: the steps run without
       the dropped contacts can themselves run a member away (a membrane through a sphere it no longer
       sees, measured on a thin Gent membrane with face contact); a rerun that runs away again has run away
       (its tables overflow too) and goes to ``fail``, as do :data:`TABLE_GROWTHS` growths in a row;
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
      whole_chunks: every pass asks ``chunk`` for a whole chunk's records, also where the budgets end
        sooner, so a stage's last, shorter chunk runs the program already compiled for the others instead
        of compiling its own. Only for a ``chunk`` that runs no block past a member's budget (the state
        unchanged there, :func:`budgeted_blocks`): :meth:`ChunkRunner.run`'s and the batched executor's
        under ``lax.map``.

    Returns:
      (state, left): the final state and the steps each member had left (0 unless stopped by errors).
    """
    left = np.ceil(np.asarray(budgets, dtype=np.float64) / record_every).astype(np.int64) * record_every
    records_per_chunk = record_slots(chunk_steps, [record_every])
    growths = 0  # in a row, since the last accepted chunk
    regrown_after_error = False  # this chunk already reran with grown tables after another error
    while left.max(initial=0) > 0:
        count = (
            records_per_chunk
            if whole_chunks
            else min(records_per_chunk, math.ceil(left.max() / record_every))
        )
        new_state, new_left, records, valid = chunk(state, left, count)
        error = np.asarray(errors(new_state))
        overflowed, other = np.any(error & OVERFLOWS), np.any(error & ~OVERFLOWS)
        # An overflowing chunk ran its later steps without some contacts, and that alone can run a member
        # away (a membrane passing through a sphere its table no longer holds, then flung off it): so it
        # reruns with grown tables before any other error counts. A chunk that runs away again with them
        # has run away (its tables overflow too): it is not grown a second time.
        if overflowed and growths < TABLE_GROWTHS and not (other and regrown_after_error):
            grown = grow(state, error, new_state)
            if grown is not None:
                state, growths, regrown_after_error = grown, growths + 1, bool(other)
                continue
        if isolate is not None and other:
            left = np.asarray(isolate(error & ~OVERFLOWS, new_state, left), dtype=np.int64).copy()
            continue
        if np.any(error):
            raise fail(error, new_state, state)
        state, growths, regrown_after_error = new_state, 0, False
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
    slots = record_slots(chunk_steps, [record_every for _, record_every in phases])
    for steps, record_every in phases:
        if steps > 0:
            state, records = runner.run(
                state, params, steps, chunk_steps, record_every, on_chunk=on_chunk, slots=slots
            )
            parts.append(records)
    return state, concatenate_records([part for part in parts if part is not None])
