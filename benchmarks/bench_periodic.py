"""Periodic elements of one packing batched in one compiled call against the same elements one by one.

For each dtype, in a fresh process split into one CPU device per core
(:func:`membrax.devices.split_cpu_devices`, as ``membrax sweep`` does; ``--cpu-devices``), builds
``--members`` periodic elements of the periodic demo's spheres (``--particles`` equal 25 mm spheres, one
packing; cell pressures spread over 10–100 kPa) as one batch (:func:`membrax.executor.build_periodic_batch`)
and times ``--steps`` consolidation steps of each member:

- batched: one chunk call advancing every member, sharded over the devices (``lax.map`` over each device's
  members on a CPU, ``vmap`` on a GPU, or ``--mode``), as a sweep runs them;
- one by one: each member's own compiled chunk (:class:`membrax.triaxial.periodic.PeriodicRunner`, one
  compile each, as the members of a sweep ran before they were batched), the members in turn.

Each column is steps/s per member: the steps every member advances per second of wall time while the
batch (or the sequence of members) runs, so the ratio is the sweep's speed-up; and the compile times.

Run: ``python benchmarks/bench_periodic.py [--members 4] [--particles 500] [--steps 1000] [--mode map|vmap]
[--cpu-devices N] [--dtypes float32,float64]``.
"""

import numpy as np
from harness import batch_columns, benchmark_parser, benchmark_report, time_one_by_one, timed


def measure(dtype: str, members: int, particles: int, steps: int, mode: str, cpu_devices: int) -> dict:
    import jax

    from membrax.devices import split_cpu_devices

    split_cpu_devices(cpu_devices or None)
    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax import executor
    from membrax.config import TriaxialConfig, with_overrides

    base = TriaxialConfig(
        name="bench_periodic",
        packing="random",
        cell="periodic",
        periodic_particles=particles,
        float64=dtype == "float64",
    )
    pressures = np.geomspace(10.0, 100.0, members)
    configs = [with_overrides(base, cell_pressure_kpa=float(p)) for p in pressures]
    batch = executor.build_periodic_batch(configs, mode=mode or None)
    record_every = 100
    count = max(1, steps // record_every)
    real = batch.num_members
    # Every real member runs the whole chunk; only the padding to a multiple of the devices is frozen.
    budgets = jnp.asarray([10 * steps] * real + [0] * (batch.num_padded - real))

    def batched(states):
        return batch._chunk(
            states,
            batch.params,
            batch.members,
            budgets,
            num_records=count,
            record_every=record_every,
            slots=count,
        )

    _, first = timed(batched, batch.initial_state)
    _, batched_time = timed(batched, batch.initial_state)
    serial_compile, serial_time = time_one_by_one(
        batch.tests, batch.unstack(batch.initial_state), count, record_every
    )
    advanced = count * record_every
    return {
        **batch_columns(dtype, batch),
        "steps": advanced,
        "batched_compile_s": first - batched_time,
        "batched_steps_per_s": advanced / batched_time,
        "serial_compile_s": serial_compile,
        "serial_steps_per_s": advanced / serial_time,
        "speedup": serial_time / batched_time,
    }


def main() -> None:
    parser = benchmark_parser(__doc__)
    parser.add_argument("--members", type=int, default=4)
    parser.add_argument("--particles", type=int, default=500)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--mode", default="", help="map or vmap (default: by backend)")
    parser.add_argument("--cpu-devices", type=int, default=0, help="CPU devices (default: one per core)")

    def caption(_, first):
        return (
            f"{first['members']} periodic elements of {first['spheres']} spheres, "
            f"{first['steps']} consolidation steps each, {first['backend']} ×{first['devices']} "
            f"({first['mode']}); steps/s per member:"
        )

    benchmark_report(
        __file__,
        parser,
        measure,
        caption,
        "batched|one by one|batched / one by one|batched compile s|one by one compile s",
        "{batched_steps_per_s:>9.0f}{serial_steps_per_s:>12.0f}{speedup:>22.2f}{batched_compile_s:>19.1f}"
        "{serial_compile_s:>22.1f}",
    )


if __name__ == "__main__":
    main()
