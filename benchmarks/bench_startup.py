"""What a run compiles before and between its steps: building a test, and the chunks of a short sweep.

For each dtype, in a fresh process with no compilation cache, prints: the seconds ``build_test`` takes
for the smoke preset's specimen (4 across, 5 layers, membrane edge D/3: the specimen the tests and the
notebooks' smoke runs use most) and the XLA programs it compiles (each eager operation on a new shape is
one); then, for a sweep of three cell pressures on it (the preset: to 0.4 % strain), the wall time, the
chunk programs ``membrax.driver.drive`` compiled (one per chunk length and record slots: the phases'
record intervals are arguments, so a run's three phases share one) and their
compile seconds. JAX's compile events are counted with ``jax.monitoring``; XLA at users' optimisation
level.

Run: ``python benchmarks/bench_startup.py [--dtypes float32]`` (about 1 min on 2 cores).
"""

import collections
import tempfile
import time
import traceback

from harness import benchmark_parser, benchmark_report


def measure(dtype: str) -> dict:
    import jax
    import jax.monitoring

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    compiled = collections.Counter()

    def count(event, duration, **_):
        if event.endswith("backend_compile_duration"):
            where = "chunk" if any(frame.name == "drive" for frame in traceback.extract_stack()) else "other"
            compiled[where] += 1
            compiled[where + "_s"] += duration

    jax.monitoring.register_event_duration_secs_listener(count)
    from membrax import SMOKE_CONFIG, sweep
    from membrax.assemble import build_test
    from membrax.config import TriaxialConfig

    config = TriaxialConfig(**{**SMOKE_CONFIG, "float64": dtype == "float64"})
    start = time.perf_counter()
    build_test(config)
    build_s, build_programs = time.perf_counter() - start, compiled["other"]
    compiled.clear()
    start = time.perf_counter()
    grid = {"cell_pressure_kpa": (10.0, 40.0, 100.0), "membrane_thickness_mm": (5.0,)}
    sweep.run_sweep(config, grid, tempfile.mkdtemp(), progress=False, num_devices=1)
    return {
        "dtype": dtype,
        "build_s": build_s,
        "build_programs": build_programs,
        "sweep_s": time.perf_counter() - start,
        "chunk_programs": compiled["chunk"],
        "chunk_compile_s": compiled["chunk_s"],
    }


def main():
    benchmark_report(
        __file__,
        benchmark_parser(__doc__),
        measure,
        lambda args, first: "smoke preset's specimen; a 3-member sweep to 0.4 % strain; no compilation cache",
        "build_test s|programs|sweep s|chunk programs|chunk compile s",
        "{build_s:>14.2f}{build_programs:>10d}{sweep_s:>9.1f}{chunk_programs:>16d}{chunk_compile_s:>17.2f}",
    )


if __name__ == "__main__":
    main()
