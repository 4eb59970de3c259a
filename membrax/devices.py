"""CPU devices for batched sweeps: one JAX device per core.

Contract. :func:`split_cpu_devices` sets ``jax_num_cpu_devices`` so the host CPU appears as several JAX
devices; :class:`membrax.executor.BatchedTest` then shards a batch's member axis over them and each core
advances its own members. It must run before JAX starts its backend, i.e. before the first JAX operation
and before importing :mod:`membrax.spheres.neighbors` (it imports ``jax_md``, which builds arrays on import),
so this module imports nothing but ``jax``. A GPU backend keeps its own devices; only the CPU platform is
split.

Why: XLA runs one CPU device's operations on all cores, but a membrane test's arrays (a few thousand
nodes) are too small to split well across threads, so whole members side by side use the cores better:
``benchmarks/bench_sweep.py`` measures it.

Usage::

    import jax
    from membrax.devices import split_cpu_devices
    split_cpu_devices()          # before `from membrax import sweep`
    from membrax import sweep
"""

from __future__ import annotations

import os
import warnings

import jax

__all__ = ["cpu_cores", "split_cpu_devices"]


def cpu_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the platform has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def split_cpu_devices(num_devices: int | None = None) -> int:
    """Make the host CPU ``num_devices`` JAX devices, so a sweep's members run one core each.

    Args:
      num_devices: CPU devices to make (default: :func:`cpu_cores`).

    Returns:
      The CPU devices this process has now: ``num_devices``, or the count JAX already started with if a
      JAX operation (or an import of ``jax_md``) came first; then a ``UserWarning`` says so.

    Raises:
      ValueError: ``num_devices`` below 1.
    """
    num_devices = cpu_cores() if num_devices is None else int(num_devices)
    if num_devices < 1:
        raise ValueError(f"num_devices = {num_devices}; give at least 1 CPU device.")
    try:
        jax.config.update("jax_num_cpu_devices", num_devices)
    except RuntimeError:
        # JAX reads the setting once, when its backend starts.
        started = jax.local_device_count("cpu")
        if started != num_devices:
            warnings.warn(
                f"JAX already started with {started} CPU device(s), so split_cpu_devices({num_devices}) has "
                "no effect: call it right after `import jax`, before any JAX operation or other membrax "
                "import.",
                stacklevel=2,
            )
        return started
    return num_devices
