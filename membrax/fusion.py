"""Fusion control: compute an intermediate once where XLA-CPU would recompute it in every consumer.

Contract. :func:`materialize` is the identity on a tuple of arrays, under ``jit``, ``vmap``, ``grad``
and ``jvp`` alike (values and derivatives unchanged, bit for bit). On the CPU backend it also stops XLA
from fusing the arrays' producers into their consumers, so each array is computed once and stored; on
other backends, and on concrete arrays outside any trace (nothing is fused there), it is a plain identity.

Why. XLA-CPU fuses chains of cheap elementwise operations (adds, multiplies, selects) into each consumer
and has no multi-output loop fusion, so a per-contact formula that feeds three vector components and two
outputs (a carried spring and a force) is evaluated six times. At paper size (51,660 node–sphere slots)
storing the law's intermediates took the contact forces from 407 to 845 evaluations/s in float32
(``benchmarks/bench_membrane.py``, same machine). ``jax.lax.optimization_barrier`` does not help there:
XLA-CPU removes it before fusion. A conditional does survive, and its result is stored, so :func:`materialize`
wraps the arrays in ``lax.cond`` on a predicate that is always true but that XLA cannot fold
(x = x or x ≠ x, true even for NaN, so no value is ever replaced). The predicate stays unbatched under
``vmap`` (a custom batching rule applies the same conditional to the batched arrays), because a batched
``cond`` becomes a ``select`` and would be fused again.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["materialize"]


def _stored(*arrays):
    """The conditional that XLA-CPU keeps: both branches run nothing but the true one is ever taken."""
    probe = arrays[0].ravel()[0]
    always = (probe == probe) | (probe != probe)  # true for every value, NaN included
    return lax.cond(always, lambda: arrays, lambda: tuple(jnp.zeros_like(a) for a in arrays))


def _on_platform(*arrays):
    return lax.platform_dependent(*arrays, cpu=_stored, default=lambda *xs: xs)


@jax.custom_batching.custom_vmap
def _batched_identity(*arrays):
    return _on_platform(*arrays)


@_batched_identity.def_vmap
def _batched_identity_vmap(axis_size, in_batched, *arrays):
    del axis_size
    # The batched arrays go through the same unbatched conditional: its predicate stays a scalar.
    return _on_platform(*arrays), tuple(in_batched)


@jax.custom_jvp
def _identity(*arrays):
    return _batched_identity(*arrays)


@_identity.defjvp
def _identity_jvp(primals, tangents):
    # The identity's derivative is the identity; tangents need no storing.
    return _identity(*primals), tuple(tangents)


def materialize(*arrays):
    """The arrays unchanged, each computed once on XLA-CPU (see the module docstring).

    Args:
      *arrays: one or more arrays (not empty, floating or integer or boolean).

    Returns:
      A tuple of the same arrays (a single array if one was given).
    """
    if not arrays:
        raise ValueError("materialize needs at least one array.")
    arrays = tuple(jnp.asarray(a) for a in arrays)
    # Outside any trace (eager calls, as the tests make of the reference laws) each operation runs and is
    # stored on its own: there is no fusion to stop, and the conditional would be one more program compiled
    # per shape (about 600 of the test suite's eager calls).
    if arrays[0].size == 0 or not any(isinstance(a, jax.core.Tracer) for a in arrays):
        return arrays[0] if len(arrays) == 1 else arrays
    out = tuple(_identity(*arrays))
    return out[0] if len(out) == 1 else out
