"""Planning a batch: the members' common Δt and mesh, their work, and their order over devices.

Contract. Pure host-side planning for :mod:`membrax.executor`, which builds the batch: :func:`plan_members`
builds the membrane members' tests on one Δt and one n_θ and charges each its expected steps
(:func:`expected_steps`); :func:`plan_periodic_members` the same for periodic elements of one packing;
:func:`balanced_order` spreads the members over devices by that work; :func:`check_batch` refuses members
that cannot share one compiled batch (naming the fields that differ) and settles the mode and the device
count; :func:`checked_order` checks a given order. It runs nothing and compiles nothing but the tests'
own builds.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import jax

from membrax.assemble import (
    BATCHED_FIELDS,
    build_periodic_test,
    build_test,
    common_nodes_around,
    run_settings,
    structure_key,
)
from membrax.config import TriaxialConfig
from membrax.triaxial.protocol import PHASES

__all__ = [
    "balanced_order",
    "check_batch",
    "checked_order",
    "expected_steps",
    "plan_members",
    "plan_periodic_members",
]


def balanced_order(work: Sequence[float], num_devices: int) -> list[int]:
    """An order of the members whose contiguous device shares carry about equal work.

    ``shard_map`` gives device d the d-th contiguous block of the (padded) member axis, and a chunk lasts
    as long as its busiest device. Low-pressure members shear for the most steps (ε̇ ∝ √σc at a fixed
    inertial number), so grid order would load one device with them. Greedy longest-first (each member,
    heaviest first, to the least-loaded block with a free slot; the last block holds the padding), then
    swaps between the busiest block and another while they lower the busiest load.

    Args:
      work: each member's expected steps.
      num_devices: devices the member axis is split over.

    Returns:
      Member indices in batch order (a permutation of ``range(len(work))``).
    """
    count = len(work)
    per_device = math.ceil(count / num_devices)
    free = [per_device] * num_devices
    free[-1] -= per_device * num_devices - count
    blocks: list[list[int]] = [[] for _ in range(num_devices)]

    def load(block):
        return sum(work[i] for i in block)

    for b in sorted(range(count), key=lambda i: (-work[i], i)):
        d = min((d for d in range(num_devices) if free[d] > 0), key=lambda d: (load(blocks[d]), d))
        blocks[d].append(b)
        free[d] -= 1
    improved = True
    while improved:
        improved = False
        busiest = max(range(num_devices), key=lambda d: load(blocks[d]))
        for d in range(num_devices):
            for i, j in itertools.product(range(len(blocks[busiest])), range(len(blocks[d]))):
                a, b = blocks[busiest][i], blocks[d][j]
                gain = work[a] - work[b]
                if gain > 0 and load(blocks[d]) + gain < load(blocks[busiest]):
                    blocks[busiest][i], blocks[d][j] = b, a
                    improved = True
                    break
            if improved:
                break
    return [b for block in blocks for b in sorted(block)]


def plan_members(
    configs: Sequence[TriaxialConfig], time_step: float | None = None, nodes_around: int | None = None
) -> tuple[list, float, int, list[int]]:
    """The members' tests on a common Δt and n_θ, and each member's expected steps (its work).

    Args:
      configs: the members' configurations (one structure).
      time_step: the common Δt, s (default: the smallest of the members' own).
      nodes_around: the common n_θ (default: :func:`membrax.assemble.common_nodes_around`).

    Returns:
      (tests, Δt, n_θ, work): shear steps are planned; consolidation stops when its test holds (unknown
      beforehand, about alike for all members), so every member is charged two chunks of it.
    """
    nodes_around = common_nodes_around(configs) if nodes_around is None else int(nodes_around)
    tests = [build_test(c, time_step, nodes_around) for c in configs]
    dt = min(t.dt for t in tests)
    tests = [
        t if t.dt == dt else build_test(c, time_step=dt, nodes_around=nodes_around)
        for t, c in zip(tests, configs, strict=True)
    ]
    work = [expected_steps(t, run_settings(c)) for t, c in zip(tests, configs, strict=True)]
    return tests, float(dt), nodes_around, work


def plan_periodic_members(configs: Sequence[TriaxialConfig]) -> tuple[list, float, list[int]]:
    """The periodic members' tests (one packing, one Δt) and each one's expected steps (its work).

    Args:
      configs: the members' configurations (``cell = "periodic"``, one structure).

    Returns:
      (tests, Δt, work), work as :func:`plan_members`'.
    """
    tests = [build_periodic_test(c) for c in configs]
    work = [expected_steps(t, run_settings(c)) for t, c in zip(tests, configs, strict=True)]
    return tests, float(tests[0].dt), work


def expected_steps(test, settings) -> int:
    """A member's work: its planned shearing steps and two chunks of consolidation (or its cap)."""
    plan = test.phase_plan(settings.loading)
    consolidation = min(settings.loading.consolidation_max_steps, 2 * settings.chunk_steps)
    return consolidation + sum(plan[phase][0] for phase in PHASES[1:])


def check_batch(configs: list, num_devices: int | None, mode: str | None) -> tuple[str, int]:
    """(mode, devices) of a batch of ``configs``, after checking they can share one compiled batch."""
    if not configs:
        raise ValueError("no members to batch; give at least one configuration.")
    keys = {structure_key(c) for c in configs}
    if len(keys) > 1:
        first = dict(structure_key(configs[0]))
        differing = sorted({name for key in keys for name, value in key if value != first.get(name)})
        raise ValueError(
            f"members differ in {differing}, which cannot vary within one batch; batch only members that "
            f"differ in {sorted(BATCHED_FIELDS)} (run_sweep groups the rest)."
        )
    mode = mode or ("vmap" if jax.default_backend() == "gpu" else "map")
    if mode not in ("map", "vmap"):
        raise ValueError(f"mode = {mode!r}; give 'map' (CPU) or 'vmap' (GPU).")
    available = jax.local_device_count()
    num_devices = available if num_devices is None else int(num_devices)
    if not 1 <= num_devices <= available:
        raise ValueError(f"num_devices = {num_devices}; this process has {available} device(s).")
    return mode, min(num_devices, len(configs))


def checked_order(order: Sequence[int], count: int) -> list[int]:
    """``order`` as a list of ints, checked to be a permutation of ``range(count)``."""
    order = [int(i) for i in order]
    if sorted(order) != list(range(count)):
        raise ValueError(f"order = {order}; give a permutation of range({count}).")
    return order
