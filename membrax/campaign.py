"""Campaigns on ``dask.distributed``: independent tasks on worker processes, on one machine or a cluster.

Contract. :func:`connect` gives a ``distributed.Client``: ``"local"`` starts :func:`local_cluster` (one worker
process per GPU, else one per CPU core) on this machine; any other value is a running scheduler's address
(``tcp://host:8786``) or its scheduler file (``*.json``, as ``dask-scheduler --scheduler-file`` and
``dask-jobqueue`` write). :func:`run_tasks` submits ``function(**arguments)`` for every task and returns
``{task name: result}``; it knows nothing of what a task computes. Its promises:

- a task whose worker dies is run again by the scheduler on another worker (up to dask's
  ``distributed.scheduler.allowed-failures``, default 3): the task function must resume from the
  checkpoints it writes (a sweep's tasks do, :mod:`membrax.sweep`);
- a task runs under a ``distributed.Lock`` named after it, so a copy left running by a client that was
  killed and a resubmitted copy never write the same files at once (the second waits for the first);
- a task that raises does not stop the others: every task is waited for, then one :class:`RunError` lists
  the failed ones (what finished is kept, and a resumed run submits only what is missing);
- progress: a tqdm bar over the tasks.

Why Dask and not ``jax.distributed``: the members of a sweep are independent. ``jax.distributed`` runs one
program in lock-step on every process, so one slow or failed process stalls or stops all; Dask's tasks are
scheduled one by one, on whatever workers exist (a laptop, workstations, a SLURM allocation through
``dask-jobqueue``), and a lost worker costs only its task's work since the last checkpoint.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
from collections.abc import Callable, Mapping

from membrax import native
from membrax.devices import cpu_cores
from membrax.errors import RunError

__all__ = ["connect", "gpu_count", "local_cluster", "run_tasks"]


def gpu_count() -> int:
    """NVIDIA GPUs this machine shows (``nvidia-smi -L``), without starting JAX; 0 when there is none."""
    if shutil.which("nvidia-smi") is None:
        return 0
    try:
        listed = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return 0
    return sum(line.startswith("GPU ") for line in listed.stdout.splitlines())


def local_cluster(num_workers: int | None = None):
    """A cluster of worker processes on this machine: one per GPU if it has any, else one per CPU core.

    Each worker is one process with one thread. A CPU worker sees one JAX device and keeps XLA's own
    thread pool to one thread (``--xla_cpu_multi_thread_eigen=false``), so the workers do not compete for
    the cores; a GPU worker sees only its GPU (``CUDA_VISIBLE_DEVICES``) and allocates memory as it goes.
    The workers share JAX's persistent compilation cache (``$JAX_COMPILATION_CACHE_DIR``, else ``jax/`` in
    membrax's cache folder, :func:`membrax.native.cache_dir`), every program kept: the workers compile the
    same programs (a group's members share their shapes), and each would otherwise compile them again.
    Worker memory is not capped (dask's default cap would pause or restart a worker whose XLA buffers pass
    its share of the memory).

    Args:
      num_workers: worker processes (default: one per GPU, else :func:`membrax.devices.cpu_cores`).

    Returns:
      A ``distributed.SpecCluster``; close it (or use it as a context manager) when done.
    """
    from distributed import Nanny, Scheduler, SpecCluster

    gpus = gpu_count()
    count = (gpus or cpu_cores()) if num_workers is None else int(num_workers)
    if count < 1:
        raise ValueError(f"num_workers = {count}; give at least 1 worker.")
    shared = {
        "JAX_COMPILATION_CACHE_DIR": os.environ.get("JAX_COMPILATION_CACHE_DIR")
        or str(native.cache_dir() / "jax"),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": os.environ.get(
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0"
        ),
    }
    workers = {}
    for w in range(count):
        if gpus:
            env = {"CUDA_VISIBLE_DEVICES": str(w % gpus), "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
        else:
            flags = os.environ.get("XLA_FLAGS", "")
            env = {"JAX_PLATFORMS": "cpu", "XLA_FLAGS": f"{flags} --xla_cpu_multi_thread_eigen=false".strip()}
        options = {"nthreads": 1, "memory_limit": 0, "env": {**shared, **env}, "silence_logs": logging.ERROR}
        workers[f"membrax-{w}"] = {"cls": Nanny, "options": options}
    scheduler = {"cls": Scheduler, "options": {"dashboard_address": None}}
    return SpecCluster(workers=workers, scheduler=scheduler, silence_logs=logging.ERROR)


def connect(scheduler, timeout_s: float = 30.0):
    """A ``distributed.Client`` for ``scheduler``, the cluster it started, and whether it is ours to close.

    Args:
      scheduler: ``"local"`` (:func:`local_cluster`), a scheduler address (``tcp://host:8786``), a
        scheduler file (``*.json``) or a ``distributed.Client`` already connected (shared by several
        sweeps; left open).
      timeout_s: how long to wait for an address to answer, s.

    Returns:
      (client, cluster or None, owned): close the client (if ``owned``) and the cluster when done.

    Raises:
      ValueError: naming the address, when no scheduler answers there within 30 s.
    """
    from distributed import Client

    if isinstance(scheduler, Client):
        return scheduler, None, False
    if scheduler == "local":
        cluster = local_cluster()
        return Client(cluster), cluster, True
    try:
        if str(scheduler).endswith(".json"):
            return Client(scheduler_file=scheduler, timeout=f"{timeout_s}s"), None, True
        return Client(scheduler, timeout=f"{timeout_s}s"), None, True
    except (OSError, TimeoutError) as error:
        raise ValueError(
            f"{scheduler}: no Dask scheduler answered within {timeout_s:g} s ({error}). Start one "
            "(`dask scheduler`, then `dask worker ADDRESS` on each machine), give its tcp://host:port or "
            "scheduler file, or use --scheduler local."
        ) from error


def _locked(function: Callable, name: str, arguments: Mapping):
    """``function(**arguments)`` holding the campaign-wide lock ``name`` (module docstring)."""
    from distributed import Lock

    with Lock(f"membrax:{name}"):
        return function(**arguments)


def run_tasks(
    client,
    function: Callable,
    tasks: Mapping[str, Mapping],
    progress: bool = True,
    description: str = "tasks",
) -> dict:
    """Run ``function(**arguments)`` for every ``name → arguments`` of ``tasks`` on the client's workers.

    Args:
      client: a ``distributed.Client`` (:func:`connect`).
      function: a module-level function (workers import it by name).
      tasks: task name (unique in the campaign, e.g. its results folder) → keyword arguments.
      progress: a tqdm bar over the tasks.
      description: the bar's label.

    Returns:
      {task name: the function's result}.

    Raises:
      RunError: listing every task that raised (or whose workers kept dying), after the others finished.
    """
    from distributed import as_completed
    from tqdm.auto import tqdm

    futures = {
        client.submit(_locked, function, name, dict(arguments), pure=False, key=f"membrax-{name}"): name
        for name, arguments in tasks.items()
    }
    results, errors = {}, {}
    with tqdm(total=len(futures), desc=description, unit="task", disable=not progress) as bar:
        for future in as_completed(futures):
            name = futures[future]
            if future.status == "error":
                errors[name] = repr(future.exception())
            else:
                results[name] = future.result()
            bar.update()
    if errors:
        lines = "\n".join(f"{name}: {error}" for name, error in errors.items())
        raise RunError(
            f"{len(errors)} of {len(futures)} tasks failed (the others' results are kept; run again with "
            f"--resume to retry only these):\n{lines}"
        )
    return results
