"""The paper's Table 1 (9 cases) batched in one compiled call against the 9 run one after another.

For each dtype, in a fresh process split into one CPU device per core
(:func:`membrax.devices.split_cpu_devices`, as ``membrax sweep`` does; ``--cpu-devices``), builds the 9
members (10, 40, 100 kPa × 2.5, 3.33, 5 mm) on the specimen of ``--size`` (``small``: 6 × 10, membrane
edge D/3, the reproduction's; ``paper``: 10 × 25, edge D/5) with one Δt and one mesh topology
(:func:`membrax.executor.build_batch`), then times consolidation steps:

- batched: one chunk call advancing all 9 members, sharded over the devices (``lax.map`` over each
  device's members on a CPU, ``vmap`` on a GPU, or ``--mode``; padding members have no steps to do, as in a
  sweep): compile time and simulation-steps/s (member-steps per second, real members counted);
- batched on one device: the same call unsharded (on a CPU: one device using every core per operation);
- serial: each member's own compiled chunk (:class:`membrax.driver.ChunkRunner`) on the default device,
  the 9 in turn: the sum of the 9 compile times and the steps/s over the 9;
- particle-steps/s (spheres + membrane nodes), peak resident memory, and the wall time the whole Table 1
  would take at the batched rate for ``--table-steps`` member-steps per case.

On one GPU the one-device call is the batched call, and the serial column costs nine compiles:
``--batched-only 1`` skips both (printed as nan).

Run: ``python benchmarks/bench_sweep.py [--size small|paper] [--steps 500] [--mode map|vmap]
[--cpu-devices N] [--batched-only 1] [--dtypes float32,float64]``.
"""

import resource
import time

from harness import batch_columns, benchmark_parser, benchmark_rows, time_one_by_one, timed


def measure(
    dtype: str, size: str, steps: int, mode: str, table_steps: int, cpu_devices: int, batched_only: int
) -> dict:
    import dataclasses

    import jax

    from membrax.devices import split_cpu_devices

    split_cpu_devices(cpu_devices or None)
    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax import assemble, executor, sweep
    from membrax.config import TriaxialConfig
    from membrax.reproduce import SIZES

    base = TriaxialConfig(**{**SIZES[size], "float64": dtype == "float64"})
    _, members = assemble.grid_members(base, sweep.DEFAULT_GRID)
    start = time.perf_counter()
    batch = executor.build_batch([config for _, config in members], mode=mode or None)
    build = time.perf_counter() - start
    record_every = 100
    count = max(1, steps // record_every)
    real = batch.num_members
    # Only the padding needed to split the members evenly over the devices is a frozen copy (no steps).
    budgets = jnp.asarray([10 * steps] * real + [0] * (batch.num_padded - real))

    def rate(chunk_of, states, left):
        def call(s):
            return chunk_of(s, left, num_records=count, record_every=record_every, slots=count)

        _, first = timed(call, states)
        _, run = timed(call, states)
        return first - run, run

    sharded_compile, sharded_time = rate(
        lambda s, left, **kw: batch._chunk(s, batch.params, batch.members, left, **kw),
        batch.initial_state,
        budgets,
    )
    # On one GPU the unsharded call is the batched program again, and the serial column costs nine compiles.
    one_compile = one_time = serial_compile = serial_time = float("nan")
    if not batched_only:
        one = dataclasses.replace(
            batch,
            num_devices=1,
            **{
                name: jax.tree.map(lambda x: x[:real], getattr(batch, name))
                for name in ("params", "members", "initial_state")
            },
        )
        one_compile, one_time = rate(
            lambda s, left, **kw: one._chunk(s, one.params, one.members, left, **kw),
            one.initial_state,
            budgets[:real],
        )
        states = [test.start_consolidation(test.initial_state) for test in batch.tests]
        serial_compile, serial_time = time_one_by_one(batch.tests, states, count, record_every)
    member_steps = real * count * record_every
    bodies = batch.tests[0].particles.num_particles + batch.tests[0].mesh.num_nodes
    return {
        **batch_columns(dtype, batch),
        "nodes": int(batch.tests[0].mesh.num_nodes),
        "build_s": build,
        "batched_compile_s": sharded_compile,
        "batched_steps_per_s": member_steps / sharded_time,
        "batched_particle_steps_per_s": member_steps * bodies / sharded_time,
        "one_device_compile_s": one_compile,
        "one_device_steps_per_s": member_steps / one_time,
        "serial_compile_s": serial_compile,
        "serial_steps_per_s": member_steps / serial_time,
        "serial_particle_steps_per_s": member_steps * bodies / serial_time,
        "table1_wall_s_at_batched_rate": real * table_steps * sharded_time / member_steps,
        "batched_s_per_step": sharded_time / (count * record_every),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = benchmark_parser(__doc__)
    parser.add_argument("--size", default="small", choices=("small", "paper"))
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--mode", default="", help="map or vmap (default: by backend)")
    parser.add_argument("--cpu-devices", type=int, default=0, help="CPU devices (default: one per core)")
    parser.add_argument(
        "--table-steps", type=int, default=30000, help="member-steps per case for the Table 1 wall estimate"
    )
    parser.add_argument(
        "--batched-only",
        type=int,
        default=0,
        help="1: skip the one-device and serial columns (on one GPU the same program, and nine compiles)",
    )
    args, rows = benchmark_rows(__file__, parser, measure)
    if rows is None:
        return
    for row in rows:
        print(
            f"{row['dtype']} {row['backend']} ×{row['devices']} ({row['mode']}), {row['members']} members of "
            f"{row['spheres']} spheres + {row['nodes']} nodes: build {row['build_s']:.1f} s\n"
            f"  batched: compile {row['batched_compile_s']:.1f} s, {row['batched_steps_per_s']:.0f} "
            f"member-steps/s ({row['batched_particle_steps_per_s']:.3g} particle-steps/s), "
            f"{1e3 * row['batched_s_per_step']:.2f} ms per batched step\n"
            f"  batched on 1 device: compile {row['one_device_compile_s']:.1f} s, "
            f"{row['one_device_steps_per_s']:.0f} member-steps/s\n"
            f"  serial : compile {row['serial_compile_s']:.1f} s (9 chunks), {row['serial_steps_per_s']:.0f} "
            f"member-steps/s ({row['serial_particle_steps_per_s']:.3g} particle-steps/s)\n"
            f"  batched / serial = {row['batched_steps_per_s'] / row['serial_steps_per_s']:.2f}; Table 1 at "
            f"{args.table_steps} steps per case ≈ {row['table1_wall_s_at_batched_rate']:.0f} s; peak RSS "
            f"{row['peak_rss_mb']:.0f} MB"
        )


if __name__ == "__main__":
    main()
