"""Throughput of the closed-form theory on large batches (float32 and float64).

Prints, per dtype: compile time and evaluations per second of a jitted function that applies the
right-cylinder membrane correction and computes the corrected φ' for N (axial strain, volumetric strain,
cell pressure) triples. Run: ``python benchmarks/bench_theory.py [N]``.
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from membrax import theory


def corrected_friction_angle(axial_strain, volumetric_strain, cell_pressure, sigma_1):
    correction = theory.right_cylinder_shell_correction(1.4e6, 0.005, 0.25, axial_strain, volumetric_strain)
    corrected = theory.apply_membrane_correction(sigma_1, cell_pressure, correction)
    return theory.mobilised_friction_angle_deg(*corrected)


def run(dtype, n):
    rng = np.random.default_rng(0)
    args = [
        jnp.asarray(rng.uniform(0.0, 0.1, n), dtype=dtype),
        jnp.asarray(rng.uniform(-0.05, 0.02, n), dtype=dtype),
        jnp.asarray(rng.uniform(1e4, 1e5, n), dtype=dtype),
        jnp.asarray(rng.uniform(5e4, 5e5, n), dtype=dtype),
    ]
    function = jax.jit(corrected_friction_angle)
    start = time.perf_counter()
    function(*args).block_until_ready()
    compile_s = time.perf_counter() - start
    repeats = 20
    start = time.perf_counter()
    for _ in range(repeats):
        out = function(*args)
    out.block_until_ready()
    per_call = (time.perf_counter() - start) / repeats
    return compile_s, n / per_call


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    print(f"theory benchmark, N = {n:,}, device = {jax.devices()[0].platform}")
    print(f"{'dtype':<8}{'compile (s)':>12}{'evals/s':>14}")
    for name, dtype in (("float32", jnp.float32), ("float64", jnp.float64)):
        if name == "float64":
            jax.config.update("jax_enable_x64", True)
        compile_s, rate = run(dtype, n)
        print(f"{name:<8}{compile_s:>12.3f}{rate:>14.3e}")
