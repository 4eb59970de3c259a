"""Where a sweep's wall time goes between chunks: steps, seconds, reallocations and checkpoints per chunk.

Runs Table 1's nine members on the specimen of ``--size`` (the reproduction's configuration,
:data:`membrax.reproduce.SIZES`) through :func:`membrax.runner.run_group`, as ``membrax reproduce`` does,
for at most ``--seconds`` (then stops after the running chunk), and prints one row per chunk: the phase,
the batched steps it advanced (the longest member's step count), its wall seconds, ms per batched step,
the table reallocations it caused (a neighbour-list or node-candidate overflow reruns the chunk from its
start with larger tables) and the seconds spent writing checkpoints. ``profile_step.py`` gives the cost
of the step itself; the difference is the host's share (reruns, checkpoints, records).

Run: ``python benchmarks/chunk_timeline.py [--size small|paper] [--seconds 300] [--out DIR]``.
"""

import argparse
import tempfile
import time
from pathlib import Path


class Stop(Exception):
    """Raised from the chunk callback when the time is up."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=("small", "paper"))
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--out", default="", help="checkpoint folder (default: a temporary one)")
    args = parser.parse_args()

    import jax
    import numpy as np

    from membrax import assemble, executor, runner, sweep
    from membrax.config import TriaxialConfig
    from membrax.reproduce import SIZES

    base = TriaxialConfig(**SIZES[args.size])
    if base.float64:
        jax.config.update("jax_enable_x64", True)
    _, members = assemble.grid_members(base, sweep.DEFAULT_GRID)
    start = time.perf_counter()
    batch = executor.build_batch([config for _, config in members])
    print(
        f"{batch.num_members} members ({batch.mode}, {jax.devices()[0].device_kind}), "
        f"{'float64' if base.float64 else 'float32'}, chunk {base.chunk_steps} steps; build "
        f"{time.perf_counter() - start:.1f} s",
        flush=True,
    )

    saving = [0.0]
    save_checkpoint = runner.save_checkpoint

    def timed_save(*a, **kw):
        begin = time.perf_counter()
        save_checkpoint(*a, **kw)
        saving[0] += time.perf_counter() - begin

    runner.save_checkpoint = timed_save
    rows = []
    last = {"time": time.perf_counter(), "step": 0, "reallocations": 0, "saving": 0.0}
    deadline = time.perf_counter() + args.seconds

    def after_chunk(states, phase):
        now = time.perf_counter()
        step = int(np.max(np.asarray(states.dem.step)))
        rows.append(
            {
                "phase": phase,
                "steps": step - last["step"],
                "seconds": now - last["time"],
                "reallocations": batch.reallocations - last["reallocations"],
                "checkpoint_s": saving[0] - last["saving"],
            }
        )
        row = rows[-1]
        per_step = 1e3 * row["seconds"] / max(row["steps"], 1)
        print(
            f"{len(rows):>5} | {phase:<13} | {row['steps']:>6} | {row['seconds']:>8.2f} | {per_step:>8.3f} | "
            f"{row['reallocations']:>5} | {row['checkpoint_s']:>6.2f}",
            flush=True,
        )
        last.update(time=now, step=step, reallocations=batch.reallocations, saving=saving[0])
        if now > deadline:
            raise Stop

    print("chunk | phase         |  steps |  seconds | ms/step | reall | ckpt s", flush=True)
    folder = Path(args.out or tempfile.mkdtemp(prefix="membrax_timeline_"))
    folder.mkdir(parents=True, exist_ok=True)
    try:
        runner.run_group(batch, folder, progress=False, after_chunk=after_chunk)
    except Stop:
        pass
    for phase in dict.fromkeys(row["phase"] for row in rows):
        mine = [row for row in rows if row["phase"] == phase]
        steps = sum(row["steps"] for row in mine)
        seconds = sum(row["seconds"] for row in mine)
        print(
            f"{phase}: {len(mine)} chunks, {steps} batched steps in {seconds:.1f} s "
            f"({1e3 * seconds / max(steps, 1):.3f} ms per step), "
            f"{sum(row['reallocations'] for row in mine)} reallocations, "
            f"{sum(row['checkpoint_s'] for row in mine):.1f} s of checkpoints"
        )


if __name__ == "__main__":
    main()
