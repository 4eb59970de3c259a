"""The GPU figures docs/benchmarks.md quotes, in one call on a lent GPU machine, inside a deadline.

Runs, in turn, each as its own process with a timeout, writing its output under ``--out``:

1. the environment (``nvidia-smi``, JAX's version and devices);
2. ``bench_sweep.py --size paper --steps 300 --batched-only 1`` (Table 1's nine members as one ``vmap``
   call: member-steps/s and ms per batched step) in float64, the dtype of ``membrax reproduce``;
3. ``bench_gradients.py --stage consolidation`` in float32 (reverse/forward time; host, program and device
   memory);
4. ``bench_dem.py`` (the rigid-wall DEM, single specimen and the 9-case batch folded, ``lax.map``, ``vmap``);
5. ``membrax reproduce --size paper`` with the time left, its tables copied to ``--out``; if it cannot
   finish, its progress log still says how far it got;
6. step 2 in float32, with what is left;
7. step 3 with ``--step-remat on`` (the windows' steps checkpointed one by one, as on a CPU's JAX path;
   on one H200 it cost 16 % more time and 12 % more program buffers, so a GPU's default is off);
8. step 3 through whole windows (``--window 10 --unroll 10``: no loop inside a checkpoint window; on one
   H200 its two passes did not finish in 180 s, 2026-11-26);
9. ``tests/test_gradients.py``'s central-difference test (two members under ``vmap``, 2,000 steps, float64):
   the checkpointed reverse pass checked on the GPU's JAX path, with what is left.

Step 5 is predicted from step 2's float64 rate (``REPRODUCE_BATCH_STEPS`` batched steps, the longest
member's at paper size) and run before steps 3–4 when it fits only without them. The prediction is low:
step 2 times consolidation steps, and on the one H200 measured (2026-11-26) the reproduction's shearing
steps took 1.7× as long (predicted 307 s; the run reached 89 % of its steps in 449 s). A later H200 with
no compilation cache reached the same step in 562 s, and ``--resume`` finished it in 116 s more.

On the lent machines the image's JAX is used and the packages it lacks travel as wheels (jax-md, e3nn-jax,
jraph, ml_collections, meshio: ``pip download --no-deps`` into ``.whl/``, then
``pip install --no-index --no-deps --target /tmp/site .whl/*.whl`` and ``PYTHONPATH=/tmp/site:$PWD``).

Run on the device machine, in the repository root: ``python3 benchmarks/gpu_check.py --budget 540``; with
``--size small`` it is a quick check of the script itself on any machine. ``--only reproduce`` gives the
reproduction the whole budget (it did not fit beside the benchmarks in one 10-minute call on an H200);
``--resume`` in a later call on the same machine continues it from its checkpoints in ``/tmp``.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
# Consolidation (10,000) then shearing (24,500 + 110,250) steps of the 10 kPa members, the last to finish
# at paper size (docs/benchmarks.md: membrax reproduce --size paper).
REPRODUCE_BATCH_STEPS = 144_750
STEPS = (
    "sweep64",
    "reproduce",
    "gradients",
    "dem",
    "sweep32",
    "gradients-on",
    "gradients-whole",
    "test-gradients",
)


def run(name: str, command: list[str], timeout: float, out: Path) -> str:
    """The output of ``command``, killed after ``timeout`` s; also written to out/name, with its status."""
    start = time.perf_counter()
    print(f"\n$ {' '.join(command)}   (timeout {timeout:.0f} s)", flush=True)
    if timeout < 10:
        print("  skipped: no time left", flush=True)
        return ""
    with open(out / name, "w") as log:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            text, _ = process.communicate(timeout=timeout)
            status = process.returncode
        except subprocess.TimeoutExpired:
            process.kill()
            text = process.communicate()[0] + f"\n[killed after {timeout:.0f} s]\n"
            status = 124
        log.write(text)
    seconds = time.perf_counter() - start
    # Progress bars rewrite one line with carriage returns: show the last state of each line.
    shown = "\n".join(line.split("\r")[-1] for line in text.splitlines())
    print(shown[-4000:], flush=True)
    print(f"  [{name}: status {status}, {seconds:.0f} s]", flush=True)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=540.0, help="seconds for the whole check")
    parser.add_argument("--size", default="paper", choices=("small", "paper"))
    parser.add_argument("--out", default=os.environ.get("OUT", "gpu_check_out"))
    parser.add_argument(
        "--only",
        default=",".join(STEPS),
        help=f"comma-separated steps to run, of {','.join(STEPS)} (reproduce alone: 620-680 s on an H200, "
        "more than one 10-minute call: finish it with --resume)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted reproduction from its checkpoints (a later call on the same machine)",
    )
    args = parser.parse_args()
    steps = set(args.only.split(","))
    if not steps <= set(STEPS):
        parser.error(f"--only: unknown steps {sorted(steps - set(STEPS))}; choose from {','.join(STEPS)}")
    deadline = time.perf_counter() + args.budget
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def left() -> float:
        return deadline - time.perf_counter()

    # Programs repeat across the steps (the members' set-up, the sweep's chunk): compile each once.
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", "/tmp/membrax_gpu_check_cache")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    python = sys.executable
    env_lines = []
    if shutil.which("nvidia-smi"):
        query = ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"]
        env_lines.append(subprocess.run(query, capture_output=True, text=True).stdout.strip())
    probe = "import jax, numpy; print('jax', jax.__version__, 'numpy', numpy.__version__, jax.devices())"
    env_lines.append(subprocess.run([python, "-c", probe], capture_output=True, text=True).stdout.strip())
    (out / "env.txt").write_text("\n".join(env_lines) + "\n")
    print("\n".join(env_lines), flush=True)

    def bench(script: str, *options: str) -> list[str]:
        return [python, str(HERE / script), "--size", args.size, *options]

    sweep_steps = "300" if args.size == "paper" else "100"
    sweep = ("bench_sweep.py", "--steps", sweep_steps, "--batched-only", "1", "--dtypes")
    text = ""
    if "sweep64" in steps:
        text = run("bench_sweep.txt", bench(*sweep, "float64"), min(200.0, left() - 30), out)
    match = re.search(r"float64 .*?([\d.]+) ms per batched step", text, re.S)
    build = re.search(r"float64 .*?build ([\d.]+) s.*?compile ([\d.]+) s", text, re.S)
    predicted = None
    if match and build:
        simulation = REPRODUCE_BATCH_STEPS * float(match.group(1)) / 1e3
        predicted = simulation + float(build.group(1)) + float(build.group(2))
        print(f"  membrax reproduce --size {args.size}: predicted {predicted:.0f} s (steps, build, compile)")

    def reproduce() -> None:
        folder = Path("/tmp") / f"reproduce_{args.size}"
        if not args.resume:
            shutil.rmtree(folder, ignore_errors=True)
        command = [python, "-m", "membrax.cli", "reproduce", "--size", args.size, "--out", str(folder)]
        run("reproduce.log", command + ["--resume"] * args.resume, left() - 10, out)
        for name in ("table2.md", "table3.md", "reproduction.md"):
            if (folder / name).exists():
                shutil.copy(folder / name, out / name)

    benches_s = 250.0  # what steps 3-4 are given when reproduce waits for them
    reproduce_first = "reproduce" in steps and (
        steps == {"reproduce"} or (predicted is not None and predicted < left() - 20 < predicted + benches_s)
    )
    if reproduce_first:
        reproduce()
    gradient_steps = "2000" if args.size == "paper" else "200"
    gradients = bench("bench_gradients.py", "--stage", "consolidation", "--steps", gradient_steps)
    if "gradients" in steps:
        run("bench_gradients.txt", [*gradients, "--dtypes", "float32"], min(150.0, left() - 10), out)
    small_dem = ["--width", "4", "--layers", "5", "--steps", "100"]
    dem_size = ["--steps", "300"] if args.size == "paper" else small_dem
    if "dem" in steps:
        run("bench_dem.txt", [python, str(HERE / "bench_dem.py"), *dem_size], min(120.0, left() - 10), out)
    if "reproduce" in steps and not reproduce_first:
        reproduce()
    if "sweep32" in steps:
        run("bench_sweep_float32.txt", bench(*sweep, "float32"), min(200.0, left() - 5), out)
    if "gradients-on" in steps:
        on = [*gradients, "--dtypes", "float32", "--step-remat", "on"]
        run("bench_gradients_on.txt", on, min(150.0, left() - 5), out)
    if "gradients-whole" in steps:
        whole = [*gradients, "--dtypes", "float32", "--window", "10", "--unroll", "10"]
        run("bench_gradients_whole.txt", whole, min(180.0, left() - 5), out)
    if "test-gradients" in steps:
        test = "test_checkpointed_gradients_through_consolidation_and_shearing_match_central_differences"
        # addopts cleared: the image has no nbmake, and this test needs none
        where = str(HERE.parent / "tests" / "test_gradients.py")
        pytest = [python, "-m", "pytest", "-o", "addopts=", "-q", "-p", "no:cacheprovider", where, "-k", test]
        run("test_gradients.txt", pytest, left() - 5, out)
    print(f"\nfiles in {out}: {sorted(p.name for p in out.iterdir())}; {left():.0f} s of the budget left")


if __name__ == "__main__":
    main()
