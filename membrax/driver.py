"""The chunk driver: a Python loop over jitted ``lax.scan`` chunks.

Contract. :class:`ChunkRunner` advances a state by whole chunks of steps. Each chunk is one compiled call
that takes ``chunk_steps`` steps and records ``record_fn(state, params)`` every ``record_every`` steps.
Between chunks, on the host, it:

- checks the error bits of the state (:mod:`membrax.errors`);
- on a neighbour-list overflow, reallocates a larger list from the *chunk's starting state*, carries the
  contact history over by partner id, and reruns the chunk — contacts are never silently dropped; the
  same for an overflow of the membrane's node–sphere candidate table (``grow_membrane``);
- on any other error raises :class:`SimulationError` naming the step and a hint, with the state and the
  records of the completed chunks attached so nothing computed so far is lost;
- calls ``on_chunk(state, records)`` (progress bars, checkpoints) and stops early when ``stop_fn`` says so.

This loop is the one place where lists are reallocated, errors checked and progress reported.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import numpy as np

from membrax.errors import OVERFLOWS, ErrorCode, describe
from membrax.neighbors import PairNeighborFn, remap_pair_history

__all__ = [
    "ChunkRunner",
    "SimulationError",
    "concatenate_records",
    "run_phases",
    "strain_rate_from_inertial_number",
    "two_rate_plan",
]


class SimulationError(RuntimeError):
    """A run stopped on an error bit; ``state`` and ``records`` hold what was computed before it."""

    def __init__(self, message, state=None, records=None):
        super().__init__(message)
        self.state = state
        self.records = records


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
      grow_membrane: for a coupled state (:class:`membrax.membrane_dem.CoupledState`),
        ``grow_membrane(state, overflowed) -> state`` with a node candidate table large enough for the
        overflowing chunk's end state ``overflowed`` (its table's ``max_count`` per node,
        ``max_sphere_count`` per sphere; see :func:`membrax.membrane_dem.grow_candidates`).
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
        self._chunk = jax.jit(self._chunk_impl, static_argnames=("num_records", "record_every"))

    def _chunk_impl(self, state, params, num_records: int, record_every: int):
        def inner(_, s):
            return self.step_fn(s, params)

        def outer(s, _):
            s = jax.lax.fori_loop(0, record_every, inner, s)
            return s, self.record_fn(s, params)

        return jax.lax.scan(outer, state, None, length=num_records)

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
        """Advance ``state`` by up to ``num_steps`` steps (rounded up to whole records).

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
        records_per_chunk = max(1, chunk_steps // record_every)
        total_records = int(np.ceil(num_steps / record_every))
        chunks = []
        done = 0
        while done < total_records:
            count = min(records_per_chunk, total_records - done)
            new_state, records = self._chunk(state, params, num_records=count, record_every=record_every)
            error = int(new_state.error)
            membrane_overflow = error & ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW
            if error & OVERFLOWS and (self.grow_membrane is not None or not membrane_overflow):
                if error & ErrorCode.NEIGHBOR_OVERFLOW:
                    state = self.reallocate(state)
                if membrane_overflow:
                    state = self.grow_membrane(state, new_state)
                    self.reallocations += 1
                continue
            if error:
                raise SimulationError(
                    f"simulation stopped in the chunk ending at step {int(new_state.step)}: "
                    + "; ".join(describe(error)),
                    state=state,
                    records=concatenate_records(chunks),
                )
            state = new_state
            chunks.append(jax.device_get(records))
            done += count
            if on_chunk is not None:
                on_chunk(state, chunks[-1])
            if stop_fn is not None and stop_fn(state, chunks[-1]):
                break
        return state, concatenate_records(chunks)


def strain_rate_from_inertial_number(inertial_number, particle_diameter, density, confining_stress):
    """Axial strain rate ε̇ = I / (d √(ρ/σ)) for an inertial number I (GDR MiDi 2004), 1/s."""
    return inertial_number / (particle_diameter * math.sqrt(density / confining_stress))


def two_rate_plan(
    steps_per_strain: float, target_strain: float, fine_until_strain: float, ramp_strain: float = 0.0
) -> tuple[int, int]:
    """Steps of the two recording phases of a strain-controlled stage: (fine, coarse).

    The strain grows by 1/``steps_per_strain`` per step once the platens are at speed: the fine phase runs
    to ``fine_until_strain`` (capped at the target), the coarse phase to ``target_strain``. A linear ramp
    from rest that ends at strain ``ramp_strain`` (:func:`membrax.walls.set_control`) lasts 2 ε_ramp/ε̇
    and so delays every later strain by ε_ramp/ε̇: the fine phase takes that many steps more.
    """
    fine_strain = min(fine_until_strain, target_strain)
    fine = math.ceil((fine_strain + ramp_strain) * steps_per_strain)
    coarse = max(math.ceil((target_strain - fine_strain) * steps_per_strain), 0)
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
