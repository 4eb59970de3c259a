"""The one host loop (membrax.driver.drive) and the one table growth (membrax.driver.grow_tables).

The loop's contract is counted by hand on a scripted chunk: an overflow grows the tables from the chunk's
*starting* state and reruns it, also when the chunk ran away beside it (once: a rerun that runs away again
fails), and growths in a row are bounded. The
growth is checked on a real FCC block: every pair the brute force finds is in the grown list, and every
tangential spring stays with its pair.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from membrax import driver
from membrax.errors import ErrorCode, SimulationError
from membrax.spheres import fcc, neighbors

D = 0.025


class _Script:
    """A chunk that adds its record count to an int state and reports scripted error bits, in order."""

    def __init__(self, bits):
        self.bits, self.calls, self.grown_from = list(bits), [], []

    def chunk(self, state, left, num_records):
        self.calls.append(state)
        return state + num_records, left - num_records, [state + num_records], None

    def errors(self, _state):
        return np.atleast_1d(self.bits.pop(0) if self.bits else 0)

    def grow(self, state, error, overflowed):
        self.grown_from.append((state, int(error[0]), overflowed))
        return state + 1000  # a state with "larger tables"

    def run(self, budget, chunk_steps=2):
        accepted = []
        state, left = driver.drive(
            self.chunk,
            0,
            [budget],
            1,
            chunk_steps,
            errors=self.errors,
            grow=self.grow,
            fail=lambda error, new, state: SimulationError(f"bits {int(error[0])} at {new}", state=state),
            accept=lambda state, records, valid, left: accepted.append(records) or [],
        )
        return state, left, accepted


def test_an_overflowing_chunk_is_run_again_from_its_start_with_grown_tables():
    """Budget 6 in chunks of 2: the second chunk overflows once; its start state (2) is grown (→ 1002) and
    the chunk rerun from there; 3 chunks accepted, 4 launched, the records only of the accepted ones."""
    script = _Script([0, ErrorCode.NEIGHBOR_OVERFLOW])
    state, left, accepted = script.run(6)
    assert script.grown_from == [(2, ErrorCode.NEIGHBOR_OVERFLOW, 4)]
    assert script.calls == [0, 2, 1002, 1004]
    assert accepted == [[2], [1004], [1006]] and state == 1006 and list(left) == [0]


@pytest.mark.parametrize("other", [ErrorCode.NOT_FINITE, ErrorCode.OUTSIDE_BOX])
def test_a_chunk_that_overflowed_and_ran_away_is_rerun_once_with_grown_tables(other):
    """Overflow and a non-finite state (or a sphere out of the box) together: the overflow may have caused
    the rest (a membrane passing through a sphere its table dropped), so the chunk's start (0) is grown once
    (→ 1000) and rerun; the rerun is clean and accepted: 4 launches, the records of 3 chunks."""
    script = _Script([ErrorCode.NEIGHBOR_OVERFLOW | other])
    state, left, accepted = script.run(6)
    assert script.grown_from == [(0, int(ErrorCode.NEIGHBOR_OVERFLOW | other), 2)]
    assert script.calls == [0, 1000, 1002, 1004]
    assert accepted == [[1002], [1004], [1006]] and state == 1006 and list(left) == [0]


@pytest.mark.parametrize("other", [ErrorCode.NOT_FINITE, ErrorCode.OUTSIDE_BOX])
def test_a_chunk_that_runs_away_again_with_grown_tables_fails(other):
    """The rerun with grown tables runs away again (its tables overflow too): SimulationError after that
    one growth, the state before the chunk (the grown one) attached; it is not grown a second time."""
    bits = ErrorCode.NEIGHBOR_OVERFLOW | other
    script = _Script([bits, bits])
    with pytest.raises(SimulationError) as raised:
        script.run(6)
    assert len(script.grown_from) == 1 and script.calls == [0, 1000] and raised.value.state == 1000
    assert str(raised.value) == f"bits {int(bits)} at 1002"


def test_a_chunk_that_runs_away_without_an_overflow_fails_at_once():
    """Non-finite alone: nothing to grow, SimulationError after the one launch."""
    script = _Script([ErrorCode.NOT_FINITE])
    with pytest.raises(SimulationError) as raised:
        script.run(6)
    assert script.grown_from == [] and script.calls == [0] and raised.value.state == 0


def test_growths_in_a_row_are_bounded():
    """A chunk that overflows whatever the tables: TABLE_GROWTHS growths, then SimulationError, not a hang."""
    script = _Script([ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW] * 100)
    with pytest.raises(SimulationError):
        script.run(6)
    assert len(script.grown_from) == driver.TABLE_GROWTHS
    assert len(script.calls) == driver.TABLE_GROWTHS + 1


def test_the_growth_count_restarts_after_an_accepted_chunk():
    """TABLE_GROWTHS − 1 overflows, a good chunk, then as many again: no error (growths *in a row*)."""
    below = driver.TABLE_GROWTHS - 1
    script = _Script([ErrorCode.NEIGHBOR_OVERFLOW] * below + [0] + [ErrorCode.NEIGHBOR_OVERFLOW] * below)
    _, left, accepted = script.run(4)
    assert len(script.grown_from) == 2 * below and len(accepted) == 2 and list(left) == [0]


def _pairs(idx, count):
    return {(int(i), int(j)) for i, j in np.asarray(idx).T if i < count and j < count}


def test_grown_tables_hold_every_pair_and_carry_every_spring():
    """An FCC block's list allocated at a fifth of its capacity (overflowed) is grown: the new list holds
    every pair closer than cutoff + skin (brute force), its capacity is at least TABLE_GROWTH × the old one,
    and a spring set on each old pair is found on the same pair (i, j) in the new list."""
    block = fcc.fcc_specimen(D, 4, 5)
    position = jnp.asarray(block.position)
    count = position.shape[0]
    lower = np.asarray(position).min(axis=0)
    upper = np.asarray(position).max(axis=0)
    tiny = neighbors.pair_neighbor_fn(lower, upper, D, 0.2 * D, D, capacity_multiplier=0.2)
    old = tiny.allocate(position)
    assert bool(old.did_buffer_overflow)
    old_pairs = np.asarray(old.idx).T
    # A spring per slot that encodes its pair: (i, j, 0) for real pairs.
    spring = np.stack([old_pairs[:, 0], old_pairs[:, 1], np.zeros(len(old_pairs))], axis=1)
    spring = jnp.asarray(spring, float)

    class Spheres:
        def __init__(self, position, neighbors, pair_spring):
            self.position, self.neighbors, self.pair_spring = position, neighbors, pair_spring

        def set(self, **changes):
            return Spheres(**{**vars(self), **changes})

    (grown,) = driver.grow_tables([Spheres(position, old, spring)], ErrorCode.NEIGHBOR_OVERFLOW, tiny)
    new = grown.neighbors
    assert not bool(new.did_buffer_overflow)
    assert new.idx.shape[1] >= np.ceil(driver.TABLE_GROWTH * old.idx.shape[1])
    distance = np.linalg.norm(np.asarray(position)[:, None] - np.asarray(position)[None], axis=-1)
    near = {(i, j) for i, j in zip(*np.nonzero(distance < D + 0.2 * D), strict=True) if i < j}
    assert near <= _pairs(new.idx, count)
    carried = np.asarray(grown.pair_spring)
    for slot, (i, j) in enumerate(np.asarray(new.idx).T):
        if i < count and (i, j) in _pairs(old.idx, count):
            assert tuple(carried[slot, :2]) == (i, j)
        else:
            assert not np.any(carried[slot])  # a new pair starts without a spring


def test_a_candidate_overflow_without_a_membrane_grower_cannot_grow():
    """grow_tables answers None (the driver then fails) when a candidate table overflowed and nobody can
    grow it: the rigid-wall test has no membrane."""
    assert driver.grow_tables([object()], ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW, frame=None) is None
