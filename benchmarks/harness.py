"""Shared benchmark plumbing: one fresh process per dtype (x64 is process-global) and a timer."""

import json
import subprocess
import sys
import time

DTYPES = ("float32", "float64")


def run_child(script: str, child: list, options: dict) -> dict:
    """Run ``script --child CHILD... --key value ...`` (``options``' keys as flags); its last JSON line."""
    command = [sys.executable, script, "--child", *child]
    for key, value in options.items():
        command += [f"--{key.replace('_', '-')}", str(value)]
    output = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    return json.loads(output.strip().splitlines()[-1])


def run_each_dtype(script: str, options: dict, dtypes=DTYPES) -> list[dict]:
    """Run ``script --child DTYPE --key value ...`` once per dtype; each child prints one JSON line."""
    return [run_child(script, [dtype], options) for dtype in dtypes]


def timed(function, *args):
    """(result, seconds) of one call, waiting for the device."""
    import jax

    start = time.perf_counter()
    out = function(*args)
    jax.block_until_ready(out)
    return out, time.perf_counter() - start


def best_of(function, *args, runs: int = 3) -> float:
    """Shortest of ``runs`` timed calls, s: a shared 2-core machine only ever adds time to a run."""
    return min(timed(function, *args)[1] for _ in range(runs))
