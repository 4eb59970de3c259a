"""Where reverse mode through a rollout spends its time: a ``jax.profiler`` trace, summed by phase.

The rollout is ``bench_gradients.py``'s (same sizes, stages and options; default paper size, shearing,
500 steps). Each dtype runs in its own process: the forward and the reverse pass are compiled and timed
(best of 3), then one call of each is traced. Every traced operation is mapped to its HLO instruction in
the compiled program (its ``op_name`` metadata and, for the compiled kernels, its FFI target), and its
time is added to one of these phases of the reverse pass:

- ``first``: the forward pass that stores the window starts (``jvp``);
- ``recompute``: each window's steps run again with their residuals stored (``rematted_computation``);
- ``backward``: the transposed steps (``transpose``);
- ``loop``: operations XLA added without a source (mostly the loops' carry copies).

Each phase is split into the compiled kernels (``membrax.native``, FFI calls) and XLA's own operations,
in milliseconds per step of thread time (two threads can overlap, so the columns can add up to more than
the traced wall time, which tracing also lengthens). ``--top N`` lists the N costliest operations.

The forward kernels of the membrane forces, the node–sphere law and the sphere pairs are asynchronous
(:mod:`membrax.native`): the trace shows only their launch under their names, so the ``kernels`` columns of
``first`` and ``recompute`` count the node update and those launches, and their loops, which run in
unnamed pool tasks, are in no column.

Run: ``python benchmarks/profile_gradients.py [--size small|paper] [--stage shear|consolidation]
[--steps 500] [--window 50] [--consolidation-steps 5000] [--unroll 2] [--top 0]``.
"""

import collections
import glob
import gzip
import json
import re
import tempfile
import time

from bench_gradients import rollout_functions, rollout_options, rollout_parser
from harness import run_each_dtype

PHASES = ("first", "recompute", "backward", "loop")


def phase_of(op_name: str) -> str:
    """The reverse pass's phase of an HLO instruction, from its ``op_name`` metadata."""
    if not op_name:
        return "loop"
    if "rematted_computation" in op_name:
        return "recompute"
    if "transpose(" in op_name:
        return "backward"
    return "first"


def instructions(hlo_text: str) -> dict:
    """HLO instruction name → (op_name metadata, FFI target or '', result shape)."""
    table = {}
    for line in hlo_text.splitlines():
        match = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = (\S+) (.*)", line)
        if not match:
            continue
        name, shape, rest = match.groups()
        op_name = re.search(r'op_name="([^"]+)"', rest)
        target = re.search(r'custom_call_target="([^"]+)"', rest)
        table[name] = (op_name.group(1) if op_name else "", target.group(1) if target else "", shape)
    return table


def traced_events(folder: str) -> list[dict]:
    """The complete events of the trace written under ``folder`` (the ``.trace.json.gz`` file)."""
    paths = sorted(glob.glob(f"{folder}/plugins/profile/*/*.trace.json.gz"))
    if not paths:
        raise RuntimeError(f"jax.profiler wrote no .trace.json.gz under {folder}")
    with gzip.open(paths[-1]) as trace:
        return [event for event in json.load(trace)["traceEvents"] if event.get("ph") == "X"]


def child(dtype, top, **options) -> dict:
    """The forward and reverse passes timed, and one reverse call traced and summed by phase."""
    import jax

    forward, reverse, theta = rollout_functions(dtype, **options)
    steps = options["steps"]
    times = {}
    for name, function in (("forward", forward), ("reverse", reverse)):
        jax.block_until_ready(function(theta))
        runs = []
        for _ in range(3):
            start = time.perf_counter()
            jax.block_until_ready(function(theta))
            runs.append(time.perf_counter() - start)
        times[name] = min(runs)
    table = instructions(reverse.lower(theta).compile().as_text())
    with tempfile.TemporaryDirectory() as folder:
        jax.profiler.start_trace(folder)
        jax.block_until_ready(reverse(theta))
        jax.profiler.stop_trace()
        events = traced_events(folder)
    # The reverse call is the executor's one "wait for completion" span; the operations ran inside it.
    waits = [e for e in events if e["name"] == "ThunkExecutor::Execute (wait for completion)"]
    if not waits:
        raise RuntimeError("no executor span in the trace: is this XLA:CPU's thunk runtime?")
    call = max(waits, key=lambda e: e["dur"])
    begin, end = call["ts"], call["ts"] + call["dur"]
    sums = collections.defaultdict(float)
    per_op = collections.defaultdict(lambda: [0, 0.0])
    for event in events:
        if not begin <= event["ts"] <= end or event["tid"] == call["tid"] or event["name"] not in table:
            continue
        op_name, target, shape = table[event["name"]]
        if re.match(r"(while|cond|call)", event["name"]):
            continue  # containers: their insides are counted
        phase, milliseconds = phase_of(op_name), event["dur"] / 1e3
        sums[f"{phase} {'kernels' if target else 'xla'}"] += milliseconds
        per_op[(event["name"], target or shape, phase)][0] += 1
        per_op[(event["name"], target or shape, phase)][1] += milliseconds
    costliest = sorted(per_op.items(), key=lambda item: -item[1][1])[:top]
    return {
        "forward_s": times["forward"],
        "reverse_s": times["reverse"],
        "traced_ms": call["dur"] / 1e3,
        "ms_per_step": {key: value / steps for key, value in sums.items()},
        "top": [[name, what, phase, count, ms] for (name, what, phase), (count, ms) in costliest],
    }


def main() -> None:
    parser = rollout_parser(steps=500)
    parser.add_argument("--top", type=int, default=0)
    parser.add_argument("--child")
    args = parser.parse_args()
    options = {**rollout_options(args), "top": args.top}
    if args.child:
        print(json.dumps(child(args.child, **options)))
        return
    print(
        f"reverse-mode profile: {args.size} size, {args.stage}, {args.steps} steps, windows of "
        f"{args.window} (reverse windows unrolled: {args.unroll}); thread time per step (ms), by phase of "
        "the reverse pass"
    )
    columns = [f"{phase} {kind}" for phase in PHASES for kind in ("kernels", "xla")]
    columns.remove("loop kernels")
    print(
        f"{'dtype':<8}{'fwd (s)':>9}{'rev (s)':>9}{'rev ×':>7}{'traced (s)':>11}"
        + "".join(f"{column:>19}" for column in columns)
    )
    rows = run_each_dtype(__file__, options)
    for dtype, row in zip(("float32", "float64"), rows, strict=True):
        per_step = row["ms_per_step"]
        print(
            f"{dtype:<8}{row['forward_s']:>9.3f}{row['reverse_s']:>9.3f}"
            f"{row['reverse_s'] / row['forward_s']:>7.2f}{row['traced_ms'] / 1e3:>11.3f}"
            + "".join(f"{per_step.get(column, 0.0):>19.3f}" for column in columns)
        )
    for dtype, row in zip(("float32", "float64"), rows, strict=True):
        if row["top"]:
            print(f"\n{dtype}: costliest operations of the reverse pass (total ms over the traced call)")
            print(f"{'operation':<40}{'kernel or shape':<41}{'phase':<11}{'calls':>7}{'ms':>9}")
            for name, what, phase, count, ms in row["top"]:
                print(f"{name[:39]:<40}{what[:40]:<41}{phase:<11}{count:>7}{ms:>9.1f}")


if __name__ == "__main__":
    main()
