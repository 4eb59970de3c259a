"""Shared benchmark plumbing: one fresh process per dtype (x64 is process-global), a timer and the table."""

import json
import re
import string
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


def time_coupled_steps(test, repeats: int) -> tuple[float, float]:
    """(first call, best of three) seconds of ``repeats`` coupled steps of a membrane test, s.

    From the test's state with the platens' servos on; compiled as membrax compiles a run's chunks (one
    ``fori_loop``, membrax's compiler options), so the first call's excess over the best is the compile time.
    """
    import jax

    from membrax import native

    state = test.set_platens(test.initial_state, True, 0.0, test.cell_pressure)
    coupled = jax.jit(
        lambda s: jax.lax.fori_loop(0, repeats, lambda _, x: test.runner.step_fn(x, test.params), s),
        compiler_options=native.compiler_options(),
    )
    state, first = timed(coupled, state)
    return first, best_of(coupled, state)


def print_table(rows: list[dict], titles: str, row_format: str) -> None:
    """Print one line per dtype's ``rows`` under a header and a rule.

    Each line is the dtype, then ``row_format.format(**row)``. ``titles`` names the fields of ``row_format``
    in order, separated by "|"; each is right-aligned to its field's width (``{key:>WIDTH...}``), so that
    the header cannot drift from the columns.
    """
    fields = [spec for _, _, spec, _ in string.Formatter().parse(row_format) if spec]
    widths = [int(re.match(r">(\d+)", spec)[1]) for spec in fields]
    columns = zip(titles.split("|"), widths, strict=True)
    header = f"{'dtype':<8}" + "".join(f"{title:>{width}}" for title, width in columns)
    print(header)
    print("-" * len(header))
    for row in rows:
        print(f"{row['dtype']:<8}" + row_format.format(**row))
