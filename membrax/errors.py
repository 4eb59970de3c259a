"""Error bits that ride in a simulation state: set inside ``jit``, read on the host between chunks.

Contract. Every state that can fail carries an int32 ``error`` mask; a jitted step ORs in the bits of
:class:`ErrorCode` (``jnp.where(condition, ErrorCode.NOT_FINITE, 0)``) and never raises. The host-side
chunk driver reads the mask after each compiled chunk: the overflow bits (:data:`OVERFLOWS`) mean "grow a
capacity and rerun the chunk", every other bit stops the run with :func:`describe`'s messages. This
module is the one list of bits and messages (jax-md's ``partition.PartitionErrorCode`` is the model);
it imports nothing from membrax, so every layer can use it.
"""

from __future__ import annotations

import enum

__all__ = ["OVERFLOWS", "ErrorCode", "describe"]


class ErrorCode(enum.IntFlag):
    """The bits of a state's ``error`` mask.

    Attributes:
      NONE: no error.
      NEIGHBOR_OVERFLOW: the sphere–sphere neighbour list ran out of slots (the driver grows it).
      NOT_FINITE: a position or velocity became NaN or infinite.
      OUTSIDE_BOX: a sphere left the neighbour list's box.
      MEMBRANE_CANDIDATE_OVERFLOW: a membrane node had more candidate spheres than its table holds (the
        driver grows the table).
    """

    NONE = 0
    NEIGHBOR_OVERFLOW = 1
    NOT_FINITE = 2
    OUTSIDE_BOX = 4
    MEMBRANE_CANDIDATE_OVERFLOW = 8


#: The bits a driver answers by growing a capacity and rerunning the chunk.
OVERFLOWS = ErrorCode.NEIGHBOR_OVERFLOW | ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW

_MESSAGES = {
    ErrorCode.NEIGHBOR_OVERFLOW: "neighbour list overflow",
    ErrorCode.NOT_FINITE: "non-finite position or velocity (reduce the time step or stiffness)",
    ErrorCode.OUTSIDE_BOX: "a particle left the neighbour-list box (increase the margin)",
    ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW: (
        "membrane node candidate table overflow (give the chunk runner a grow_membrane function)"
    ),
}


def describe(error: int) -> list[str]:
    """The messages of the bits set in ``error`` (an int or a 0-d integer array), lowest bit first."""
    error = int(error)
    return [message for bit, message in _MESSAGES.items() if error & bit]
