"""Vectorised sweeps: a grid of membrane triaxial tests run as one batched, compiled simulation.

Contract. :func:`run_sweep` takes a base :class:`membrax.config.TriaxialConfig` and a grid (field name →
values, default the paper's Table 1: ``cell_pressure_kpa`` × ``membrane_thickness_mm``), runs every
member's test (:mod:`membrax.run`'s protocol: consolidation, then drained shearing) and writes one
:class:`xarray.Dataset` whose dimensions are the grid's fields plus ``record``:

- ``sweep.nc``: the shearing records of every member (the first record the end of consolidation, strains
  from the start of shearing, the derived quantities of :func:`membrax.triaxial.analysis.derived_quantities`),
  NaN-padded along ``record`` to the longest member (``num_records`` says how many are real), with the
  per-member scalars ``consolidation_steps``, ``shear_steps`` and the Table 2/3 numbers
  (``sigma3_internal_kpa``, ``peak_external_friction_angle_deg``, …);
- ``sweep_consolidation.nc``: the consolidation records, padded the same way;
- ``summary.csv``: one row per member with those scalars; ``sweep.toml``: the base config and grid.

Batching and stages. Members that differ only in :data:`membrax.assemble.BATCHED_FIELDS` (traced
parameters: pressure, thickness, modulus, friction, stiffness, rate, strain targets) form one batch of
:mod:`membrax.runner` (the loop every run shares; a single test is a batch of one): one compiled call per
chunk for all of them, one time step (the smallest of the members' own) and one mesh topology (n_θ from
the members' mean perimeter, each thickness keeping its own rest geometry); each member stops
consolidating at its own step and shears for its own steps (ε̇ ∝ √σc at a fixed inertial number). Fields
that change array shapes or compiled constants (specimen size, mesh resolution, density, record cadence,
dtype) split the grid into groups, run one after another.

Devices. With several devices the member axis is sharded across them with ``jax.shard_map`` (members padded
with frozen copies to a multiple of the device count). On a CPU this is the fast batching: one device per core
(:func:`membrax.devices.split_cpu_devices`, called before other membrax imports; ``membrax sweep`` and
``membrax reproduce`` do it) runs each core's members side by side, each member's arrays on one core, which
beats both one device using the cores for every operation and the members run one after another
(``benchmarks/bench_sweep.py``). No program a sweep compiles holds a cross-device collective (the driver
splits stacked members on the host, :func:`membrax.executor.BatchedTest.unstack`), so a device busy
with a long chunk never stalls another, which XLA would end after 40 s.

Campaigns (``scheduler=``, ``membrax sweep --scheduler``). The members run as tasks on ``dask.distributed``
workers (:mod:`membrax.campaign`): a worker process per core or GPU on this machine (``"local"``), or the
workers of a running scheduler (workstations, a SLURM allocation). Each group is planned once on a worker
(its Δt, n_θ and each member's expected steps, kept in ``groups/group_{g}/plan.json``) and split into tasks
of ``members_per_task`` members (default: the group shared evenly over the workers, by
:func:`membrax.planning.balanced_order`); a task is one batch on its worker's devices, with the group's Δt
and n_θ, so every member takes the steps it takes in-process. A task writes its results and checkpoints
into ``groups/group_{g}/task_{t}`` (the folder must be on a filesystem every worker sees) and resumes from
its checkpoint when its worker died and the scheduler ran it again; ``resume=True`` reuses the plans and
submits only the unfinished tasks. The client writes ``sweep.nc`` from the task folders as in-process.

Periodic elements (``cell = "periodic"``) batch too: members that share one packing and Δt (a grid over
the cell pressure, the inertial numbers, the strain targets, the friction, the consolidation criteria:
:func:`membrax.assemble.structure_key`) are one :class:`membrax.executor.PeriodicBatch`, stacked in one
compiled chunk and sharded over the devices as above, run through the protocol's phases by
:func:`membrax.runner.run_group` into ``groups/group_{g}``; members that cannot stack (another
particle count, seed, grading, particle stiffness or precision: another packing or Δt) are grouped by those
fields and the groups run one after another. ``sweep.nc`` holds their records and figures (peak and late
φ', ε_v, the lateral servo's error: :func:`membrax.triaxial.analysis.element_summary`) on the same grid.
On one device each member's records are those of its element run alone, to the bit; sharded or vmapped,
to round-off that the granular dynamics amplify (:mod:`membrax.executor`). On a Dask scheduler their groups
split into tasks as above (a group's plan holds its packing's Δt and no n_θ), and a member that fails is
frozen and marked as below.

Long runs. :func:`membrax.runner.run_group`'s progress bars, checkpoints and ``resume=True`` (results
identical to an uninterrupted sweep), one checkpoint per group (per task in a campaign); finished groups
are kept in ``groups/``. A member that fails is frozen at its last good records and marked in ``status``;
the sweep fails only when every member did.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import json
import math
import os
import shutil
import socket
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import numpy as np
import xarray as xr

from membrax import __version__, campaign, paper
from membrax.assemble import grid_members, precision_scope, run_settings, structure_key
from membrax.config import (
    ConfigError,
    TriaxialConfig,
    config_to_dict,
    dump_config_toml,
    parse_overrides,
    to_si,
)
from membrax.devices import cpu_cores
from membrax.errors import RunError
from membrax.executor import build_batch, build_periodic_batch, describe_failure
from membrax.io import dataset_attrs_to_python, read_checkpoint_host, read_results, write_netcdf
from membrax.planning import balanced_order, plan_members, plan_periodic_members
from membrax.run import default_folder as run_folder
from membrax.run import periodic_datasets
from membrax.run_records import member_chunk_records, results_datasets, run_metadata
from membrax.runner import CHECKPOINT_NAME, run_group
from membrax.triaxial import analysis

__all__ = [
    "DEFAULT_GRID",
    "SweepResult",
    "default_folder",
    "parse_grid",
    "run_sweep",
]

#: The paper's Table 1 (:data:`membrax.paper.TABLE_1_GRID`).
DEFAULT_GRID = paper.TABLE_1_GRID
# ----------------------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------------------


def default_folder(base: TriaxialConfig) -> Path:
    """Where a sweep over ``base`` writes by default: ``results_<name>_sweep``."""
    return run_folder(base, "_sweep")


def parse_grid(items: Sequence[str]) -> dict[str, tuple]:
    """``["cell_pressure_kpa=10,40,100", "membrane_thickness_mm=2.5,5"]`` → ``{field: values}``.

    Values are converted and checked by the configuration when the members are made
    (:func:`membrax.assemble.grid_members`).

    Raises:
      ConfigError: naming the item, for a missing ``=``, an empty value list, a repeated field or a field
        that is not a configuration field.
    """
    grid: dict[str, tuple] = {}
    for item in items:
        key, sep, values = str(item).partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ConfigError(f"--grid {item!r}: write FIELD=V1,V2,... e.g. cell_pressure_kpa=10,40,100.")
        if key in grid:
            raise ConfigError(f"--grid {item!r}: {key} is given twice; list all its values in one --grid.")
        texts = [value.strip() for value in values.split(",") if value.strip()]
        # Each value read as the CLI's --set reads it (TOML numbers, booleans, strings).
        parsed = tuple(parse_overrides([f"{key}={text}"])[key] for text in texts)
        if not parsed:
            raise ConfigError(f"--grid {item!r}: no values; write {key}=V1,V2,...")
        grid[key] = parsed
    return grid


@pydataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` produced.

    Attributes:
      folder: the results folder.
      dataset: the shearing records over the grid (module docstring).
      consolidation: the consolidation records over the grid.
      files: paths written.
      seconds: wall time of the whole sweep, s.
    """

    folder: Path
    dataset: xr.Dataset
    consolidation: xr.Dataset
    files: dict
    seconds: float

    def member(self, **coordinates) -> xr.Dataset:
        """One member's shearing records, padding removed: ``result.member(cell_pressure_kpa=10, ...)``."""
        return member_records(self.dataset, **coordinates)


def member_records(dataset: xr.Dataset, **coordinates) -> xr.Dataset:
    """One member of a sweep dataset (selected by its grid coordinates), its NaN padding removed."""
    missing = [
        dim for dim in dataset.attrs.get("grid_fields", "").split(",") if dim and dim not in coordinates
    ]
    if missing:
        raise ValueError(f"give a value for every grid field; missing {missing}.")
    selected = dataset.sel(coordinates, method="nearest")
    count = int(selected["num_records"])
    return selected.isel(record=slice(0, count))


_SCALARS = (
    "sigma3_external_kpa",
    "sigma3_internal_kpa",
    "sigma1_external_kpa",
    "sigma1_internal_kpa",
    "peak_external_friction_angle_deg",
    "peak_external_axial_strain",
    "peak_internal_friction_angle_deg",
    "peak_internal_axial_strain",
)


#: A periodic element's per-member scalars (:func:`membrax.triaxial.analysis.element_summary`).
_ELEMENT_SCALARS = (
    "peak_friction_angle_deg",
    "peak_axial_strain",
    "late_friction_angle_deg",
    "final_volumetric_strain",
    "lateral_stress_error",
    "solid_fraction",
    "coordination_number",
    "rattler_free_coordination_number",
)


def _member_scalars(shear: xr.Dataset, attrs: dict) -> dict:
    """A member's scalars: the Table 2/3 numbers of a membrane cell, the element figures of a periodic one."""
    if attrs.get("cell") == "periodic":
        cell_pressure = to_si("cell_pressure_kpa", attrs["config"]["cell_pressure_kpa"])
        return analysis.element_summary(shear, cell_pressure)
    values = {**analysis.initial_state(shear), **analysis.peak(shear)}
    return {name: float(values[name]) for name in _SCALARS}


def _grid_dataset(datasets: list, coordinates: dict, indices: list, extra: dict, attrs: dict) -> xr.Dataset:
    """Stack per-member datasets (dimension ``record`` first) onto the grid, NaN-padded along ``record``."""
    dims = tuple(coordinates)
    shape = tuple(len(v) for v in coordinates.values())
    length = max(ds.sizes["record"] for ds in datasets)
    variables = {}
    names = list(datasets[0].coords) + list(datasets[0].data_vars)
    for name in names:
        first = datasets[0].variables[name]
        if not first.dims or first.dims[0] != "record":
            continue
        tail = first.shape[1:]
        values = np.full((*shape, length, *tail), np.nan)
        for index, ds in zip(indices, datasets, strict=True):
            data = np.asarray(ds.variables[name].values, dtype=np.float64)
            values[index][: data.shape[0]] = data
        variables[name] = xr.Variable(dims + first.dims, values, attrs=dict(first.attrs))
    counts = np.zeros(shape, dtype=np.int32)
    for index, ds in zip(indices, datasets, strict=True):
        counts[index] = ds.sizes["record"]
    variables["num_records"] = xr.Variable(dims, counts)
    for name, per_member in extra.items():
        values = np.full(shape, np.nan)
        for index, value in zip(indices, per_member, strict=True):
            values[index] = value
        variables[name] = xr.Variable(dims, values)
    coords = {dim: np.asarray(values, dtype=np.float64) for dim, values in coordinates.items()}
    return xr.Dataset(variables, coords=coords, attrs={**attrs, "grid_fields": ",".join(dims)})


def _member_label(coordinates: dict, index: tuple) -> str:
    """A grid member by its coordinates, e.g. ``cell_pressure_kpa=10, membrane_thickness_mm=5``."""
    return ", ".join(f"{dim}={coordinates[dim][i]:g}" for dim, i in zip(coordinates, index, strict=True))


def _write_summary_csv(
    path: Path, coordinates: dict, configs_by_index: dict, dataset: xr.Dataset, scalars=_SCALARS
) -> None:
    names = ["consolidation_steps", "shear_steps", "num_records", *scalars]
    lines = [",".join([*coordinates, *names, "status"])]
    for index in configs_by_index:
        point = {dim: coordinates[dim][i] for dim, i in zip(coordinates, index, strict=True)}
        cells = [repr(float(v)) for v in point.values()]
        cells += [repr(float(dataset[name].values[index])) for name in names]
        cells.append(json.dumps(str(dataset["status"].values[index])))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------------------------------------------------
# Units of work: a batch of members run into one folder (a whole group here, or one task on a worker)
# ----------------------------------------------------------------------------------------------------------

_DONE = "results.nc"


def _run_unit(
    configs: list,
    folder: Path,
    resume: bool,
    progress: bool,
    num_devices: int | None = None,
    mode: str | None = None,
    order: Sequence[int] | None = None,
    time_step: float | None = None,
    nodes_around: int | None = None,
    interrupt_after_chunks: int | None = None,
    chunk_counter: list | None = None,
) -> list[int]:
    """Run ``configs`` as one batch into ``folder`` (in this process or as a task on a worker).

    Writes ``shear_{k}.nc``/``consolidation_{k}.nc`` for the batch's member k (``configs[order[k]]``),
    ``members.json`` (the order) and, last, ``results.nc``. A member that fails is frozen and written
    with its ``status`` (``isolate_failures`` of :func:`membrax.runner.run_group`). Returns the order.
    """
    build_start = time.perf_counter()
    periodic = run_settings(configs[0]).cell == "periodic"
    if periodic:
        batch = build_periodic_batch(configs, num_devices, mode, order)
    else:
        batch = build_batch(configs, num_devices, mode, order, time_step, nodes_around)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "members.json").write_text(json.dumps(batch.order))
    build_seconds = time.perf_counter() - build_start
    records, shear_start, elapsed = run_group(
        batch, folder, resume, progress, interrupt_after_chunks, chunk_counter, isolate_failures=True
    )
    for k, (settings, test) in enumerate(zip(batch.settings, batch.tests, strict=True)):
        mine = member_chunk_records(records, k)
        failure = batch.failures.get(k)
        batch_attrs = {
            "batch_members": batch.num_members,
            "batch_devices": batch.num_devices,
            "status": "completed" if failure is None else f"failed: {describe_failure(failure)}",
        }
        if periodic:
            shear, consolidation = periodic_datasets(
                test, settings, mine, build_seconds, elapsed, **batch_attrs
            )
        else:
            metadata = run_metadata(settings, test, mine, build_seconds, elapsed)
            metadata.update(nodes_around=batch.nodes_around, **batch_attrs)
            shear, consolidation = results_datasets(mine, shear_start[k], metadata)
        if shear is None:  # a member that failed before shearing
            shear = xr.Dataset(attrs=consolidation.attrs)
        write_netcdf(shear, folder / f"shear_{k}.nc")
        write_netcdf(consolidation, folder / f"consolidation_{k}.nc")
    write_netcdf(xr.Dataset(attrs={"members": batch.num_members}), folder / _DONE)
    return batch.order


def _read_unit(folder: Path, members: list) -> list:
    """(grid index, shear, consolidation) of each of ``members`` ((index, config) in the unit's order)."""
    return [
        (index, read_results(folder / f"shear_{k}.nc"), read_results(folder / f"consolidation_{k}.nc"))
        for k, (index, _) in enumerate(members)
    ]


def _run_groups_here(groups, folder, resume, progress, num_devices, mode, interrupt_after_chunks) -> list:
    """Every group as one batch in this process, one after another (``groups/group_{g}``)."""
    outcomes, chunk_counter = [], [0]
    if resume and (folder / "members").exists():
        raise ConfigError(
            f"{folder} holds periodic members run one after another (members/, an earlier membrax); they now "
            "run as batches: give a new output folder."
        )
    for g, group in enumerate(groups.values()):
        group_folder = folder / "groups" / f"group_{g}"
        # The batch order (balanced_order) depends on the device count: a resumed group keeps its own.
        order_file = group_folder / "members.json"
        order = None
        if resume and (group_folder / "plan.json").exists():
            raise ConfigError(
                f"{group_folder} holds a Dask campaign's tasks; resume it with the same --scheduler option, "
                "or give a new output folder."
            )
        if resume and order_file.exists():
            order = json.loads(order_file.read_text())
        elif resume and group_folder.exists():
            order = list(range(len(group)))  # a folder written before members.json: grid order
        if not (resume and (group_folder / _DONE).exists()):
            order = _run_unit(
                [config for _, config in group],
                group_folder,
                resume,
                progress,
                num_devices,
                mode,
                order,
                interrupt_after_chunks=interrupt_after_chunks,
                chunk_counter=chunk_counter,
            )
        outcomes += _read_unit(group_folder, [group[i] for i in order])
    return outcomes


def plan_group(configs: list) -> dict:
    """A group's common Δt and n_θ and each member's expected steps (run on a worker: it builds the tests).

    A group of periodic elements has its packing's Δt and no mesh (``nodes_around`` None).
    """
    with precision_scope(configs[0]):
        if run_settings(configs[0]).cell == "periodic":
            _, time_step, work = plan_periodic_members(configs)
            nodes_around = None
        else:
            _, time_step, nodes_around, work = plan_members(configs)
    return {"time_step": time_step, "nodes_around": nodes_around, "work": work}


def run_task(configs: list, folder: str, time_step: float, nodes_around: int | None) -> int:
    """One task of a Dask campaign, run on a worker: ``configs`` as one batch, into ``folder``.

    The batch shards over the worker's devices, with the group's Δt and n_θ (so each member takes the
    steps it takes in-process; periodic elements, :class:`membrax.executor.PeriodicBatch`, take their
    packing's Δt, the plan's, and have no n_θ). Always resumes from the folder's checkpoint: a task whose
    worker died goes on where it stopped; a finished folder is left as it is. Each start appends a line to
    ``attempts.jsonl`` (process, host, and the steps the checkpoint had reached). Returns the members.
    """
    folder = Path(folder)
    if (folder / _DONE).exists():
        return len(configs)
    folder.mkdir(parents=True, exist_ok=True)
    checkpoint = folder / CHECKPOINT_NAME
    steps = read_checkpoint_host(checkpoint).get("member_steps") if checkpoint.exists() else None
    attempt = {"pid": os.getpid(), "host": socket.gethostname(), "time": time.time(), "resumed_steps": steps}
    with (folder / "attempts.jsonl").open("a") as log:
        log.write(json.dumps(attempt) + "\n")
    with precision_scope(configs[0]):
        _run_unit(
            configs,
            folder,
            True,
            False,
            order=list(range(len(configs))),
            time_step=time_step,
            nodes_around=nodes_around,
        )
    return len(configs)


def _run_groups_on_dask(groups, folder, resume, progress, scheduler, members_per_task):
    """Every group split into tasks (``groups/group_{g}/task_{t}``), all sent to a Dask scheduler at once.

    Each group's Δt, n_θ and split are planned on a worker and kept in ``groups/group_{g}/plan.json``; a
    resumed campaign reuses them and submits only the tasks without ``results.nc``.
    """
    client, cluster, owned = campaign.connect(scheduler)
    try:
        workers = max(1, sum(client.nthreads().values()))  # task slots (0 while none has joined yet)
        plans = {}
        for g, group in enumerate(groups.values()):
            group_folder = folder / "groups" / f"group_{g}"
            plan_file = group_folder / "plan.json"
            if resume and plan_file.exists():
                plans[g] = json.loads(plan_file.read_text())
                continue
            if resume and (group_folder / "members.json").exists():
                raise ConfigError(
                    f"{group_folder} holds an in-process sweep's results; resume it without --scheduler, "
                    "or give a new output folder."
                )
            if group_folder.exists():
                shutil.rmtree(group_folder)  # a fresh run: no stale task checkpoints to resume from
            plans[g] = client.submit(plan_group, [config for _, config in group], pure=False)
        for g, group in enumerate(groups.values()):
            if isinstance(plans[g], dict):
                continue
            plan = plans[g].result()
            per_task = members_per_task or math.ceil(len(group) / workers)
            count = math.ceil(len(group) / per_task)
            order = balanced_order(plan.pop("work"), count)
            size = math.ceil(len(group) / count)
            plan["tasks"] = [order[t * size : (t + 1) * size] for t in range(count)]
            plan_file = folder / "groups" / f"group_{g}" / "plan.json"
            plan_file.parent.mkdir(parents=True, exist_ok=True)
            plan_file.write_text(json.dumps(plan))
            plans[g] = plan
        tasks, units = {}, []
        for g, group in enumerate(groups.values()):
            plan = plans[g]
            for t, positions in enumerate(plan["tasks"]):
                task_folder = (folder / "groups" / f"group_{g}" / f"task_{t}").resolve()
                members = [group[i] for i in positions]
                units.append((task_folder, members))
                if not (task_folder / _DONE).exists():
                    tasks[str(task_folder)] = {
                        "configs": [config for _, config in members],
                        "folder": str(task_folder),
                        "time_step": plan["time_step"],
                        "nodes_around": plan["nodes_around"],
                    }
        campaign.run_tasks(client, run_task, tasks, progress, "sweep tasks")
    finally:
        if owned:
            client.close()
        if cluster is not None:
            cluster.close()
    return [outcome for task_folder, members in units for outcome in _read_unit(task_folder, members)]


def run_sweep(
    base: TriaxialConfig,
    grid: Mapping[str, Sequence] | None = None,
    folder=None,
    resume: bool = False,
    progress: bool = True,
    num_devices: int | None = None,
    mode: str | None = None,
    interrupt_after_chunks: int | None = None,
    scheduler: str | None = None,
    members_per_task: int | None = None,
) -> SweepResult:
    """Run every member of ``grid`` over ``base`` into ``folder`` (module docstring).

    Args:
      base: the configuration shared by all members.
      grid: field → values (default :data:`DEFAULT_GRID`, the paper's Table 1).
      folder: results folder (default ``results_{base.name}_sweep``), created.
      resume: continue from the folder's checkpoints.
      progress: tqdm progress bars.
      num_devices: devices to shard each batch over (default all; on a CPU see
        :func:`membrax.devices.split_cpu_devices`).
      mode: ``"map"``/``"vmap"`` (default by backend, :func:`build_batch`).
      interrupt_after_chunks: testing aid: ``KeyboardInterrupt`` after this many chunks of this call.
      scheduler: run the members as tasks on ``dask.distributed`` (module docstring): ``"local"``, a
        scheduler's address or file, or a connected ``Client`` (:func:`membrax.campaign.connect`); None
        runs them in this process.
      members_per_task: members per task (default: a group's members shared evenly over the workers).

    Returns:
      A :class:`SweepResult`.

    Raises:
      ConfigError: a bad grid. RunError: every member failed (each one's error, phase and step); a member
        that fails alone is frozen at its last good records and marked in ``status`` (a warning lists them).
    """
    started = time.perf_counter()
    if members_per_task is not None and members_per_task < 1:
        raise ConfigError(f"members_per_task = {members_per_task}; give at least 1 (or None: even shares).")
    grid = dict(DEFAULT_GRID if grid is None else grid)
    coordinates, members = grid_members(base, grid)
    folder = Path(folder if folder is not None else default_folder(base))
    folder.mkdir(parents=True, exist_ok=True)
    if not resume:
        (folder / "sweep.toml").write_text(
            dump_config_toml(base)
            + "\n[grid]\n"
            + "".join(f"{key} = {json.dumps(list(values))}\n" for key, values in coordinates.items())
        )
    cells = {run_settings(config).cell for _, config in members}
    if len(cells) > 1:
        raise ConfigError(f"the grid mixes cells {sorted(cells)}; sweep one cell at a time.")
    periodic = cells == {"periodic"}
    # (A Dask client starts no JAX backend here: on a GPU machine that would hold the workers' memory.)
    in_process = scheduler is None
    one_cpu_device = in_process and jax.default_backend() == "cpu" and jax.local_device_count() == 1
    if one_cpu_device and not periodic and cpu_cores() > 1 < len(members):
        warnings.warn(
            f"one CPU device on {cpu_cores()} cores: call membrax.devices.split_cpu_devices() before "
            "importing the rest of membrax (or any JAX operation) to run the members side by side, one "
            "per core (bench_sweep: 1.5–2.5× faster than serial on 2 cores).",
            stacklevel=2,
        )
    groups: dict[tuple, list] = {}
    for index, config in members:
        groups.setdefault(structure_key(config), []).append((index, config))
    # The base configuration's precision, scoped to this call (thread-local), as in run_test.
    with precision_scope(base):
        if scheduler is None:
            outcomes = _run_groups_here(
                groups, folder, resume, progress, num_devices, mode, interrupt_after_chunks
            )
        else:
            outcomes = _run_groups_on_dask(groups, folder, resume, progress, scheduler, members_per_task)
    shear_sets, consolidation_sets, indices, extra, statuses = [], [], [], {}, {}
    for index, shear, consolidation in outcomes:
        attrs = dataset_attrs_to_python(shear)
        statuses[index] = attrs.get("status", "completed")
        if statuses[index] != "completed":
            continue  # its records stop at the failure (groups/); the grid shows the status only
        indices.append(index)
        shear_sets.append(shear)
        consolidation_sets.append(consolidation)
        for name in ("consolidation_steps", "shear_steps", "dt_s", "nodes_around"):
            extra.setdefault(name, []).append(attrs.get(name, np.nan))
        # The specimen (a random packing differs between seeds): its sphere count and solid fraction.
        extra.setdefault("num_particles", []).append(attrs.get("num_particles", -1))
        if not periodic:  # the element's solid fraction is among its scalars
            extra.setdefault("solid_fraction", []).append(
                attrs.get("specimen", {}).get("solid_fraction", np.nan)
            )
        for name, value in _member_scalars(shear, attrs).items():
            extra.setdefault(name, []).append(value)
    attrs = {
        "membrax_version": __version__,
        "base_config": config_to_dict(base),
        "grid": {key: list(values) for key, values in coordinates.items()},
        "groups": len(groups),
    }
    failed = {index: status for index, status in statuses.items() if status != "completed"}
    failures = "\n".join(f"{_member_label(coordinates, i)}: {status}" for i, status in failed.items())
    if len(failed) == len(statuses):
        raise RunError("every member failed:\n" + failures)
    dataset = _grid_dataset(shear_sets, coordinates, indices, extra, attrs)
    consolidation = _grid_dataset(consolidation_sets, coordinates, indices, {}, attrs)
    status = np.full(tuple(len(v) for v in coordinates.values()), "completed", dtype=object)
    for index, value in statuses.items():
        status[index] = value
    for ds in (dataset, consolidation):
        ds["status"] = xr.Variable(tuple(coordinates), status.astype(str))
    if failed:
        warnings.warn(
            f"{len(failed)} of {len(statuses)} members failed and were frozen at their last good records "
            "(their other variables are NaN here; groups/ keeps their records):\n" + failures,
            stacklevel=2,
        )
    seconds = time.perf_counter() - started
    dataset.attrs["run_s"] = seconds
    files = {
        "sweep": write_netcdf(dataset, folder / "sweep.nc"),
        "consolidation": write_netcdf(consolidation, folder / "sweep_consolidation.nc"),
    }
    _write_summary_csv(
        folder / "summary.csv",
        coordinates,
        dict.fromkeys(statuses),
        dataset,
        _ELEMENT_SCALARS if periodic else _SCALARS,
    )
    files["summary"] = folder / "summary.csv"
    return SweepResult(folder, dataset, consolidation, files, seconds)
