"""membrax's errors: the bits that ride in a simulation state, and the exceptions raised on the host.

Contract. Every state that can fail carries an int32 ``error`` mask; a jitted step ORs in the bits of
:class:`ErrorCode` (``jnp.where(condition, ErrorCode.NOT_FINITE, 0)``) and never raises. The host-side
chunk driver reads the mask after each compiled chunk: the overflow bits (:data:`OVERFLOWS`) mean "grow a
capacity and rerun the chunk", every other bit stops the run with :func:`describe`'s messages. This
module is the one list of bits and messages (jax-md's ``partition.PartitionErrorCode`` is the model);
it imports nothing from membrax, so every layer can use it. :func:`not_finite_bit` is the steps' one
finiteness check.

The exceptions, each carrying a message that names what to change:

- :class:`ConfigError`: an invalid configuration (:mod:`membrax.config`), every bad field at once;
- :class:`SimulationError`: a compiled run stopped on an error bit (:mod:`membrax.driver`), with the state
  and records computed before it;
- :class:`RunError`: a run or sweep stopped (non-finite values or runaway kinetic energy), with its records
  so far (:mod:`membrax.runner`).
"""

from __future__ import annotations

import enum
import functools
import operator
import os
from collections.abc import Iterable

import jax.numpy as jnp

__all__ = [
    "OVERFLOWS",
    "ConfigError",
    "ErrorCode",
    "RunError",
    "SimulationError",
    "describe",
    "not_finite_bit",
]


class ErrorCode(enum.IntFlag):
    """The bits of a state's ``error`` mask.

    Attributes:
      NONE: no error.
      NEIGHBOR_OVERFLOW: the sphere–sphere neighbour list ran out of slots (the driver grows it).
      NOT_FINITE: a position or velocity became NaN or infinite.
      OUTSIDE_BOX: a sphere left the neighbour list's box.
      MEMBRANE_CANDIDATE_OVERFLOW: a membrane node had more candidate spheres than its table holds (the
        driver grows the table).
      MEMBRANE_LOCKED: a membrane triangle under the Gent law was stretched past the fraction of its lock
        beyond which the energy is continued, no longer Gent's (:mod:`membrax.membrane.energies`).
      MEMBRANE_STIFFENED: a membrane triangle under the Gent law was stretched past s_stable, where the
        law's tangent stiffness has grown beyond what the time step tolerates, so that the explicit step
        would blow up (:func:`membrax.membrane.energies.gent_tangent_ratio`,
        :func:`membrax.membrane.stability.stiffened_bit`).
    """

    NONE = 0
    NEIGHBOR_OVERFLOW = 1
    NOT_FINITE = 2
    OUTSIDE_BOX = 4
    MEMBRANE_CANDIDATE_OVERFLOW = 8
    MEMBRANE_LOCKED = 16
    MEMBRANE_STIFFENED = 32


#: The bits a driver answers by growing a capacity and rerunning the chunk.
OVERFLOWS = ErrorCode.NEIGHBOR_OVERFLOW | ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW

_MESSAGES = {
    ErrorCode.NEIGHBOR_OVERFLOW: "neighbour list overflow",
    ErrorCode.NOT_FINITE: "non-finite position or velocity (reduce the time step or stiffness)",
    ErrorCode.OUTSIDE_BOX: "a particle left the neighbour-list box (increase the margin)",
    ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW: (
        "membrane node candidate table overflow (give the chunk runner a grow_membrane function)"
    ),
    ErrorCode.MEMBRANE_LOCKED: (
        "membrane stretched near its Gent lock (I1 - 3 past 0.9 J_m; raise membrane_locking_jm, the "
        "membrane's thickness or modulus, or lower the cell pressure)"
    ),
    ErrorCode.MEMBRANE_STIFFENED: (
        "membrane stiffened past its stable step: a triangle's (I1 - 3)/J_m passed s_stable, where the Gent "
        "law's tangent stiffness outgrows the time step (lower dt_safety, raise membrane_locking_jm, or "
        "lower the cell pressure)"
    ),
}


def not_finite_bit(*arrays):
    """:attr:`ErrorCode.NOT_FINITE` if an entry of ``arrays`` is NaN or infinite, else 0 (jittable).

    Tested on each array's sum: IEEE arithmetic carries a NaN or an infinity into the sum (∞ − ∞ is NaN),
    so the sum is finite exactly when every entry is, unless the entries' magnitudes add up past the
    dtype's largest number (3.4e38 in float32), far beyond any position in m or velocity in m/s. One
    reduction per array: ``jnp.all(jnp.isfinite(x))`` ran on XLA-CPU as a pass writing a boolean array,
    a windowed reduction and a final one, 74 µs per step for a paper-size membrane's positions and
    velocities (``benchmarks/profile_step.py``). A maximum of ``|x|`` is no substitute: XLA-CPU's
    reduction drops NaN.
    """
    finite = functools.reduce(operator.and_, (jnp.isfinite(jnp.sum(array)) for array in arrays))
    return jnp.where(finite, 0, ErrorCode.NOT_FINITE)


def describe(error: int) -> list[str]:
    """The messages of the bits set in ``error`` (an int or a 0-d integer array), lowest bit first."""
    error = int(error)
    return [message for bit, message in _MESSAGES.items() if error & bit]


class ConfigError(ValueError):
    """An invalid configuration: the message names each bad field, its accepted range or type and the fix.

    Attributes:
      errors: one message per problem, in the order found (unknown keys first, then fields in order).
      source: where the configuration came from (a file path), or ``None``.
    """

    def __init__(self, errors: str | Iterable[str], source: str | os.PathLike | None = None):
        self.errors = (errors,) if isinstance(errors, str) else tuple(errors)
        self.source = None if source is None else os.fspath(source)
        where = f" in {self.source}" if self.source is not None else ""
        if len(self.errors) == 1:
            prefix = f"{self.source}: " if self.source is not None else ""
            message = f"{prefix}{self.errors[0]}"
        else:
            lines = "\n".join(f"  - {error}" for error in self.errors)
            message = f"{len(self.errors)} problems in the triaxial configuration{where}:\n{lines}"
        super().__init__(message)


class SimulationError(RuntimeError):
    """A run stopped on an error bit; ``state`` and ``records`` hold what was computed before it.

    Also raised (``state`` and ``records`` None) by a host loop that can make no more progress, e.g. the
    frictionless search of :mod:`membrax.spheres.compaction` (its "Budgets"); the message names the loop's
    state and what to change.
    """

    def __init__(self, message, state=None, records=None):
        super().__init__(message)
        self.state = state
        self.records = records


class RunError(RuntimeError):
    """The simulation stopped (non-finite values or runaway energy); the message says what to change.

    ``records`` holds the records computed before the stop (:func:`run_group`'s by phase), or None.
    """

    def __init__(self, message, records=None):
        super().__init__(message)
        self.records = records
