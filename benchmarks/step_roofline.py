"""The coupled step against the machine's limits: flops and bytes per step beside what the cores can do.

For the paper-size member (FCC, 25 mm spheres, 10 across, 25 layers, membrane edge D/5, 5 mm at 10 kPa,
consolidating, as ``bench_membrane.py``'s coupled row), in a fresh process per dtype:

- **work per step**: XLA's cost analysis (``Compiled.cost_analysis()``) of one jitted step without its
  table rebuilds (:func:`rebuilds_compiled_out`: XLA would count each rebuild branch on every step; a
  steady run rebuilds rarely); the rebuilds' flops are reported apart. The flop count is taken from the
  pure-JAX formulas (the step traced with :func:`membrax.native.available` patched to False, as
  ``MEMBRAX_NATIVE=0``), because XLA counts no flops in a custom call; the compiled kernels do the same
  arithmetic. The bytes are XLA's own tally of the operands and results its instructions touch, for the
  step as users run it (kernels on) and for the JAX formulas: an upper bound on the traffic, since an
  operand that a fusion rereads from cache counts again.
- **the state**: the bytes of the step's state (every array it reads and writes), the least a step can
  move (read once, write once: 2× the state).
- **time per step**: best of three runs of ``--repeats`` steps inside one ``fori_loop``.
- **the machine**: a float matrix product (``jnp.dot``, 2,048², XLA's Eigen on all cores) for the
  attainable flop rate, and an array update ``y = 1.0001 x + y`` (read 2, write 1) for the bandwidth, once
  out of cache (256 MB arrays, DRAM) and once cache-resident (arrays the size of one member's state).

The achieved rates (flops / time, bytes / time) over the limits say how far the step is from being bound
by arithmetic or by memory: both far below 1 means latency, launches and serial dependencies cost the time.

Run: ``python benchmarks/step_roofline.py [--dtypes float32,float64] [--repeats 200]``.
"""

import argparse
import contextlib
import json

from harness import best_of, print_table, run_each_dtype, timed


def cost(compiled) -> tuple[float, float]:
    """(flops, bytes accessed) of a compiled executable, from XLA's cost analysis."""
    analysis = compiled.cost_analysis()
    if isinstance(analysis, list):  # older jax returns one dict per program
        analysis = analysis[0]
    return float(analysis.get("flops", 0.0)), float(analysis.get("bytes accessed", 0.0))


def cost_of(function, *args, kernels: bool) -> tuple[float, float]:
    """(flops, bytes) of ``jit(function)(*args)`` traced with the compiled CPU kernels on or off."""
    import jax

    from membrax import native

    available = native.available
    if not kernels:
        native.available = lambda: False
    try:
        jax.clear_caches()
        return cost(jax.jit(function).lower(*args).compile())
    finally:
        native.available = available
        jax.clear_caches()


@contextlib.contextmanager
def rebuilds_compiled_out():
    """Trace steps whose neighbour list and node–sphere candidates never rebuild (tables kept as they are).

    XLA's cost analysis counts a conditional as its costliest branch, i.e. a rebuild on every step, while a
    steady run rebuilds rarely (``profile_step.py --warmup-steps``: none in 500 steps); the per-step figure
    leaves them out and the rebuild's own cost is reported apart.
    """
    from membrax.membrane import coupled
    from membrax.spheres import integrate, neighbors

    saved = (coupled.update_candidates, neighbors.PairNeighborFn.update, integrate.remap_pair_history)
    coupled.update_candidates = lambda candidates, spring, *_: (candidates, spring)
    neighbors.PairNeighborFn.update = lambda self, position, table: table
    integrate.remap_pair_history = lambda old_idx, new_idx, history, num_particles: history
    try:
        yield
    finally:
        coupled.update_candidates, neighbors.PairNeighborFn.update, integrate.remap_pair_history = saved


def machine_limits(dtype) -> dict:
    """Measured flop rate (matrix product) and bandwidth (y = a x + y) out of and inside the cache."""
    import jax
    import jax.numpy as jnp

    size = 2048
    a = jnp.ones((size, size), dtype) * 1e-3
    dot = jax.jit(lambda x: jnp.dot(x, x))
    timed(dot, a)
    flop_rate = 2.0 * size**3 / best_of(dot, a, runs=5)

    def bandwidth(num_bytes: int, repeats: int) -> float:
        n = num_bytes // jnp.dtype(dtype).itemsize
        x = jnp.ones(n, dtype)
        update = jax.jit(
            lambda y: jax.lax.fori_loop(0, repeats, lambda _, z: jnp.asarray(1.0001, dtype) * x + z, y)
        )
        timed(update, x)
        return 3.0 * n * jnp.dtype(dtype).itemsize * repeats / best_of(update, x)

    return {"flop_rate": flop_rate, "dram_bandwidth": bandwidth(256 << 20, 5)}, bandwidth


def measure(dtype: str, repeats: int) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax import native
    from membrax.spheres import fcc
    from membrax.triaxial import membrane_cell as membrane_triaxial

    specimen = fcc.fcc_specimen(0.025, 10, 25)
    test = membrane_triaxial.membrane_test(
        specimen, cell_pressure=1e4, membrane_thickness=0.005, edges_per_diameter=5.0
    )
    state = test.set_platens(test.initial_state, True, 0.0, test.cell_pressure)

    def one_step(s):
        return test.runner.step_fn(s, test.params)

    kernels = native.available()
    full_flops, _ = cost_of(one_step, state, kernels=False)
    with rebuilds_compiled_out():
        flops, jax_bytes = cost_of(one_step, state, kernels=False)
        _, xla_bytes = cost_of(one_step, state, kernels=kernels)

    loop = jax.jit(  # compiled as membrax compiles a run's chunks
        lambda s: jax.lax.fori_loop(0, repeats, lambda _, x: one_step(x), s),
        compiler_options=native.compiler_options(),
    )
    state, _ = timed(loop, state)
    seconds = best_of(loop, state) / repeats
    state_bytes = sum(leaf.nbytes for leaf in jax.tree_util.tree_leaves(state) if hasattr(leaf, "nbytes"))

    limits, bandwidth = machine_limits(getattr(jnp, dtype))
    cache_bandwidth = bandwidth(max(state_bytes // 3, 1 << 16), 200)
    return {
        "dtype": dtype,
        "kernels": "compiled" if kernels else "JAX",
        "spheres": int(specimen.position.shape[0]),
        "nodes": int(test.mesh.num_nodes),
        "step_ms": 1e3 * seconds,
        "mflop": 1e-6 * flops,
        "rebuild_mflop": 1e-6 * (full_flops - flops),
        "gflops": 1e-9 * flops / seconds,
        "peak_gflops": 1e-9 * limits["flop_rate"],
        "flop_share": flops / seconds / limits["flop_rate"],
        "state_mb": 1e-6 * state_bytes,
        "xla_mb": 1e-6 * xla_bytes,
        "jax_mb": 1e-6 * jax_bytes,
        "gbs": 1e-9 * xla_bytes / seconds,
        "state_gbs": 1e-9 * 2 * state_bytes / seconds,
        "dram_gbs": 1e-9 * limits["dram_bandwidth"],
        "cache_gbs": 1e-9 * cache_bandwidth,
        "byte_share": xla_bytes / seconds / cache_bandwidth,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dtypes", default="float32,float64")
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.child, args.repeats)))
        return
    rows = run_each_dtype(__file__, {"repeats": args.repeats}, dtypes=tuple(args.dtypes.split(",")))
    first = rows[0]
    print(
        f"coupled step, paper-size member: {first['spheres']} spheres + {first['nodes']} nodes; "
        f"CPU kernels: {first['kernels']}; per step without rebuilds (rebuild: the flops of one rebuild of "
        "both tables); flops from the JAX formulas, MB/step from XLA's tally of the step as run; cache "
        "bandwidth on arrays of a third of the state each"
    )
    print_table(
        rows,
        "step ms|MFLOP/step|rebuild MFLOP|GFLOP/s|peak GFLOP/s|of peak|state MB|MB/step|JAX MB/step|"
        "GB/s|2×state GB/s|DRAM GB/s|cache GB/s|of cache",
        "{step_ms:>8.3f}{mflop:>11.2f}{rebuild_mflop:>14.1f}{gflops:>8.2f}{peak_gflops:>13.1f}"
        "{flop_share:>8.1%}{state_mb:>9.2f}{xla_mb:>8.1f}{jax_mb:>12.1f}{gbs:>6.1f}{state_gbs:>13.2f}"
        "{dram_gbs:>10.1f}{cache_gbs:>11.1f}{byte_share:>9.1%}",
    )


if __name__ == "__main__":
    main()
