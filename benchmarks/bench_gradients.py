"""Reverse mode through a rollout of the coupled step, with ``jax.checkpoint``: time and memory vs forward.

For a rollout of N steps (default 2,000) of the membrane test, y = the internal σ1 at the end, along one
of two stages (``--stage``):

- ``shear`` (default): from the state after C steps of consolidation (``--consolidation-steps``, default
  5,000, run forward and not differentiated), the platens closing at the configuration's strain rate
  (:meth:`MembraneTest.start_shear`); θ acts on the shearing window only;
- ``consolidation``: from the as-built state, both platens servo-controlled to σc A₀;

- ``forward``: y(θ) by one jitted ``lax.scan`` over windows of W steps (a checkpoint is the plain loop
  when nothing is differentiated), each window's loop unrolled by 2: the program
  :attr:`membrax.gradients.Rollout.forward` runs;
- ``reverse``: (y, dy/dθ) by ``jax.value_and_grad`` of the same scan, each window wrapped in
  ``jax.checkpoint``, so reverse mode stores N/W window-start states and recomputes one window's steps
  at a time (θ = E_m and σc); the windows are the library's (:func:`membrax.gradients.checkpoint_window`):
  a loop of ``--unroll`` steps per iteration, or with ``--unroll`` ≥ ``--window`` whole windows without
  a loop; on a CPU's JAX path (``MEMBRAX_NATIVE=0``) each step checkpointed inside them too, not on a
  GPU, where it does not pay (``--step-remat`` forces it on or off);

each in its own process, once per dtype, printing compile time (lowering and compiling), run time (best
of 3 after one warm-up), peak RSS, the compiled program's own buffers (XLA's ``memory_analysis``:
temporaries, arguments and outputs; not the constants, such as the start state, nor the process's
fixed ~1.2 GB that the RSS includes), on an accelerator its own peak memory (``memory_stats``), and the
ratios reverse/forward. The goals at paper size: memory ≤ 2×, time ≤ 4×.

This measures cost, not correctness, in the paper's mode (Cundall local damping), which has no derivative
through this transient (its step jumps where a velocity changes sign; membrax.gradients): the gradient
printed is the derivative of the smooth pieces and means nothing. The smooth mode (``viscous_damping``)
runs the same kernels and the same work per step; its gradients are checked against central differences
in ``tests/test_gradients.py``.

Run: ``python benchmarks/bench_gradients.py [--size small|paper] [--stage shear|consolidation] [--steps 2000]
[--window 50] [--consolidation-steps 5000] [--step-remat auto|on|off] [--unroll 2]
[--dtypes float32,float64]``.
"""

import argparse
import json
import resource
import time

from harness import DTYPES, run_child

SIZES = {
    "small": {"particles_across": 6, "layers": 10, "membrane_edges_per_diameter": 3.0},
    "paper": {},
}


def rollout_functions(
    dtype: str,
    size: str,
    steps: int,
    window: int,
    stage: str,
    consolidation_steps: int,
    step_remat: str = "auto",
    unroll: int | None = None,
):
    """(forward, reverse, θ): y(θ) and (y, dy/dθ), both jitted, for the rollout described above.

    ``step_remat``: "auto" checkpoints each step inside the windows where the library does
    (:func:`membrax.gradients.checkpoint_window`: on a CPU's JAX path), "on" and "off" force it.
    ``unroll``: steps per iteration of the reverse pass's windows' loops (None: the library's default,
    :data:`membrax.gradients.UNROLL`; ≥ ``window``: whole windows, no loop); the forward's loops are
    unrolled by that default whatever it is, as :attr:`membrax.gradients.Rollout.forward`'s.

    Sets ``jax_enable_x64`` for float64, so call it once per process. Shared with ``profile_gradients.py``.
    """
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax.assemble import build_test
    from membrax.config import TriaxialConfig
    from membrax.gradients import UNROLL, checkpoint_window
    from membrax.sensitivities import apply_parameters

    config = TriaxialConfig(**SIZES[size], cell_pressure_kpa=10.0, membrane_thickness_mm=5.0)
    test = build_test(config)
    state = test.start_consolidation(test.initial_state)
    step = test.make_step(test.mesh)
    base = test.params
    if stage == "shear":  # consolidate forward (not timed), then shear from there
        state = jax.jit(lambda s: jax.lax.fori_loop(0, consolidation_steps, lambda _, x: step(x, base), s))(
            state
        )
        state = test.start_shear(
            state, config.inertial_number, config.shear_ramp_strain, config.symmetric_loading
        )
    record = test.make_record(test.mesh, test.initial_volume)  # (areas from the as-built size: cost only)

    # The library's windows (membrax.gradients.checkpoint_window: steps rematerialised as it chooses) for
    # both passes, each unrolled as the library's rollouts do: without differentiation a checkpoint is
    # the plain loop, so the forward is the program Rollout.forward runs, and the reverse Rollout's.
    remat = {"auto": None, "on": True, "off": False}[step_remat]
    float_dtype = test.mesh.reference_position.dtype

    def output(theta, unroll):  # θ = (E_m, σc) in kPa; σc also sets the servo target (consolidation)
        run = checkpoint_window(step, window, float_dtype, remat, unroll)
        values = {"membrane_modulus_kpa": theta[0], "cell_pressure_kpa": theta[1]}
        params, _, start = apply_parameters(values, base, test.mesh, state)
        final, _ = jax.lax.scan(lambda s, _: (run(s, params), None), start, None, length=steps // window)
        return record(final, params).internal_axial_stress[0]

    theta = jnp.asarray([config.membrane_modulus_kpa, config.cell_pressure_kpa])
    forward = jax.jit(lambda t: output(t, UNROLL))
    reverse = jax.jit(jax.value_and_grad(lambda t: output(t, UNROLL if unroll is None else unroll)))
    return forward, reverse, theta


def child(dtype: str, mode: str, **options) -> dict:
    """One pass (``mode``: forward or reverse) compiled, timed and measured; ``options``: the rollout's."""
    import jax

    forward, reverse, theta = rollout_functions(dtype, **options)
    function = forward if mode == "forward" else reverse
    start = time.perf_counter()
    function = function.lower(theta).compile()
    compile_s = time.perf_counter() - start
    # The program's own buffers (XLA's buffer assignment; constants such as the start state not counted):
    # what checkpointing trades against time, without the process's fixed ~1.2 GB that the RSS includes.
    buffers = function.memory_analysis()
    program_mb = (
        (buffers.temp_size_in_bytes + buffers.argument_size_in_bytes + buffers.output_size_in_bytes) / 2**20
        if buffers is not None
        else None
    )
    jax.block_until_ready(function(theta))
    runs = []
    for _ in range(3):
        start = time.perf_counter()
        out = jax.block_until_ready(function(theta))
        runs.append(time.perf_counter() - start)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    # An accelerator's own memory (None on a CPU, whose arrays the RSS above already counts).
    stats = jax.devices()[0].memory_stats() if jax.default_backend() != "cpu" else None
    value = out if mode == "forward" else out[0]
    return {
        "compile_s": compile_s,
        "run_s": min(runs),
        "peak_mb": peak_mb,
        "device_peak_mb": stats["peak_bytes_in_use"] / 2**20 if stats else None,
        "program_mb": program_mb,
        "backend": jax.default_backend(),
        "value": float(value),
        "gradient": None if mode == "forward" else [float(g) for g in out[1]],
    }


OPTIONS = ("size", "steps", "window", "stage", "consolidation_steps", "step_remat", "unroll")


def rollout_parser(steps: int) -> argparse.ArgumentParser:
    """The rollout's options (:data:`OPTIONS`, :func:`rollout_functions`' arguments); shared."""
    from membrax.gradients import UNROLL, WINDOW

    parser = argparse.ArgumentParser()
    parser.add_argument("--size", choices=tuple(SIZES), default="paper")
    parser.add_argument("--steps", type=int, default=steps)
    parser.add_argument("--window", type=int, default=WINDOW)
    parser.add_argument("--stage", choices=("shear", "consolidation"), default="shear")
    parser.add_argument("--consolidation-steps", type=int, default=5000)
    parser.add_argument(
        "--step-remat",
        choices=("auto", "on", "off"),
        default="auto",
        help="checkpoint each step inside the windows: auto = as membrax.gradients does (a CPU's JAX path)",
    )
    parser.add_argument(
        "--unroll",
        type=int,
        default=UNROLL,
        help="steps per iteration of the reverse pass's windows' loops; >= --window: whole windows, no loop",
    )
    return parser


def rollout_options(args: argparse.Namespace) -> dict:
    """:data:`OPTIONS` from parsed arguments, as keyword arguments of :func:`rollout_functions`."""
    return {name: getattr(args, name) for name in OPTIONS}


def main() -> None:
    parser = rollout_parser(steps=2000)
    parser.add_argument("--child", nargs=2, metavar=("DTYPE", "MODE"))
    parser.add_argument("--dtypes", default=",".join(DTYPES), help="comma-separated dtypes to run")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(*args.child, **rollout_options(args))))
        return
    print(
        f"gradient benchmark: {args.size} size, {args.stage}, {args.steps} steps, windows of {args.window} "
        f"(jax.checkpoint; steps rematerialised: {args.step_remat}; reverse windows unrolled: {args.unroll})"
        + (f", after {args.consolidation_steps} steps of consolidation" if args.stage == "shear" else "")
    )
    print(
        f"{'dtype':<8}{'fwd compile':>12}{'fwd run (s)':>12}{'rev compile':>12}{'rev run (s)':>12}"
        f"{'time ×':>8}{'fwd RSS MB':>11}{'rev RSS MB':>11}{'memory ×':>10}"
        f"{'fwd prog MB':>12}{'rev prog MB':>12}{'prog ×':>8}"
        f"{'fwd dev MB':>11}{'rev dev MB':>11}{'dev mem ×':>10}"
    )
    for dtype in args.dtypes.split(","):
        rows = {}
        for mode in ("forward", "reverse"):
            rows[mode] = run_child(__file__, [dtype, mode], rollout_options(args))
        forward, reverse = rows["forward"], rows["reverse"]
        print(
            f"{dtype:<8}{forward['compile_s']:>12.1f}{forward['run_s']:>12.2f}{reverse['compile_s']:>12.1f}"
            f"{reverse['run_s']:>12.2f}{reverse['run_s'] / forward['run_s']:>8.2f}{forward['peak_mb']:>11.0f}"
            f"{reverse['peak_mb']:>11.0f}{reverse['peak_mb'] / forward['peak_mb']:>10.2f}"
            f"{forward['program_mb']:>12.1f}{reverse['program_mb']:>12.1f}"
            f"{reverse['program_mb'] / forward['program_mb']:>8.2f}"
            + (
                f"{forward['device_peak_mb']:>11.0f}{reverse['device_peak_mb']:>11.0f}"
                f"{reverse['device_peak_mb'] / forward['device_peak_mb']:>10.2f}"
                if forward["device_peak_mb"]
                else f"{'-':>11}{'-':>11}{'-':>10}"
            )
        )


if __name__ == "__main__":
    main()
