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

Batching and stages. Members that differ only in :data:`membrax.runner.BATCHED_FIELDS` (traced
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
splits stacked members on the host, :func:`membrax.runner.BatchedTest.unstack`), so a device busy with a long
chunk never stalls another, which XLA would end after 40 s. Across several hosts, call
``jax.distributed.initialize()`` in every process before :func:`run_sweep`: ``jax.devices()`` then lists every
host's devices, but a batch shards over the local ones only: between chunks the driver reads every member's
error bits and records on the host. Give each process its share of the grid (e.g. ``jax.process_index()``
picks the pressures) and merge the ``sweep.nc`` files with ``xarray.combine_by_coords`` (README).

Long runs. :func:`membrax.runner.run_group`'s progress bars, checkpoints and ``resume=True`` (results
identical to an uninterrupted sweep), one checkpoint per group; finished groups are kept in ``groups/``.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import itertools
import json
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import numpy as np
import xarray as xr

from membrax import __version__, paper
from membrax.config import (
    ConfigError,
    TriaxialConfig,
    config_to_dict,
    dump_config_toml,
    parse_overrides,
    with_overrides,
)
from membrax.devices import cpu_cores
from membrax.errors import RunError
from membrax.io import dataset_attrs_to_python, read_results, write_netcdf
from membrax.runner import (
    BOOKKEEPING_FIELDS,
    build_batch,
    consolidation_tolerance,
    describe_failure,
    member_chunk_records,
    results_datasets,
    run_group,
    run_metadata,
    structure_key,
)
from membrax.triaxial import analysis

__all__ = [
    "DEFAULT_GRID",
    "SweepResult",
    "grid_members",
    "parse_grid",
    "run_sweep",
]

#: The paper's Table 1 (:data:`membrax.paper.TABLE_1_GRID`).
DEFAULT_GRID = paper.TABLE_1_GRID
# ----------------------------------------------------------------------------------------------------------
# The grid
# ----------------------------------------------------------------------------------------------------------


def parse_grid(items: Sequence[str]) -> dict[str, tuple]:
    """``["cell_pressure_kpa=10,40,100", "membrane_thickness_mm=2.5,5"]`` → ``{field: values}``.

    Values are converted and checked by the configuration (:func:`membrax.config.with_overrides`).

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


def grid_members(base: TriaxialConfig, grid: Mapping[str, Sequence]) -> tuple[dict, list]:
    """Every combination of ``grid`` applied to ``base``, in row-major order (the last field fastest).

    Returns:
      (coordinates: {field: tuple of the field's values, converted}, members: list of
      (index tuple, TriaxialConfig named ``{base.name}_{k}``)).

    Raises:
      ConfigError: an unknown or bookkeeping field, a repeated value, or a value out of range (the
        configuration's own message).
    """
    if not grid:
        raise ConfigError("the grid is empty; give at least one field, e.g. cell_pressure_kpa=10,40,100.")
    fields = {field.name for field in pydataclasses.fields(TriaxialConfig)}
    coordinates: dict[str, tuple] = {}
    for key, values in grid.items():
        if key not in fields or key in BOOKKEEPING_FIELDS:
            raise ConfigError(
                f"grid field {key!r} is not a simulation field of TriaxialConfig; choose from "
                f"{sorted(fields - BOOKKEEPING_FIELDS)}."
            )
        converted = tuple(getattr(with_overrides(base, **{key: value}), key) for value in values)
        if len(set(converted)) != len(converted):
            raise ConfigError(f"grid field {key!r} repeats a value ({list(values)}); give distinct values.")
        coordinates[key] = converted
    members = []
    for k, index in enumerate(itertools.product(*(range(len(v)) for v in coordinates.values()))):
        overrides = {key: coordinates[key][i] for key, i in zip(coordinates, index, strict=True)}
        members.append((index, with_overrides(base, name=f"{base.name}_{k}", **overrides)))
    return coordinates, members


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


def _member_scalars(shear: xr.Dataset) -> dict:
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


def _write_summary_csv(path: Path, coordinates: dict, configs_by_index: dict, dataset: xr.Dataset) -> None:
    names = ["consolidation_steps", "shear_steps", "num_records", *_SCALARS]
    lines = [",".join([*coordinates, *names, "status"])]
    for index in configs_by_index:
        point = {dim: coordinates[dim][i] for dim, i in zip(coordinates, index, strict=True)}
        cells = [repr(float(v)) for v in point.values()]
        cells += [repr(float(dataset[name].values[index])) for name in names]
        cells.append(json.dumps(str(dataset["status"].values[index])))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")


def run_sweep(
    base: TriaxialConfig,
    grid: Mapping[str, Sequence] | None = None,
    folder=None,
    resume: bool = False,
    progress: bool = True,
    num_devices: int | None = None,
    mode: str | None = None,
    interrupt_after_chunks: int | None = None,
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

    Returns:
      A :class:`SweepResult`.

    Raises:
      ConfigError: a bad grid. RunError: every member failed (each one's error, phase and step); a member
        that fails alone is frozen at its last good records and marked in ``status`` (a warning lists them).
    """
    started = time.perf_counter()
    grid = dict(DEFAULT_GRID if grid is None else grid)
    coordinates, members = grid_members(base, grid)
    folder = Path(folder if folder is not None else f"results_{base.name}_sweep")
    folder.mkdir(parents=True, exist_ok=True)
    if not resume:
        (folder / "sweep.toml").write_text(
            dump_config_toml(base)
            + "\n[grid]\n"
            + "".join(f"{key} = {json.dumps(list(values))}\n" for key, values in coordinates.items())
        )
    if jax.default_backend() == "cpu" and jax.local_device_count() == 1 and cpu_cores() > 1 < len(members):
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
    with jax.enable_x64(base.float64):
        shear_sets, consolidation_sets, indices, extra, statuses = [], [], [], {}, {}
        chunk_counter = [0]
        for g, group in enumerate(groups.values()):
            group_folder = folder / "groups" / f"group_{g}"
            done_file = group_folder / "results.nc"
            # The batch order (balanced_order) depends on the device count: a resumed group keeps its own.
            order_file = group_folder / "members.json"
            order = None
            if resume and order_file.exists():
                order = json.loads(order_file.read_text())
            elif resume and group_folder.exists():
                order = list(range(len(group)))  # a folder written before members.json: grid order
            if resume and done_file.exists():
                group = [group[i] for i in order]
                shear_group = [read_results(group_folder / f"shear_{k}.nc") for k in range(len(group))]
                consolidation_group = [
                    read_results(group_folder / f"consolidation_{k}.nc") for k in range(len(group))
                ]
            else:
                build_start = time.perf_counter()
                batch = build_batch([config for _, config in group], num_devices, mode, order)
                group = [group[i] for i in batch.order]
                group_folder.mkdir(parents=True, exist_ok=True)
                order_file.write_text(json.dumps(batch.order))
                build_seconds = time.perf_counter() - build_start
                records, shear_start, elapsed = run_group(
                    batch,
                    group_folder,
                    resume,
                    progress,
                    interrupt_after_chunks,
                    chunk_counter,
                    isolate_failures=True,
                )
                shear_group, consolidation_group = [], []
                for k, ((_, config), test) in enumerate(zip(group, batch.tests, strict=True)):
                    mine = member_chunk_records(records, k)
                    metadata = run_metadata(
                        config, test, mine, build_seconds, elapsed, consolidation_tolerance(config)
                    )
                    failure = batch.failures.get(k)
                    metadata.update(
                        batch_members=batch.num_members,
                        batch_devices=batch.num_devices,
                        nodes_around=batch.nodes_around,
                        status="completed" if failure is None else f"failed: {describe_failure(failure)}",
                    )
                    shear, consolidation = results_datasets(mine, shear_start[k], metadata)
                    if shear is None:  # a member that failed before shearing
                        shear = xr.Dataset(attrs=consolidation.attrs)
                    write_netcdf(shear, group_folder / f"shear_{k}.nc")
                    write_netcdf(consolidation, group_folder / f"consolidation_{k}.nc")
                    shear_group.append(shear)
                    consolidation_group.append(consolidation)
                write_netcdf(xr.Dataset(attrs={"members": len(group)}), done_file)
            for (index, _), shear, consolidation in zip(group, shear_group, consolidation_group, strict=True):
                attrs = dataset_attrs_to_python(shear)
                statuses[index] = attrs.get("status", "completed")
                if statuses[index] != "completed":
                    continue  # its records stop at the failure (groups/); the grid shows the status only
                indices.append(index)
                shear_sets.append(shear)
                consolidation_sets.append(consolidation)
                extra.setdefault("consolidation_steps", []).append(attrs["consolidation_steps"])
                extra.setdefault("shear_steps", []).append(attrs["shear_steps"])
                extra.setdefault("dt_s", []).append(attrs["dt_s"])
                extra.setdefault("nodes_around", []).append(attrs["nodes_around"])
                for name, value in _member_scalars(shear).items():
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
    _write_summary_csv(folder / "summary.csv", coordinates, dict.fromkeys(statuses), dataset)
    files["summary"] = folder / "summary.csv"
    return SweepResult(folder, dataset, consolidation, files, seconds)
