"""A sweep on a SLURM cluster: Dask workers as SLURM jobs (dask-jobqueue), the members as their tasks.

Run it on the login node (or in a small job) of a cluster where membrax is installed with
``pip install -e ".[cluster]"`` and the output folder is on a filesystem every node mounts:

    python examples/slurm_campaign.py study.toml --grid cell_pressure_kpa=10,25,40,70,100 \\
        --grid membrane_thickness_mm=1,2,3,5 --out /scratch/$USER/study --jobs 4 --account myproject

Each job is one node running ``--cores`` worker processes of one thread (one per core, as
``--scheduler local`` does on one machine). The script asks for ``--jobs`` jobs, sends the grid's members
as tasks (:func:`membrax.sweep.run_sweep` with the cluster's client) and writes ``sweep.nc`` into
``--out`` when every task has finished. Jobs that end (wall time, pre-emption) take their workers with
them; their tasks go back to the queue and resume from their checkpoints on the workers left, and
``cluster.adapt`` asks for new ones. If this script itself is stopped, run it again with ``--resume``:
finished tasks are read back, the others resume from their checkpoints. Not run by the tests (no SLURM
there); docs/campaigns.md has the set-up without this script (a scheduler file and ``membrax sweep
--scheduler``).
"""

import argparse


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", help="TOML configuration: the base of every member")
    parser.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2,...")
    parser.add_argument("--out", required=True, help="results folder on a filesystem every node mounts")
    parser.add_argument("--jobs", type=int, default=2, help="SLURM jobs (nodes) to keep")
    parser.add_argument("--cores", type=int, default=16, help="cores (worker processes) per job")
    parser.add_argument("--memory", default="64GB", help="memory per job")
    parser.add_argument("--walltime", default="12:00:00")
    parser.add_argument("--account", default=None, help="SLURM account (--account)")
    parser.add_argument("--task-members", type=int, default=1, help="members per task (1: finest balance)")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()

    from dask_jobqueue import SLURMCluster
    from distributed import Client

    from membrax.config import load_config
    from membrax.sweep import parse_grid, run_sweep

    cluster = SLURMCluster(
        cores=args.cores,
        processes=args.cores,  # one single-threaded worker per core
        memory=args.memory,
        walltime=args.walltime,
        job_extra_directives=[f"--account={args.account}"] if args.account else [],
        # CPU nodes: one XLA thread per worker process, and one compilation cache for all workers (on the
        # shared filesystem), as membrax.campaign.local_cluster sets up on one machine.
        job_script_prologue=[
            "export JAX_PLATFORMS=cpu XLA_FLAGS=--xla_cpu_multi_thread_eigen=false",
            f"export JAX_COMPILATION_CACHE_DIR={args.out}/jax_cache",
            "export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0",
        ],
    )
    # Keep --jobs jobs: one that ends is replaced, and its tasks resume from their checkpoints.
    cluster.adapt(minimum_jobs=args.jobs, maximum_jobs=args.jobs)
    with Client(cluster) as client:
        result = run_sweep(
            load_config(args.config),
            parse_grid(args.grid) if args.grid else None,
            args.out,
            resume=args.resume,
            scheduler=client,
            # Explicit: while jobs wait in the queue there are no workers to share a group over.
            members_per_task=args.task_members,
        )
    cluster.close()
    print((result.folder / "summary.csv").read_text())


if __name__ == "__main__":
    main()
