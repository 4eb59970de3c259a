"""The membrane's node–sphere candidate table: a cell list over every sphere, rebuilt on displacement.

Contract. In jax-md's "Dense" format, as :mod:`membrax.spheres.neighbors` is for sphere pairs:
:class:`NodeCandidates` holds, for each node, up to K sphere ids
(n_nodes, K) within R_i + t_m/2 + skin, in increasing id order, padded with N (the number of spheres).
Every sphere may be a candidate: :func:`build_candidates` bins the spheres' centres into a cell list
(:class:`CellGrid`, cubic cells of edge 2 R_max + skin ≥ R_i + t_m/2 + skin, so a node's candidates lie in
its own cell or the 26 around it) inside ``jit``, and checks each node against the spheres of those 27 cells
only: about 27 C distance checks per node (C spheres per cell) instead of N, so the cost grows with the
nodes, not with nodes × spheres. The grid is fixed when the table is first built (the spheres' bounding box
and one cell more); a node or sphere that leaves it is counted in the nearest boundary cell, which keeps
every pair within reach in neighbouring cells (clipping a cell index never separates two indices that
differ by at most one), so a specimen that bulges or shortens costs only fuller boundary cells.
:func:`update_candidates` rebuilds when any node or sphere moved more than skin/2 since the last build
(reference positions are kept), so no pair can come into contact unseen between rebuilds. A node with more
than K candidates, a cell with more than C spheres or a sphere held by more than M slots sets
``did_overflow`` (the table is then incomplete): :func:`candidate_errors` turns it into
``ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW`` (:mod:`membrax.errors`) for the state's error bitmask, so the
host driver reallocates with larger capacities (``max_count``, ``max_cell_count`` and
``max_sphere_count`` say how large) and reruns: contacts are never silently dropped. The springs,
(3, n_nodes, K), follow their sphere ids per node through rebuilds (:func:`remap_node_history`, the
per-row analogue of :func:`membrax.spheres.neighbors.remap_pair_history`). A table's capacities (K, M, C)
are :class:`CandidateCapacities`; after an overflow :func:`grown_candidate_capacities` says how large to
rebuild it, :func:`fitted_candidate_capacities` how narrow a resumed one may be. Cost at paper size (17,220
nodes, 1,816 spheres, K = 3, float32, 2 CPU cores): see ``benchmarks/bench_membrane.py``'s rebuild column.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.errors import ErrorCode
from membrax.vector import safe_norm

__all__ = [
    "ERROR_MEMBRANE_CANDIDATE_OVERFLOW",
    "CandidateCapacities",
    "CellGrid",
    "NodeCandidates",
    "build_candidates",
    "candidate_capacities",
    "candidate_errors",
    "cell_grid",
    "fitted_candidate_capacities",
    "grown_candidate_capacities",
    "needs_rebuild",
    "remap_node_history",
    "sphere_slot_table",
    "update_candidates",
]


# Alias of membrax.errors.ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW, kept for code written against this module.
ERROR_MEMBRANE_CANDIDATE_OVERFLOW = ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW


class CellGrid(NamedTuple):
    """The cell list's grid (static: part of the table's structure, fixed when the table is first built).

    Attributes:
      origin: (x, y, z) of the grid's lower corner, m.
      edge: the cells' edge, m; at least the largest reach R_i + t_m/2 + skin.
      dims: cells along x, y and z.
      cell_capacity: C, sphere slots per cell.
    """

    origin: tuple[float, float, float]
    edge: float
    dims: tuple[int, int, int]
    cell_capacity: int

    @property
    def num_cells(self) -> int:
        """The number of cells."""
        return self.dims[0] * self.dims[1] * self.dims[2]


def cell_grid(sphere_position, sphere_radius, skin, cell_capacity: int | None = None) -> CellGrid:
    """The grid of a candidate table for spheres at ``sphere_position`` (on the host, concrete arrays).

    Edge 2 R_max + skin: the reach R_i + t_m/2 + skin of every sphere for any membrane no thicker than the
    largest sphere's diameter (:func:`build_candidates` refuses a thicker one). The grid covers the
    spheres' bounding box and one cell more on each side. C defaults to the fullest cell's count now plus
    two (a sheared specimen's cells fill unevenly; an overflow grows C).

    Args:
      sphere_position: (N, 3), m.
      sphere_radius: (N,), m.
      skin: the table's skin, m.
      cell_capacity: C (default: from the spheres now, above).
    """
    position = np.asarray(sphere_position, dtype=np.float64)
    edge = 2.0 * float(np.max(np.asarray(sphere_radius))) + float(skin)
    lower = position.min(axis=0) - edge
    dims = tuple(int(n) for n in np.floor((position.max(axis=0) - lower) / edge).astype(int) + 2)
    grid = CellGrid(tuple(float(x) for x in lower), edge, dims, 1)
    if cell_capacity is None:
        counts = np.bincount(np.asarray(_flat_cell(grid, position)), minlength=grid.num_cells)
        cell_capacity = int(counts.max()) + 2
    return grid._replace(cell_capacity=int(cell_capacity))


def _cell_coordinates(grid: CellGrid, position):
    """(n, 3) int32 cell coordinates of rows of ``position``, clipped into the grid (see the module doc)."""
    origin = jnp.asarray(grid.origin, position.dtype)
    edge = jnp.asarray(grid.edge, position.dtype)
    coordinates = jnp.floor((position - origin[None, :]) / edge).astype(jnp.int32)
    return jnp.clip(coordinates, 0, jnp.asarray(grid.dims, jnp.int32)[None, :] - 1)


def _flat_cell(grid: CellGrid, position):
    """(n,) int32 flat cell ids (x fastest)."""
    c = _cell_coordinates(grid, jnp.asarray(position))
    return c[:, 0] + grid.dims[0] * (c[:, 1] + grid.dims[1] * c[:, 2])


@pytree.dataclass
class NodeCandidates:
    """Dense node → sphere candidate table and the state that decides when to rebuild it.

    Attributes:
      idx: (n_nodes, K) int32 sphere ids, increasing along a row, padded with N (number of spheres).
      reference_node_position: (n_nodes, 3) node positions at the last build, m.
      reference_sphere_position: (N, 3) sphere positions at the last build, m.
      skin: the extra distance, m (scalar); rebuild when anything moved more than skin/2.
      did_overflow: bool, sticky: some node had more than K candidates, some cell more than C spheres, or
        some sphere more than M slots, at a build.
      max_count: int32, the largest number of candidates of one node at any build since the table was
        allocated (:func:`build_candidates`; :func:`update_candidates` keeps the largest).
      sphere_slots: (N, M) int32, for each sphere the flat ids (into ``idx.reshape(-1)``) of the slots that
        hold it, padded with n_nodes·K: the incidence the sphere forces are summed over
        (:func:`sphere_slot_table`).
      max_sphere_count: int32, the largest number of slots of one sphere, likewise.
      max_cell_count: int32, the largest number of spheres in one cell, likewise.
      grid: the cell list's :class:`CellGrid` (static).
      extra_reach: m (static, default 0): sphere i is a candidate of a node within R_i + t_m/2 +
        ``extra_reach`` + skin, so that a table for contacts anywhere on the node's triangles
        (:mod:`membrax.membrane.face_contact`) holds every sphere within reach of any point of them.
    """

    idx: jnp.ndarray
    reference_node_position: jnp.ndarray
    reference_sphere_position: jnp.ndarray
    skin: jnp.ndarray
    did_overflow: jnp.ndarray
    max_count: jnp.ndarray
    sphere_slots: jnp.ndarray
    max_sphere_count: jnp.ndarray
    max_cell_count: jnp.ndarray
    grid: CellGrid = pytree.static_field()
    extra_reach: float = pytree.static_field(default=0.0)

    @property
    def capacity(self) -> int:
        """K."""
        return self.idx.shape[-1]

    @property
    def sphere_capacity(self) -> int:
        """M, slots per sphere."""
        return self.sphere_slots.shape[-1]

    @property
    def cell_capacity(self) -> int:
        """C, spheres per cell."""
        return self.grid.cell_capacity


# The 27 cells around a cell (itself included), as offsets.
_NEIGHBOUR_CELLS = np.stack(np.meshgrid(*([np.arange(-1, 2)] * 3), indexing="ij"), axis=-1).reshape(-1, 3)


def _cell_table(grid: CellGrid, sphere_position):
    """The spheres of each cell, and the largest count.

    Returns (num_cells + 1, C) int32 ids padded with N, the last row an empty cell that neighbours outside
    the grid point to.
    """
    num_spheres = sphere_position.shape[0]
    cell = _flat_cell(grid, sphere_position)
    order = jnp.argsort(cell, stable=True).astype(jnp.int32)
    sorted_cell = cell[order]
    cells = jnp.arange(grid.num_cells, dtype=jnp.int32)
    start = jnp.searchsorted(sorted_cell, cells, side="left").astype(jnp.int32)
    count = jnp.searchsorted(sorted_cell, cells, side="right").astype(jnp.int32) - start
    column = jnp.arange(grid.cell_capacity, dtype=jnp.int32)
    take = jnp.minimum(start[:, None] + column[None, :], num_spheres - 1)
    table = jnp.where(column[None, :] < count[:, None], order[take], num_spheres)
    table = jnp.concatenate([table, jnp.full((1, grid.cell_capacity), num_spheres, jnp.int32)])
    return table.astype(jnp.int32), jnp.max(count, initial=0)


def _select_candidates(
    node_position,
    sphere_position,
    sphere_radius,
    grid: CellGrid,
    membrane_thickness,
    skin,
    capacity: int,
    extra_reach: float = 0.0,
):
    """Per node the K smallest sphere ids within R + t_m/2 (+ extra_reach) + skin, from the 27 cells around.

    Returns (idx, max_count, max_cell_count).
    """
    num_spheres = sphere_position.shape[0]
    table, max_cell_count = _cell_table(grid, sphere_position)
    dims = jnp.asarray(grid.dims, jnp.int32)
    offsets = jnp.asarray(_NEIGHBOUR_CELLS, jnp.int32)[None, :, :]
    around = _cell_coordinates(grid, node_position)[:, None, :] + offsets  # (n, 27, 3)
    inside = jnp.all((around >= 0) & (around < dims[None, None, :]), axis=-1)
    flat = around[..., 0] + grid.dims[0] * (around[..., 1] + grid.dims[1] * around[..., 2])
    ids = table[jnp.where(inside, flat, grid.num_cells)].reshape(node_position.shape[0], -1)  # (n, 27 C)
    valid = ids < num_spheres
    safe = jnp.where(valid, ids, 0)
    reach = sphere_radius[safe] + 0.5 * membrane_thickness + skin
    if extra_reach:  # static: a node table's arithmetic stays as it was
        reach = reach + extra_reach
    squared = jnp.zeros(ids.shape, dtype=node_position.dtype)
    for axis in range(3):  # written out: no reduction over a size-3 axis
        difference = node_position[:, axis][:, None] - sphere_position[:, axis][safe]
        squared = squared + difference * difference
    within = valid & (squared < reach * reach)
    count = jnp.sum(within, axis=1, dtype=jnp.int32)

    # K passes of "smallest id above the previous": the row in increasing id order (8× faster than
    # lax.top_k on XLA-CPU for a brute-force table; the same order as a search over spheres in id order).
    # Unrolled and stacked as columns: a scan's (K, n_nodes) rows transposed made XLA keep the table
    # column-major through the rebuild's cond and copy it to the kernels' row-major layout on every step
    # (three copies, 31 µs per paper-size member-step).
    found = [jnp.full((node_position.shape[0],), -1, dtype=jnp.int32)]
    for _ in range(capacity):
        found.append(jnp.min(jnp.where(within & (ids > found[-1][:, None]), ids, num_spheres), axis=1))
    return jnp.stack(found[1:], axis=1).astype(jnp.int32), jnp.max(count, initial=0), max_cell_count


def sphere_slot_table(idx, num_spheres: int, sphere_capacity: int):
    """Incidence of a candidate table seen from the spheres: which slots hold each sphere.

    Sorts the flat slots by their sphere id (padding last); sphere i owns the run [start_i, start_i +
    count_i) of the sorted order, found by binary search.

    Args:
      idx: (n_nodes, K) int sphere ids padded with ``num_spheres``.
      num_spheres: N.
      sphere_capacity: M, slots kept per sphere (static).

    Returns:
      (slots, max_count): (N, M) int32 flat slot ids padded with n_nodes·K, and the largest count.
    """
    num_slots = idx.size
    owner = idx.reshape(-1)
    order = jnp.argsort(owner, stable=True).astype(jnp.int32)
    sorted_owner = owner[order]
    rows = jnp.arange(num_spheres, dtype=owner.dtype)
    start = jnp.searchsorted(sorted_owner, rows, side="left").astype(jnp.int32)
    count = jnp.searchsorted(sorted_owner, rows, side="right").astype(jnp.int32) - start
    column = jnp.arange(sphere_capacity, dtype=jnp.int32)
    take = jnp.minimum(start[:, None] + column[None, :], num_slots - 1)
    slots = jnp.where(column[None, :] < count[:, None], order[take], num_slots)
    return slots.astype(jnp.int32), jnp.max(count, initial=0)


def _build(
    node_position,
    sphere_position,
    sphere_radius,
    grid,
    membrane_thickness,
    skin,
    capacity,
    sphere_capacity,
    extra_reach: float = 0.0,
):
    """A fresh table's fields (everything but the sticky overflow flag, which the callers combine)."""
    idx, max_count, max_cell_count = _select_candidates(
        node_position, sphere_position, sphere_radius, grid, membrane_thickness, skin, capacity, extra_reach
    )
    slots, max_sphere_count = sphere_slot_table(idx, sphere_position.shape[0], sphere_capacity)
    overflow = (
        (max_count > capacity) | (max_sphere_count > sphere_capacity) | (max_cell_count > grid.cell_capacity)
    )
    return NodeCandidates(
        idx=idx,
        reference_node_position=node_position,
        reference_sphere_position=sphere_position,
        skin=skin,
        did_overflow=overflow,
        max_count=max_count,
        sphere_slots=slots,
        max_sphere_count=max_sphere_count,
        max_cell_count=max_cell_count,
        grid=grid,
        extra_reach=extra_reach,
    )


#: :func:`_build` as one program. Called eagerly (a table's first build, on the host) its ~60 operations
#: (K passes of the smallest id, the sorts and searches) each compiled on their own for every new table
#: size; as one program they compile once. Inside a caller's ``jit`` it is inlined. Its outputs are ids and
#: counts, and the positions and skin passed through, so the table is the same either way.
_build_compiled = jax.jit(_build, static_argnums=(3, 6, 7, 8))


def build_candidates(
    node_position,
    sphere_position,
    sphere_radius,
    membrane_thickness,
    skin,
    capacity: int,
    sphere_capacity: int = 64,
    grid: CellGrid | None = None,
    extra_reach: float = 0.0,
) -> NodeCandidates:
    """Build the dense candidate table (jittable with the capacities, ``grid`` and ``extra_reach`` static).

    Args:
      node_position: (n_nodes, 3), m.
      sphere_position: (N, 3), m.
      sphere_radius: (N,), m.
      membrane_thickness: t_m, m (the contact's thickness); at most the largest sphere's diameter.
      skin: extra distance, m: sphere i is a candidate of a node when |x_node − x_i| < R_i + t_m/2 + skin.
      capacity: K, candidates per node (static). Must not exceed N.
      sphere_capacity: M, slots per sphere in the incidence table (static). A 25 mm sphere behind a mesh of
        5 mm edges with a 5 mm skin holds about 25–50 slots.
      grid: the cell list's grid (default :func:`cell_grid` of the spheres and ``skin`` + ``extra_reach``:
        concrete positions and skin are then needed, i.e. not under ``jit``).
      extra_reach: m, added to every sphere's reach (:class:`NodeCandidates`); a Python float.

    Returns:
      A :class:`NodeCandidates`; ``did_overflow`` is set if some node had more than K candidates, some
      cell more than C spheres or some sphere more than M slots.
    """
    num_spheres = sphere_position.shape[0]
    if capacity > num_spheres:
        raise ValueError(f"capacity {capacity} exceeds the {num_spheres} spheres.")
    extra_reach = float(extra_reach)
    if grid is None:
        grid = cell_grid(sphere_position, sphere_radius, float(skin) + extra_reach)
    if not any(isinstance(x, jax.core.Tracer) for x in (membrane_thickness, sphere_radius)):
        largest = float(np.max(np.asarray(sphere_radius)))
        if float(np.max(np.asarray(membrane_thickness))) > 2.0 * largest:
            raise ValueError(
                f"membrane_thickness {float(np.max(np.asarray(membrane_thickness))):.4g} m exceeds the "
                f"largest sphere's diameter {2.0 * largest:.4g} m: the cell list's reach assumes a membrane "
                "thinner than the particles."
            )
    skin = jnp.asarray(skin, dtype=node_position.dtype)
    arrays = (node_position, sphere_position, sphere_radius)
    return _build_compiled(*arrays, grid, membrane_thickness, skin, capacity, sphere_capacity, extra_reach)


def _max_displacement(position, reference):
    """Largest |x − x_ref| over rows, m."""
    difference = jnp.moveaxis(position - reference, -1, 0)  # component-first (membrax.vector)
    return jnp.max(safe_norm(difference), initial=0.0)


def needs_rebuild(candidates: NodeCandidates, node_position, sphere_position):
    """True when a node or a sphere moved more than skin/2 since the last build."""
    half_skin = 0.5 * candidates.skin
    node_moved = _max_displacement(node_position, candidates.reference_node_position)
    sphere_moved = _max_displacement(sphere_position, candidates.reference_sphere_position)
    return (node_moved > half_skin) | (sphere_moved > half_skin)


def remap_node_history(old_idx, new_idx, old_history, num_spheres: int, components_first: bool = False):
    """Carry per-slot history from one node candidate table to another by sphere id, row by row.

    Args:
      old_idx: (n_nodes, K_old) int sphere ids padded with ``num_spheres`` (distinct within a row).
      new_idx: (n_nodes, K_new) int, same convention.
      old_history: (n_nodes, K_old, ...) values per old slot, or (C, n_nodes, K_old) with
        ``components_first`` (the tangential springs).
      num_spheres: N (the padding value).
      components_first: the history's slot axes are its last two.

    Returns:
      (n_nodes, K_new, ...) history (or (C, n_nodes, K_new)): the old value of the same (node, sphere)
      pair, zero elsewhere.
    """
    sources = _slot_sources(old_idx, new_idx, num_spheres)
    if components_first:
        return _carry_components(sources, old_history)
    return _carry_rows(sources, old_history)


def _slot_sources(old_idx, new_idx, num_spheres):
    """Which old slot holds each new slot's (real) sphere: (n_nodes, K_new), K_old where none does.

    int8 (int32 past 126 old slots). A row's ids are distinct, so a new slot matches one old slot at most.
    """
    match = (new_idx[:, :, None] == old_idx[:, None, :]) & (new_idx < num_spheres)[:, :, None]
    k_old = old_idx.shape[1]
    sources = jnp.where(jnp.any(match, axis=-1), jnp.argmax(match, axis=-1), k_old)
    return sources.astype(jnp.int8 if k_old < 127 else jnp.int32)


def _slot_match(sources, k_old: int, dtype):
    """(n_nodes, K_new, K_old) 0/1 of ``dtype``: new slot i takes old slot j."""
    return (sources[:, :, None] == jnp.arange(k_old, dtype=sources.dtype)[None, None, :]).astype(dtype)


# Both carries checkpointed, from the one small source table: reverse mode keeps it per step (not the two
# integer tables it came from, nor the (n_nodes, K, K) match), and the carry is linear in the history.
@jax.checkpoint
def _carry_rows(sources, old_history):
    flat = old_history.reshape((*old_history.shape[:2], -1))
    match = _slot_match(sources, flat.shape[1], flat.dtype)
    carried = jnp.einsum("nij,njc->nic", match, flat)
    return carried.reshape(sources.shape + old_history.shape[2:])


@jax.checkpoint
def _carry_components(sources, old_history):
    # An elementwise product and a sum over the short old-slot axis, in the (C, n_nodes, K) layout the
    # kernels use: moving the component axis last (as _carry_rows wants) made XLA give the springs a
    # transposed layout at the rebuild's cond and copy them back and forth on every step.
    match = _slot_match(sources, old_history.shape[-1], old_history.dtype)
    return jnp.sum(match[None] * old_history[:, :, None, :], axis=-1)


def update_candidates(
    candidates: NodeCandidates,
    spring,
    node_position,
    sphere_position,
    sphere_radius,
    membrane_thickness,
    with_rebuilt: bool = False,
):
    """Rebuild the table if needed (:func:`needs_rebuild`) and carry the springs to it (jittable).

    Args:
      candidates: the current :class:`NodeCandidates`.
      spring: (3, n_nodes, K) springs of the current table.
      node_position: (n_nodes, 3), m.
      sphere_position: (N, 3), m.
      sphere_radius: (N,), m.
      membrane_thickness: t_m, m.
      with_rebuilt: also return whether the table was rebuilt (static), for what is derived from it.

    Returns:
      (candidates, spring): the possibly rebuilt table, with ``did_overflow`` kept sticky and the counts
      the largest since allocation, and the springs
      remapped onto it by sphere id; with ``with_rebuilt``, (candidates, spring, rebuilt), rebuilt a bool.
    """
    num_spheres = sphere_position.shape[0]

    def rebuild(_):
        new = _build(
            node_position,
            sphere_position,
            sphere_radius,
            candidates.grid,
            membrane_thickness,
            candidates.skin,
            candidates.capacity,
            candidates.sphere_capacity,
            candidates.extra_reach,
        )
        # The counts are kept as the largest since the table was allocated, as the overflow flag is: a
        # later, smaller build must not hide from the host which capacity ran out (it grows only that one).
        new = new.set(
            did_overflow=candidates.did_overflow | new.did_overflow,
            max_count=jnp.maximum(candidates.max_count, new.max_count),
            max_sphere_count=jnp.maximum(candidates.max_sphere_count, new.max_sphere_count),
            max_cell_count=jnp.maximum(candidates.max_cell_count, new.max_cell_count),
        )
        return new, remap_node_history(candidates.idx, new.idx, spring, num_spheres, components_first=True)

    def keep(_):
        return candidates, spring

    rebuilt = needs_rebuild(candidates, node_position, sphere_position)
    table, carried = jax.lax.cond(rebuilt, rebuild, keep, None)
    return (table, carried, rebuilt) if with_rebuilt else (table, carried)


def candidate_errors(candidates: NodeCandidates):
    """int32 error bits for the state's bitmask: ``ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW`` on overflow."""
    return jnp.where(candidates.did_overflow, ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW, 0).astype(jnp.int32)


class CandidateCapacities(NamedTuple):
    """The static sizes of a node candidate table (:class:`NodeCandidates`).

    Attributes:
      capacity: K, candidates per node.
      sphere_capacity: M, slots per sphere.
      cell_capacity: C, spheres per cell of the cell list.
    """

    capacity: int
    sphere_capacity: int
    cell_capacity: int


def candidate_capacities(candidates) -> CandidateCapacities:
    """(K, M, C) of a candidate table (of one state, or stacked)."""
    capacity, sphere_capacity = np.shape(candidates.idx)[-1], np.shape(candidates.sphere_slots)[-1]
    return CandidateCapacities(int(capacity), int(sphere_capacity), candidates.cell_capacity)


def grown_candidate_capacities(old, overflowed) -> CandidateCapacities:
    """(K, M, C) after a candidate-table overflow: slots per node, per sphere and spheres per cell.

    Only what ran out grows, so that an overflow of the sphere slots does not widen every node's row (under
    face contact each triangle visits 3 K slots and each edge 2 K, every step):
    K = max(the largest count + 2, ⌈1.5 K_old⌉) if that count exceeds K_old, at most the number of spheres;
    M = the largest per-sphere count + 8 if it exceeds M_old; C = the fullest cell + 2 if it exceeds C_old;
    each otherwise unchanged. The counts are the largest since the table was allocated
    (:func:`update_candidates`). Should none exceed its capacity, K grows by
    ⌈1.5 K_old⌉, so that a rerun never meets the same tables.
    ``old`` and ``overflowed`` are candidate tables (of one state, or stacked: the largest over the
    members).
    """
    num_spheres = int(np.shape(old.reference_sphere_position)[-2])
    current = candidate_capacities(old)
    count, sphere_count, cell_count = (
        int(np.max(np.asarray(getattr(overflowed, name))))
        for name in ("max_count", "max_sphere_count", "max_cell_count")
    )
    grow_nodes = count > current.capacity
    grow_spheres = sphere_count > current.sphere_capacity
    grow_cells = cell_count > current.cell_capacity
    if not (grow_nodes or grow_spheres or grow_cells):
        grow_nodes = True
    capacity = max(count + 2, math.ceil(1.5 * current.capacity)) if grow_nodes else current.capacity
    sphere_capacity = sphere_count + 8 if grow_spheres else current.sphere_capacity
    cell_capacity = cell_count + 2 if grow_cells else current.cell_capacity
    return CandidateCapacities(min(capacity, num_spheres), sphere_capacity, cell_capacity)


def fitted_candidate_capacities(table) -> CandidateCapacities:
    """(K, M, C) of ``table`` with K cut back to its largest count + 2 where it is wider (M and C kept).

    A table grown for a passing need keeps padding every node's row; under face contact each step visits
    3 K slots per triangle and 2 K per edge, so a row three times too wide costs the face law about that
    much. The width only pads the rows: it changes no bit of a run (``tests/test_membrane_dem.py``).
    ``table`` is a candidate table (of one state, or stacked: the largest count over the members).
    """
    current = candidate_capacities(table)
    needed = int(np.max(np.asarray(table.max_count))) + 2
    return current._replace(capacity=min(current.capacity, needed))
