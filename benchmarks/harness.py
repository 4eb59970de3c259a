"""Shared benchmark plumbing: one fresh process per dtype (x64 is process-global), a timer and the table."""

import argparse
import json
import re
import string
import subprocess
import sys
import time

import numpy as np

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


def benchmark_parser(doc: str) -> argparse.ArgumentParser:
    """An argument parser (described by ``doc``'s first line) with the flags every benchmark takes.

    ``--dtypes`` (comma-separated, default float32,float64) and the hidden ``--child DTYPE`` of
    :func:`benchmark_rows`.
    """
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--dtypes", default=",".join(DTYPES), help="comma-separated dtypes to run")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    return parser


def benchmark_rows(script: str, parser: argparse.ArgumentParser, measure, flags=None):
    """Every benchmark's child protocol: (its parsed arguments, its rows, one fresh process per dtype).

    Run as ``script --child DTYPE --key value ...`` (``--child`` given), print ``measure(DTYPE, **options)``
    as one JSON line and return rows None (the caller returns); otherwise run one child per dtype of
    ``--dtypes`` (:func:`run_each_dtype`) and return their rows. ``options`` are the parsed ``flags`` (names;
    default every flag but ``--child`` and ``--dtypes``): the flags are ``measure``'s keywords.
    """
    args = parser.parse_args()
    names = [name for name in vars(args) if name not in ("child", "dtypes")] if flags is None else flags
    options = {name: getattr(args, name) for name in names}
    if args.child:
        print(json.dumps(measure(args.child, **options)))
        return args, None
    return args, run_each_dtype(script, options, tuple(args.dtypes.split(",")))


def benchmark_report(
    script: str, parser: argparse.ArgumentParser, measure, caption, titles: str, row_format: str
) -> list[dict] | None:
    """A benchmark's main: its rows (:func:`benchmark_rows`), a caption and the table (:func:`print_table`).

    ``caption(args, first_row)`` is the line printed above the table; ``titles`` and ``row_format`` are
    :func:`print_table`'s. Returns the rows, or None in a child process (the caller returns).
    """
    args, rows = benchmark_rows(script, parser, measure)
    if rows is None:
        return None
    print(caption(args, rows[0]))
    print_table(rows, titles, row_format)
    return rows


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


def batch_columns(dtype: str, batch) -> dict:
    """The columns a batch benchmark's row starts with: dtype, backend, devices, mode, members, spheres."""
    import jax

    return {
        "dtype": dtype,
        "backend": jax.default_backend(),
        "devices": batch.num_devices,
        "mode": batch.mode,
        "members": batch.num_members,
        "spheres": int(batch.tests[0].particles.num_particles),
    }


def time_one_by_one(tests, states, num_records: int, record_every: int) -> tuple[float, float]:
    """(compile, run) seconds summed over the tests, each its runner's own compiled chunk from its state.

    Each test's chunk (:class:`membrax.driver.ChunkRunner`: ``num_records`` records every ``record_every``
    steps) is called twice in turn, the tests one after another: the first call's excess over the second is
    its compile time.
    """
    compile_time, run_time = 0.0, 0.0
    for test, state in zip(tests, states, strict=True):

        def alone(s, test=test):
            return test.runner._chunk(
                s,
                test.params,
                np.int32(num_records * record_every),
                num_records=num_records,
                record_every=record_every,
                slots=num_records,
            )

        _, compile_and_run = timed(alone, state)
        _, run = timed(alone, state)
        compile_time += compile_and_run - run
        run_time += run
    return compile_time, run_time


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
