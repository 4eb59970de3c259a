"""Batching a parameter study: the folded system (CPU) and stacked states for ``vmap`` (GPU).

Contract. A batch of B specimens that differ only in parameters (contact law, damping, wall stresses, …)
runs as one compiled call in either of two layouts:

- **folded**: the B specimens become one system of B·N spheres, member b shifted along x by b × spacing
  (spacing > specimen width + cutoff, so members never interact and one neighbour list serves all);
  ``Particles.member`` tells each sphere its member, walls carry a member axis, and parameters are arrays
  over members. The gather/scatter kernels then run once over B·N spheres: as fast as serial for small
  specimens, 12–43 % slower at paper size where the arrays leave the cache (``benchmarks/bench_dem.py``).
- **stacked**: B independent single-member states stacked on a leading axis (:func:`stack`), run by
  :func:`map_members` (``lax.map``: members in turn inside one compiled call — the fastest CPU path,
  because each member's arrays stay in cache) or :func:`vmap_members` (``vmap``: the GPU path; on a
  2-core CPU a ``vmap`` of gather/scatter code is several times slower than serial). Neighbour lists
  cannot be allocated inside ``vmap`` (jax-md #101): each member's list is allocated outside, with one
  capacity for all (jax-md #192).

:func:`fold` / :func:`unfold` convert per-particle arrays; :func:`member_offsets` gives the shifts (to apply
to wall positions: a plane x·e = h of member b moves to h + offset_b·e).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["fold", "map_members", "member_offsets", "stack", "unfold", "vmap_members"]


def map_members(run_fn):
    """Batch ``run_fn(state, params)`` over stacked members with ``lax.map`` (one call, members in turn).

    The CPU path: each member's arrays stay cache-sized (a folded 9 × 1,816-sphere system spills the
    pair arrays out of L2 and ran 12 % (float32) to 43 % (float64) slower than serial), and there is one
    dispatch for the whole batch. Apply it to a whole chunk (a ``fori_loop`` of steps), not to one step.
    """
    return lambda states, params: jax.lax.map(lambda member: run_fn(*member), (states, params))


def vmap_members(run_fn):
    """Batch ``run_fn(state, params)`` over stacked members with ``vmap``: the GPU path (data parallel)."""
    return jax.vmap(run_fn)


def member_offsets(num_members: int, spacing: float) -> np.ndarray:
    """(B, 3) shifts of the members of a folded batch: member b at (b·spacing, 0, 0)."""
    offsets = np.zeros((num_members, 3))
    offsets[:, 0] = spacing * np.arange(num_members)
    return offsets


def fold(position, num_members: int, spacing: float):
    """Replicate one specimen's (N, 3) positions into a folded batch.

    Returns:
      (positions (B·N, 3), member ids (B·N,) int32).
    """
    position = jnp.asarray(position)
    n = position.shape[0]
    offsets = jnp.asarray(member_offsets(num_members, spacing), dtype=position.dtype)
    folded = (position[None, :, :] + offsets[:, None, :]).reshape(num_members * n, 3)
    member = jnp.repeat(jnp.arange(num_members, dtype=jnp.int32), n)
    return folded, member


def unfold(values, num_members: int):
    """Split a folded per-particle array (B·N, ...) into (B, N, ...)."""
    values = jnp.asarray(values)
    return values.reshape(num_members, values.shape[0] // num_members, *values.shape[1:])


def stack(trees):
    """Stack a list of pytrees of equal structure along a new leading axis (for ``vmap``)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *trees)
