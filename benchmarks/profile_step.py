"""Where the batched step's time goes: kernels (or CPU thunks) per step and time per kernel, from a trace.

Builds Table 1's nine members on the specimen of ``--size`` (as ``bench_sweep.py`` does, one Δt and one
mesh topology, :func:`membrax.executor.build_batch`; ``vmap`` on a GPU, ``lax.map`` on a CPU unless
``--mode``), then for two stages runs one chunk of ``--steps`` steps under ``jax.profiler.trace`` and reads
the trace back (``jax.profiler.ProfileData``, no other tool):

- ``consolidation``: the members at rest, both platens servo-controlled, records every ``--record-every``
  (default: the consolidation's interval of the configuration);
- ``shear``: the same members switched to drained shearing (:meth:`MembraneTest.start_shear`), records at
  the shear's fine-phase interval (``record_every_fine``), as the first shearing chunks of a run.

For each stage it prints the wall time per batched step (host clock around a second, untraced call), the
device work per step (the sum of the kernels' or thunks' durations), the number of kernel launches per step,
the device-to-host and host-to-device copies per chunk, and the most expensive kernels (launches and µs per
step, share of the device time). It also counts the ``conditional`` instructions of the compiled chunk
(under ``vmap`` a ``lax.cond`` whose predicate differs between members becomes a select: both branches,
e.g. a neighbour-list or candidate rebuild, run on every step).

Each stage first runs ``--warmup-steps`` steps (default 0) and profiles from the state they reach: the
first steps from a freshly built batch rebuild every member's tables, so a steady run's share of rebuilds
shows only after a warm-up.

Run: ``python benchmarks/profile_step.py [--size small|paper] [--dtype float32] [--steps 200]
[--warmup-steps 0] [--mode map|vmap] [--top 15] [--out DIR]`` (``--out``: where the traces and a JSON
summary go).
"""

import argparse
import collections
import glob
import json
import os
import tempfile
import time


def device_events(trace_dir: str) -> tuple[str, list]:
    """(kind, [(line name, event name, duration ns)]) of the trace's device plane, or the CPU's thunks."""
    from jax.profiler import ProfileData

    (path,) = glob.glob(os.path.join(trace_dir, "**", "*.xplane.pb"), recursive=True)
    data = ProfileData.from_file(path)
    gpu = [plane for plane in data.planes if plane.name.startswith("/device:GPU")]
    events = []
    if gpu:
        for plane in gpu:
            for line in plane.lines:
                # Stream lines hold the kernels and copies; "XLA Ops"/"XLA Modules" lines repeat them.
                if "Stream" not in line.name:
                    continue
                events += [(line.name, event.name, event.duration_ns) for event in line.events]
        return "GPU kernels", events
    for plane in data.planes:
        if plane.name != "/host:CPU":
            continue
        for line in plane.lines:
            if line.name.startswith("tf_XLA"):
                events += [
                    (line.name, event.name, event.duration_ns)
                    for event in line.events
                    # The executor's own spans enclose the thunks: count the thunks alone.
                    if not event.name.startswith(("end:", "ThreadpoolListener", "ThunkExecutor"))
                ]
    return "CPU thunks", events


def is_copy(name: str) -> str | None:
    """'D2H', 'H2D' or 'D2D' for a memcpy event's name ("MemcpyD2H", "Memcpy HtoD", ...), else None."""
    key = name.lower().replace(" ", "").replace("_", "")
    if "memcpy" not in key:
        return None
    for marker, kind in (("d2h", "D2H"), ("dtoh", "D2H"), ("h2d", "H2D"), ("htod", "H2D")):
        if marker in key:
            return kind
    return "D2D"


def advance(chunk, states, left, steps: int, record_every: int):
    """The states after ``steps`` steps (rounded up to whole record intervals) of ``chunk``."""
    import jax

    if steps <= 0:
        return states
    num_records = -(-steps // record_every)
    states, *_ = chunk(states, left, num_records=num_records, record_every=record_every, slots=num_records)
    return jax.block_until_ready(states)


def profile(chunk, states, left, steps: int, record_every: int, top: int, trace_dir: str) -> dict:
    import jax

    num_records = max(1, steps // record_every)
    steps = num_records * record_every

    def call():
        out = chunk(states, left, num_records=num_records, record_every=record_every, slots=num_records)
        jax.block_until_ready(out)
        return out

    start = time.perf_counter()
    call()
    compile_and_run = time.perf_counter() - start
    start = time.perf_counter()
    call()
    wall = time.perf_counter() - start
    with jax.profiler.trace(trace_dir):
        call()
    kind, events = device_events(trace_dir)
    by_name = collections.defaultdict(lambda: [0, 0.0])
    copies = collections.Counter()
    for _, name, duration in events:
        by_name[name][0] += 1
        by_name[name][1] += duration
        copy = is_copy(name)
        if copy:
            copies[copy] += 1
    busy = sum(d for _, d in by_name.values())
    ranked = sorted(by_name.items(), key=lambda item: -item[1][1])
    return {
        "kind": kind,
        "steps": steps,
        "record_every": record_every,
        "compile_s": compile_and_run - wall,  # 0 where the chunk was compiled before
        "wall_ms_per_step": 1e3 * wall / steps,
        "device_ms_per_step": 1e-6 * busy / steps,
        "launches_per_step": len(events) / steps,
        "distinct_kernels": len(by_name),
        "copies_per_chunk": dict(copies),
        "top": [
            {
                "name": name,
                "launches_per_step": count / steps,
                "us_per_step": 1e-3 * total / steps,
                "share": total / busy if busy else float("nan"),
            }
            for name, (count, total) in ranked[:top]
        ],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=("small", "paper"))
    parser.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--mode", default="", help="map or vmap (default: by backend)")
    parser.add_argument("--record-every", type=int, default=0, help="consolidation's (default: config's)")
    parser.add_argument(
        "--warmup-steps",
        type=int,
        default=0,
        help="steps run in each stage before the profiled chunk (the state carried on: a steady run's "
        "rebuild frequency instead of the first steps' forced rebuilds)",
    )
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("--out", default="", help="folder for the traces and profile.json")
    args = parser.parse_args()

    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax import assemble, executor, sweep
    from membrax.config import TriaxialConfig
    from membrax.reproduce import SIZES

    out = args.out or tempfile.mkdtemp(prefix="membrax_profile_")
    os.makedirs(out, exist_ok=True)
    base = TriaxialConfig(**{**SIZES[args.size], "float64": args.dtype == "float64"})
    _, members = assemble.grid_members(base, sweep.DEFAULT_GRID)
    start = time.perf_counter()
    batch = executor.build_batch([config for _, config in members], mode=args.mode or None)
    build = time.perf_counter() - start
    plans = [t.phase_plan(s.loading) for t, s in zip(batch.tests, batch.settings, strict=True)]
    consolidation_every = args.record_every or plans[0]["consolidation"][1]
    left = jnp.asarray([10**9] * batch.num_padded)

    def chunk(states, left, **kw):
        return batch._chunk(states, batch.params, batch.members, left, **kw)

    records = max(1, args.steps // consolidation_every)
    start = time.perf_counter()
    compiled = batch._chunk.lower(
        batch.initial_state,
        batch.params,
        batch.members,
        left,
        num_records=records,
        record_every=consolidation_every,
        slots=records,
    ).compile()
    compile_s = time.perf_counter() - start
    conditionals = compiled.as_text().count(" conditional(")

    members_now = batch.unstack(batch.initial_state)
    sheared = batch.restack(
        [
            test.start_phase("shear_fine", m, s.loading)
            for test, m, s in zip(batch.tests, members_now, batch.settings, strict=True)
        ]
        + members_now[len(batch.tests) :]
    )
    stages = {
        "consolidation": (batch.initial_state, consolidation_every),
        "shear": (sheared, plans[0]["shear_fine"][1]),
    }
    results = {
        "backend": jax.default_backend(),
        "device": str(jax.devices()[0].device_kind),
        "dtype": args.dtype,
        "size": args.size,
        "mode": batch.mode,
        "members": batch.num_members,
        "spheres": int(batch.tests[0].particles.num_particles),
        "nodes": int(batch.tests[0].mesh.num_nodes),
        "build_s": build,
        "consolidation_compile_s": compile_s,
        "conditionals_in_chunk": conditionals,
        "stages": {},
    }
    results["warmup_steps"] = args.warmup_steps
    for name, (states, record_every) in stages.items():
        states = advance(chunk, states, left, args.warmup_steps, record_every)
        results["stages"][name] = profile(
            chunk, states, left, args.steps, record_every, args.top, os.path.join(out, name)
        )
    with open(os.path.join(out, "profile.json"), "w") as handle:
        json.dump(results, handle, indent=1)

    print(
        f"{results['members']} members ({results['mode']}, {results['backend']}: {results['device']}), "
        f"{results['spheres']} spheres + {results['nodes']} nodes, {args.dtype}; build {build:.1f} s, "
        f"compile {compile_s:.1f} s; {args.warmup_steps} warm-up steps per stage; "
        f"'conditional' instructions in the compiled chunk: {conditionals}"
    )
    print(
        "dtype   | stage         | record every | compile s | wall ms/step | device ms/step | launches/step"
    )
    for name, row in results["stages"].items():
        print(
            f"{args.dtype:<8}| {name:<14}|{row['record_every']:>13} |{row['compile_s']:>10.1f} |"
            f"{row['wall_ms_per_step']:>13.3f} |{row['device_ms_per_step']:>15.3f} |"
            f"{row['launches_per_step']:>14.1f}"
        )
    for name, row in results["stages"].items():
        print(
            f"\n{name}: copies per chunk {row['copies_per_chunk']}; top {args.top} {row['kind']} of "
            f"{row['distinct_kernels']} (per batched step)"
        )
        print("launches |    µs | share | name")
        for entry in row["top"]:
            share = 100 * entry["share"]
            print(
                f"{entry['launches_per_step']:>8.2f} |{entry['us_per_step']:>6.1f} |{share:>5.1f}% | "
                f"{entry['name'][:90]}"
            )
    print(f"\ntraces and profile.json in {out}")


if __name__ == "__main__":
    main()
