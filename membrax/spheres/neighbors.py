"""Neighbour (candidate-contact) lists with contact history that survives rebuilds.

Contract. :func:`pair_neighbor_fn` wraps ``jax_md.partition.neighbor_list`` in free space with the
``OrderedSparse`` format: ``nbrs.idx`` is (2, capacity) with each candidate pair (i < j) once, padded
with ``num_particles``. ``nbrs.update(position)`` runs inside ``jit`` and rebuilds the list when a particle
has moved more than half the skin since the last build; if the list then holds more pairs than its
static capacity, ``nbrs.did_buffer_overflow`` (a uint8, not a bool) is set and the pairs are incomplete.
The chunk driver (:mod:`membrax.driver`) checks it between jitted chunks, reallocates a larger list on
the host, and reruns the chunk, so contacts are never silently dropped.

Contact history (the tangential springs) is stored per pair slot. :func:`remap_pair_history` moves it from
an old list to a new one by matching the partner ids (key i·N + j), so a rebuild or a reallocation keeps
every spring of a pair that is still a candidate; pairs that left the list lose theirs (they are more than
the cutoff apart, so their contact had opened and the spring was zero anyway).

Why jax-md's cell list: it is maintained, handles the free-space box, and its rebuild is triggered by
displacement, not by step count, so a slowly shearing FCC specimen rebuilds rarely (measured in
``benchmarks/bench_dem.py``). Its cell hashing needs every position inside [0, box): callers pass
positions shifted by ``origin`` (see :class:`PairNeighborFn`), and :func:`outside_box` reports a particle
that left the box (an error bit in the state) instead of letting the list silently miss it. jax-md mixes
dtypes and ranks internally, so its calls run under local standard promotion: membrax works when a user
(or the test suite) sets ``jax_numpy_dtype_promotion="strict"`` and ``jax_numpy_rank_promotion="raise"``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import sys
import types
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


def _jax_md_modules():
    """jax-md's ``space`` and ``partition``, the two modules membrax uses, without its package's import.

    ``import jax_md`` runs the package's ``__init__``, which imports every submodule: ``rigid_body`` (array
    code at import, ~130 small compiled programs) and ``nn`` (flax, e3nn) took 14–16 s of a 2-core machine's
    time, every process that imports membrax (measured 2026-11-29). Where the package is not imported yet,
    a bare package module stands in for it while its two submodules load (their own imports, ``util`` and
    ``dataclasses``, are light: 0.1 s in all), then is removed again, so that a later ``import jax_md``
    runs the real ``__init__``, which finds the submodules already loaded and binds the same objects.
    """
    if "jax_md" in sys.modules:
        from jax_md import partition, space

        return space, partition
    spec = importlib.util.find_spec("jax_md")
    if spec is None or spec.submodule_search_locations is None:
        raise ImportError("membrax needs jax-md (pip install 'jax-md>=0.2.29').")
    stand_in = types.ModuleType("jax_md")
    stand_in.__spec__, stand_in.__path__ = spec, list(spec.submodule_search_locations)
    sys.modules["jax_md"] = stand_in
    try:
        from jax_md import partition, space
    finally:
        if sys.modules.get("jax_md") is stand_in:
            del sys.modules["jax_md"]
    return space, partition


# This is membrax's only import of jax-md (its dataclasses are membrax.pytree's). jax-md's modules may run
# array code when imported, which fails under a caller's strict dtype or rank promotion (the test suite's
# setting): they are imported under the standard rules.
with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
    space, partition = _jax_md_modules()

__all__ = [
    "PairNeighborFn",
    "PeriodicNeighborFn",
    "allocate_shared",
    "outside_box",
    "pair_neighbor_fn",
    "periodic_neighbor_fn",
    "remap_pair_history",
    "remap_pair_history_if",
]

# Keys i·N + j must fit in int32 when x64 is off.
_MAX_PARTICLES = 46_340


class PairNeighborFn(NamedTuple):
    """A neighbour-list factory and the frame it works in.

    Attributes:
      neighbor_fn: the jax-md ``NeighborListFns`` (``allocate`` on the host, ``update`` under jit).
      origin: (3,) shift added to positions so the whole specimen sits inside [0, box).
      box: (3,) box size, m.
      cutoff: contact distance used for candidates (largest diameter), m.
      skin: extra distance; the list is rebuilt when a particle moved more than skin/2, m.
    """

    neighbor_fn: partition.NeighborListFns
    origin: np.ndarray
    box: np.ndarray
    cutoff: float
    skin: float

    def allocate(self, position, extra_capacity: int = 0):
        """Build a new list on the host (not jittable: its capacity is data dependent)."""
        with _jax_md_promotion():
            return self.neighbor_fn.allocate(position + self.origin[None, :], extra_capacity=extra_capacity)

    def update(self, position, neighbors):
        """Update under jit; rebuilds if needed and sets the overflow bit when capacity is short."""
        with _jax_md_promotion():
            return neighbors.update(position + jnp.asarray(self.origin, dtype=position.dtype)[None, :])


@contextlib.contextmanager
def _jax_md_promotion():
    """jax-md's cell list mixes dtypes and ranks; let it, locally, even when a user runs strict promotion."""
    with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
        yield


def pair_neighbor_fn(
    lower_corner,
    upper_corner,
    cutoff: float,
    skin: float,
    margin: float,
    capacity_multiplier: float = 1.25,
) -> PairNeighborFn:
    """Neighbour-list factory for spheres inside the axis-aligned region [lower, upper] plus a margin.

    Args:
      lower_corner: (3,) lowest coordinates any particle may reach (before the margin), m.
      upper_corner: (3,) highest coordinates, m.
      cutoff: contact distance (the largest particle diameter), m.
      skin: neighbour skin, m; a pair is a candidate when closer than cutoff + skin.
      margin: extra room on every side of the region (bulging, platen travel), m.
      capacity_multiplier: spare capacity over the pairs found at allocation.
    """
    lower = np.asarray(lower_corner, dtype=float) - margin
    upper = np.asarray(upper_corner, dtype=float) + margin
    box = upper - lower
    displacement, _ = space.free()
    neighbor_fn = partition.neighbor_list(
        displacement,
        box=jnp.asarray(box),
        r_cutoff=cutoff,
        dr_threshold=skin,
        capacity_multiplier=capacity_multiplier,
        format=partition.OrderedSparse,
    )
    return PairNeighborFn(neighbor_fn=neighbor_fn, origin=-lower, box=box, cutoff=cutoff, skin=skin)


def allocate_shared(frame: PairNeighborFn, positions, capacity: int = 0, cell_capacity: int = 0) -> list:
    """One neighbour list per member with identical static structure (capacities), so they stack.

    jax-md keeps the list's capacity and cell-list capacity as static fields (and a fresh cell-list
    closure per allocation), so lists allocated separately do not stack. Every member's list is rebuilt
    here from one template with the largest capacities needed (at least ``capacity``/``cell_capacity``):
    the template's reference position is moved away, which makes ``update`` rebuild at the member's
    positions. Real pairs come out in the same order as an allocation of their own; only the padding differs.
    """
    positions = [jnp.asarray(p) for p in positions]
    while True:
        allocated = [frame.allocate(p) for p in positions]
        occupancy = max([capacity] + [int(nl.max_occupancy) for nl in allocated])
        cells = max([cell_capacity] + [int(nl.cell_list_capacity or 0) for nl in allocated])
        template = allocated[0]
        if cells and template.format is not partition.NeighborListFormat.Dense:
            # A rebuild's table holds at most the cell list's candidates, N · 3^d · cell capacity
            # (jax-md truncates to the smaller), so a larger capacity than that cannot be asked for.
            count, dimension = positions[0].shape
            occupancy = min(occupancy, count * 3**dimension * cells)
        # The template's pair table must have the capacity it claims: update's rebuild and its no-rebuild
        # branch return tables of those two sizes, which lax.cond needs equal.
        padding = occupancy - template.idx.shape[-1]
        idx = jnp.pad(template.idx, ((0, 0), (0, max(padding, 0))), constant_values=positions[0].shape[0])
        # The overflow bit is sticky (jax-md ORs it into every update): an allocation that overflowed would
        # pass it to every rebuild from this template, however large.
        error = partition.PartitionError(jnp.zeros_like(template.error.code))
        template = template.set(
            idx=idx, max_occupancy=occupancy, cell_list_capacity=cells or None, error=error
        )
        away = jnp.full_like(template.reference_position, 1e6)
        lists = [frame.update(p, template.set(reference_position=away)) for p in positions]
        if not any(bool(nl.did_buffer_overflow) for nl in lists):
            return lists
        capacity, cell_capacity = math.ceil(1.5 * occupancy), math.ceil(1.5 * max(cells, 1))


def outside_box(position, neighbor_frame: PairNeighborFn):
    """True if any particle left the neighbour-list box (the cell list would then miss its contacts)."""
    shifted = position + jnp.asarray(neighbor_frame.origin, dtype=position.dtype)[None, :]
    box = jnp.asarray(neighbor_frame.box, dtype=position.dtype)[None, :]
    return jnp.any(shifted < 0.0) | jnp.any(shifted >= box)


class PeriodicNeighborFn(NamedTuple):
    """A neighbour-list factory for an orthorhombic periodic cell whose box lengths change in time.

    Positions are fractional, s ∈ [0, 1)³ (x = L ⊙ s), and every call takes the current box lengths L
    (jax-md's ``periodic_general`` space with ``fractional_coordinates=True``, its box a (3,) diagonal), so
    candidates are found with the minimum image at the current L.

    Rebuilds. A pair is a candidate when closer than cutoff + skin at the last build. Two motions eat the
    skin: each sphere's own motion in the cell's frame (jax-md rebuilds when one moved more than skin/4 in
    fractional coordinates measured at the current L, so a pair closes by at most skin/2 that way), and
    the box's homogeneous deformation, which changes every distance with no motion in fractional
    coordinates: a pair within cutoff + skin closes by at most (cutoff + skin) max_k |L_k/L_k,ref − 1|, so
    :meth:`update` forces a rebuild when that passes skin/2 (``reference_length``: L at the last build).

    Attributes:
      neighbor_fn: the jax-md ``NeighborListFns``.
      cutoff: contact distance (the largest diameter), m.
      skin: extra distance of the candidates, m.
    """

    neighbor_fn: partition.NeighborListFns
    cutoff: float
    skin: float

    def allocate(self, fraction, length, extra_capacity: int = 0):
        """Build a new list on the host at fractional positions ``fraction`` (N, 3), box lengths ``length``.

        The cell list's cells are sized for ``length`` (in fractional units cutoff/min L): a box that later
        shrinks makes them too small (jax-md's ``cell_size_too_small``; :meth:`needs_new_list`).
        """
        with _jax_md_promotion():
            return self.neighbor_fn.allocate(
                fraction, box=jnp.asarray(length, fraction.dtype), extra_capacity=extra_capacity
            )

    def update(self, fraction, neighbors, length, reference_length):
        """Update under jit at box lengths ``length``: (list, rebuilt).

        A rebuild is forced when the box deformed too far since ``reference_length`` (class docstring).
        """
        length = jnp.asarray(length, fraction.dtype)
        strain = jnp.max(jnp.abs(length / reference_length - 1.0))
        deformed = (self.cutoff + self.skin) * strain > 0.5 * self.skin
        # Half a cell away in fractional coordinates is half a box away at any L: jax-md then rebuilds.
        away = jnp.where(deformed, neighbors.reference_position + 0.5, neighbors.reference_position)
        with _jax_md_promotion():
            new = neighbors.set(reference_position=away).update(fraction, box=length)
        # A forced rebuild of spheres that did not move in the cell's frame leaves the reference as it was.
        rebuilt = deformed | jnp.any(new.reference_position != neighbors.reference_position)
        return new, rebuilt

    def reallocate(self, fraction, length, cell_length, capacity: int = 0):
        """A new list at box lengths ``length`` whose cells fit any box down to ``cell_length`` (host side).

        Allocated at ``cell_length`` (<= ``length``: every distance is smaller there, so the capacity found
        holds the pairs at ``length``), padded to at least ``capacity`` slots, then rebuilt at ``length``:
        :meth:`reallocate_shared` of one cell.
        """
        return self.reallocate_shared([fraction], [length], cell_length, capacity)[0]

    def reallocate_shared(self, fractions, lengths, cell_length, capacity: int = 0) -> list:
        """One list per cell with one static structure, so a batch's lists stack (host side).

        Each cell (fractional positions ``fractions[b]``, box ``lengths[b]``) is allocated at the common
        ``cell_length`` (one cell grid: jax-md keeps it in the list's static closure), the largest pair and
        cell capacities taken (at least ``capacity`` pairs), and every cell's list rebuilt from the first
        one's, padded to them (as :func:`allocate_shared`). A cell alone gets the list of its own allocation.
        """
        allocated = [self.allocate(fraction, cell_length) for fraction in fractions]
        occupancy = max([int(capacity)] + [int(listing.max_occupancy) for listing in allocated])
        cells = max(int(listing.cell_list_capacity or 0) for listing in allocated)
        template = allocated[0]
        padding = occupancy - template.idx.shape[-1]
        idx = jnp.pad(template.idx, ((0, 0), (0, max(padding, 0))), constant_values=fractions[0].shape[0])
        # The overflow bits are sticky (jax-md ORs them into every update): start clean.
        error = partition.PartitionError(jnp.zeros_like(template.error.code))
        template = template.set(
            idx=idx, max_occupancy=occupancy, cell_list_capacity=cells or None, error=error
        )
        lists = []
        for fraction, length in zip(fractions, lengths, strict=True):
            length = jnp.asarray(length, fraction.dtype)
            lists.append(self.update(fraction, template, length, 2.0 * length)[0])
        return lists

    @staticmethod
    def needs_new_list(neighbors):
        """True where the list overflowed or the box shrank below its cells: allocate a new list."""
        return (neighbors.did_buffer_overflow | neighbors.cell_size_too_small) > 0


def periodic_neighbor_fn(cutoff: float, skin: float, capacity_multiplier: float = 1.5) -> PeriodicNeighborFn:
    """Neighbour-list factory for an orthorhombic periodic cell (:class:`PeriodicNeighborFn`).

    Args:
      cutoff: contact distance (the largest particle diameter), m.
      skin: neighbour skin, m: half for the spheres' own motion, half for the box's deformation.
      capacity_multiplier: spare capacity over the pairs found at allocation.
    """
    # jax-md probes the displacement with float32 arrays: under local standard promotion, as its calls.
    with _jax_md_promotion():
        displacement, _ = space.periodic_general(jnp.ones(3), fractional_coordinates=True)
        neighbor_fn = partition.neighbor_list(
            displacement,
            box=jnp.ones(3),
            r_cutoff=cutoff + 0.5 * skin,
            dr_threshold=0.5 * skin,
            capacity_multiplier=capacity_multiplier,
            format=partition.OrderedSparse,
            fractional_coordinates=True,
        )
    return PeriodicNeighborFn(neighbor_fn=neighbor_fn, cutoff=cutoff, skin=skin)


def remap_pair_history(old_idx, new_idx, old_history, num_particles: int):
    """Carry per-pair history from one pair list to another by partner ids.

    Args:
      old_idx: (2, C_old) int pairs (i < j), padded with ``num_particles``.
      new_idx: (2, C_new) int pairs, same convention.
      old_history: (C_old, ...) values per old slot (e.g. tangential springs).
      num_particles: N (the padding value).

    Returns:
      (C_new, ...) history: the old value where the same (i, j) pair existed, zero elsewhere.
    """
    if num_particles > _MAX_PARTICLES:
        raise ValueError(
            f"num_particles = {num_particles} exceeds {_MAX_PARTICLES}: pair keys overflow int32."
        )
    n = num_particles
    # Padding pairs get a key above every real one and never match.
    old_key = jnp.where(old_idx[0] < n, old_idx[0] * n + old_idx[1], n * n + 1)
    new_key = jnp.where(new_idx[0] < n, new_idx[0] * n + new_idx[1], n * n + 2)
    order = jnp.argsort(old_key)
    sorted_key = old_key[order]
    slot = jnp.clip(jnp.searchsorted(sorted_key, new_key), 0, old_key.shape[0] - 1)
    found = sorted_key[slot] == new_key
    gathered = old_history[order[slot]]
    found = found.reshape(found.shape + (1,) * (old_history.ndim - 1))
    return jnp.where(found, gathered, jnp.zeros_like(gathered))


def remap_pair_history_if(rebuilt, old_idx, new_idx, old_history, num_particles: int):
    """:func:`remap_pair_history` where the pair list was ``rebuilt`` (a traced bool), else ``old_history``.

    A step's carry of its springs: the remap (a sort and a search) runs only in the steps that rebuilt.
    """
    return jax.lax.cond(
        rebuilt,
        lambda: remap_pair_history(old_idx, new_idx, old_history, num_particles),
        lambda: old_history,
    )
