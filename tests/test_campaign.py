"""Campaigns on Dask: tasks on worker processes give the in-process results, and survive lost processes.

The cluster is real: two worker processes of :func:`membrax.campaign.local_cluster` (one per core), a
scheduler in this process. Each test runs the three-pressure grid as three one-member tasks, so with two
workers the third task waits for a free one; two run a grid of periodic elements as two tasks.
"""

import json
import os
import signal
import subprocess
import sys
import time

import cloudpickle
import dask
import distributed  # noqa: F401  (its config defaults loaded before dask.config.set below: see cluster)
import jax.numpy as jnp
import numpy as np
import pytest
from test_periodic_batch import BASE as ELEMENT
from test_periodic_batch import GRID as ELEMENT_GRID
from test_sweep import COMPARED, SHORT

from membrax import assemble, campaign, executor, sweep
from membrax.assemble import precision_scope
from membrax.config import ConfigError, TriaxialConfig, dump_config_toml
from membrax.errors import RunError
from membrax.io import read_checkpoint_host

# Every test here runs simulations on worker processes (the module's fixtures alone take about 2 min).
pytestmark = pytest.mark.slow

GRID = {"cell_pressure_kpa": (10.0, 40.0, 100.0), "membrane_thickness_mm": (5.0,)}


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes; a lock held by a killed worker is released after 2 s (dask's default: 30 s).

    ``distributed`` is imported at the top of this module: ``dask.config.set`` restores on exit what it
    found, and a ``distributed`` section it did not find is deleted, which left later tests of the same
    process (xarray's ``to_netcdf`` asks distributed for a client) without distributed's configuration."""
    short_leases = {
        "distributed.scheduler.locks.lease-timeout": "2s",
        "distributed.scheduler.locks.lease-validation-interval": "500ms",
    }
    with dask.config.set(short_leases), campaign.local_cluster(2) as workers:
        yield workers


@pytest.fixture(scope="module")
def on_dask(cluster, tmp_path_factory):
    """The grid as three uninterrupted one-member tasks."""
    return _campaign(tmp_path_factory.mktemp("campaign") / "whole", cluster.scheduler_address)


def _campaign(folder, scheduler, resume: bool = False):
    """The grid as three one-member tasks on ``scheduler``, into ``folder``."""
    return sweep.run_sweep(
        TriaxialConfig(**SHORT), GRID, folder, resume, progress=False, scheduler=scheduler, members_per_task=1
    )


def _task_folders(folder):
    return sorted((folder / "groups" / "group_0").glob("task_*"))


def _attempts(task_folder) -> list[dict]:
    path = task_folder / "attempts.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def test_tasks_on_worker_processes_give_the_in_process_results(on_dask, tmp_path):
    """Each task builds its member with the group's Δt and n_θ (planned once, on a worker), so every member
    takes the steps it takes in the in-process batch, and float64 runs the same arithmetic: every variable
    of ``sweep.nc`` and ``sweep_consolidation.nc`` equals the in-process sweep's (three one-member tasks
    against one three-member batch). Each task ran once, in a worker process, not in this one."""
    here = sweep.run_sweep(TriaxialConfig(**SHORT), GRID, tmp_path / "here", progress=False, num_devices=1)
    for ours, theirs in ((on_dask.dataset, here.dataset), (on_dask.consolidation, here.consolidation)):
        assert set(ours.variables) == set(theirs.variables)
        for name in theirs.variables:
            np.testing.assert_array_equal(ours[name].values, theirs[name].values, err_msg=name)
    tasks = _task_folders(on_dask.folder)
    assert len(tasks) == 3
    plan = json.loads((on_dask.folder / "groups" / "group_0" / "plan.json").read_text())
    assert sorted(i for task in plan["tasks"] for i in task) == [0, 1, 2]
    assert plan["time_step"] == pytest.approx(float(here.dataset["dt_s"].values[0, 0]), rel=1e-15)
    for task in tasks:
        (attempt,) = _attempts(task)
        assert attempt["pid"] != os.getpid() and attempt["resumed_steps"] is None
    assert set(on_dask.dataset["status"].values.ravel()) == {"completed"}


@pytest.fixture(scope="module")
def periodic_here(tmp_path_factory):
    """test_periodic_batch's 64-sphere element at 20 and 40 kPa (float64), in process: one batch."""
    return sweep.run_sweep(
        ELEMENT, ELEMENT_GRID, tmp_path_factory.mktemp("periodic_here"), progress=False, num_devices=1
    )


def _periodic_campaign(folder, scheduler, resume: bool = False):
    """The periodic grid as two one-member tasks on ``scheduler``, into ``folder``."""
    return sweep.run_sweep(
        ELEMENT, ELEMENT_GRID, folder, resume, progress=False, scheduler=scheduler, members_per_task=1
    )


def _assert_same_sweep(ours, theirs):
    """Every variable of ``sweep.nc`` and ``sweep_consolidation.nc`` equal, to the bit."""
    for mine, other in ((ours.dataset, theirs.dataset), (ours.consolidation, theirs.consolidation)):
        assert set(mine.variables) == set(other.variables)
        for name in other.variables:
            np.testing.assert_array_equal(mine[name].values, other[name].values, err_msg=name)


def test_periodic_elements_run_as_tasks_and_give_the_in_process_results(cluster, periodic_here, tmp_path):
    """A grid of periodic elements as two one-member tasks: the group is planned once on a worker (its
    packing's Δt, no n_θ) and each task is one :class:`membrax.executor.PeriodicBatch` on its worker. On one
    device a member's records are those of its element alone, to the bit, so every variable of ``sweep.nc``
    and ``sweep_consolidation.nc`` equals the in-process sweep's (one two-member batch); each task ran
    once, in a worker process."""
    there = _periodic_campaign(tmp_path, cluster.scheduler_address)
    _assert_same_sweep(there, periodic_here)
    assert set(there.dataset["status"].values.ravel()) == {"completed"}
    plan = json.loads((there.folder / "groups" / "group_0" / "plan.json").read_text())
    assert plan["nodes_around"] is None and sorted(i for task in plan["tasks"] for i in task) == [0, 1]
    assert plan["time_step"] == float(periodic_here.dataset["dt_s"].values[0])
    tasks = _task_folders(there.folder)
    assert len(tasks) == 2
    for task in tasks:
        (attempt,) = _attempts(task)
        assert attempt["pid"] != os.getpid() and attempt["resumed_steps"] is None


def test_a_periodic_task_resumes_on_a_worker_from_its_checkpoint(cluster, periodic_here, tmp_path):
    """A periodic campaign whose first task stopped after 3 chunks (its checkpoint: stacked states, budgets,
    the lists' shape, the records so far; run here as a killed worker would leave it) and whose second never
    started, resumed on the workers: the first task starts at its checkpoint's steps (past consolidation),
    and the records equal the in-process sweep's to the bit."""
    _, members = assemble.grid_members(ELEMENT, ELEMENT_GRID)
    dt = float(periodic_here.dataset["dt_s"].values[0])
    group = tmp_path / "groups" / "group_0"
    group.mkdir(parents=True)
    (group / "plan.json").write_text(json.dumps({"time_step": dt, "nodes_around": None, "tasks": [[0], [1]]}))
    task = (group / "task_0").resolve()
    with precision_scope(ELEMENT), pytest.raises(KeyboardInterrupt):
        sweep._run_unit([members[0][1]], task, False, False, order=[0], interrupt_after_chunks=3)
    checkpoint = read_checkpoint_host(task / "checkpoint.npz")
    assert checkpoint["phase"] == 1  # in shear_fine: consolidation ended after its first chunk
    resumed = _periodic_campaign(tmp_path, cluster.scheduler_address, resume=True)
    _assert_same_sweep(resumed, periodic_here)
    (attempt,) = _attempts(task)
    assert attempt["resumed_steps"] == checkpoint["member_steps"]
    assert attempt["resumed_steps"][0] > int(periodic_here.dataset["consolidation_steps"].values[0])


def _wait_for(condition, seconds: float, what: str):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError(f"timed out after {seconds} s waiting for {what}")


def test_a_killed_worker_and_a_killed_client_lose_only_the_work_since_the_last_checkpoint(
    cluster, on_dask, tmp_path
):
    """``membrax sweep --scheduler`` in a subprocess. Once a task has written a checkpoint, its worker
    process is killed (SIGKILL): the scheduler runs the task again on a restarted worker, which resumes
    from that checkpoint (its second attempt starts at the checkpoint's steps). Once a task has finished,
    the client itself is killed (SIGKILL); the campaign resumed from another client runs only the tasks
    without results. The records equal the uninterrupted campaign's to the last bit."""
    folder = tmp_path / "killed"
    config = tmp_path / "base.toml"
    config.write_text(dump_config_toml(TriaxialConfig(**SHORT)))
    command = [
        sys.executable,
        "-m",
        "membrax.cli",
        "sweep",
        str(config),
        "--grid",
        "cell_pressure_kpa=10,40,100",
        "--grid",
        "membrane_thickness_mm=5",
        "--scheduler",
        cluster.scheduler_address,
        "--task-members",
        "1",
        "--out",
        str(folder),
        "--no-progress",
    ]
    client = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:

        def checkpointed_task():
            for task in _task_folders(folder):
                attempts = _attempts(task)
                if (task / "checkpoint.npz").exists() and not (task / "results.nc").exists() and attempts:
                    return task, attempts[-1]["pid"]
            return None

        killed_task, worker_pid = _wait_for(checkpointed_task, 600, "a task's first checkpoint")
        os.kill(worker_pid, signal.SIGKILL)
        finished = _wait_for(
            lambda: [t for t in _task_folders(folder) if (t / "results.nc").exists()], 600, "a finished task"
        )
        client.kill()
    finally:
        if client.poll() is None:
            client.kill()
        client.wait()
    assert client.returncode == -signal.SIGKILL, client.stderr.read()[-2000:]
    assert len(finished) < 3, "every task finished before the client was killed: nothing left to resume"
    finished_before = {task.name: len(_attempts(task)) for task in finished}

    resumed = _campaign(folder, cluster.scheduler_address, resume=True)
    for task in _task_folders(folder):
        if task.name in finished_before:
            assert len(_attempts(task)) == finished_before[task.name], task.name  # not run again
    attempts = _attempts(killed_task)
    assert len(attempts) >= 2, attempts
    assert attempts[1]["pid"] != worker_pid
    assert attempts[1]["resumed_steps"] is not None and min(attempts[1]["resumed_steps"]) > 0, attempts
    for name in (*COMPARED, "consolidation_steps", "shear_steps"):
        ours, theirs = resumed.dataset[name].values, on_dask.dataset[name].values
        np.testing.assert_array_equal(ours, theirs, err_msg=name)


def _sabotage(pressure_pa: float | None):
    """On a worker: raise the sphere stiffness of the member at ``pressure_pa`` 1e6-fold (its Δt then far
    past the stable step), as test_sweep's in-process sabotage; None restores the worker."""
    if pressure_pa is None:
        sweep.build_batch = executor.build_batch
        return

    def sabotaged(configs, *args, **kwargs):
        batch = executor.build_batch(configs, *args, **kwargs)
        cell = [t.cell_pressure for t in batch.tests]
        if pressure_pa in cell:
            contact = batch.params.dem.contact
            stiffness = np.asarray(contact.normal_stiffness).copy()
            stiffness[cell.index(pressure_pa)] *= 1e6
            contact = contact.set(normal_stiffness=jnp.asarray(stiffness))
            batch.params = batch.params.set(dem=batch.params.dem.set(contact=contact))
        return batch

    sweep.build_batch = sabotaged


def test_a_member_that_blows_up_on_a_worker_is_flagged_and_the_others_are_unchanged(
    cluster, on_dask, tmp_path
):
    """Failure isolation across processes: the 100 kPa member, sabotaged on the workers, goes non-finite in
    its first chunk; the sweep returns with it flagged (error, phase, step) and the 10 and 40 kPa members
    equal to the uninterrupted campaign's, bit for bit."""
    from distributed import Client

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this test module
    with Client(cluster.scheduler_address) as client:
        client.run(_sabotage, 1e5)
        try:
            with pytest.warns(UserWarning, match="1 of 3 members failed"):
                mixed = _campaign(tmp_path, client)
        finally:
            client.run(_sabotage, None)
    status = mixed.dataset["status"].values[:, 0]
    assert list(status[:2]) == ["completed", "completed"]
    assert status[2].startswith("failed: ") and status[2].endswith(
        " in consolidation (chunk ending at step 500)"
    )
    for name in COMPARED:
        np.testing.assert_array_equal(mixed.dataset[name].values[:2], on_dask.dataset[name].values[:2])


def test_a_task_that_raises_is_reported_after_the_others_finish(cluster):
    """A task that raises does not stop the others: all are waited for, then one RunError names it."""
    from distributed import Client

    with Client(cluster.scheduler_address) as client:
        tasks = {"a": {"s": "2"}, "b": {"s": "{"}, "c": {"s": "3"}}
        with pytest.raises(RunError, match=r"(?s)1 of 3 tasks failed.*b: JSONDecodeError"):
            campaign.run_tasks(client, json.loads, tasks, progress=False)
        del tasks["b"]
        assert campaign.run_tasks(client, json.loads, tasks, progress=False) == {"a": 2, "c": 3}


def test_a_scheduler_that_does_not_answer_is_named():
    with pytest.raises(ValueError, match=r"tcp://127\.0\.0\.1:9: no Dask scheduler answered"):
        campaign.connect("tcp://127.0.0.1:9", timeout_s=2.0)


def test_a_campaign_folder_is_not_resumed_in_process(tmp_path):
    """A Dask campaign's folder (its groups hold plan.json and task folders) resumed without --scheduler
    is refused with the fix, before anything runs or is overwritten."""
    group = tmp_path / "groups" / "group_0"
    group.mkdir(parents=True)
    (group / "plan.json").write_text(json.dumps({"time_step": 1e-5, "nodes_around": 34, "tasks": [[0]]}))
    with pytest.raises(ConfigError, match="resume it with the same --scheduler option"):
        sweep.run_sweep(TriaxialConfig(**SHORT), GRID, tmp_path, resume=True, progress=False, num_devices=1)
    assert sorted(path.name for path in group.iterdir()) == ["plan.json"]


def test_a_task_size_below_one_is_refused_before_a_cluster_starts(tmp_path):
    with pytest.raises(ConfigError, match=r"members_per_task = 0; give at least 1"):
        sweep.run_sweep(TriaxialConfig(**SHORT), GRID, tmp_path, scheduler="local", members_per_task=0)
    assert not (tmp_path / "groups").exists()
