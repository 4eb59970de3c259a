"""DEM speed and memory at paper size: one specimen, and a 9-case batch three ways.

Paper-size FCC specimen (25 mm spheres, 10 across, 25 layers: 1,816 spheres) in a rigid-wall cell with
servo walls (the rigid-wall triaxial reference), Cundall local damping, frictionless walls. For float32
and float64, each in a fresh process, prints:

- single specimen: compile time, steps/s and particle-steps/s of the jitted step (in a ``fori_loop``);
- 9 cases (φμ 15–35°, k_n 0.5–2 × 1e7 N/m, σc 10–100 kPa): 9 serial runs of the single-member step,
  one folded system of 9 × 1,816 spheres, ``lax.map`` and ``vmap`` over 9 stacked states (one compiled
  call each), as simulation steps per second (one batch step = 9 simulation steps);
- peak resident memory of the process.

Run: ``python benchmarks/bench_dem.py [--width 10 --layers 25 --steps 500]`` (≈ 4 minutes on 2 cores).
"""

import resource

from harness import benchmark_parser, benchmark_report, timed

CASES = 9


def measure(dtype: str, width: int, layers: int, steps: int) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from membrax import batch, native
    from membrax.spheres import contact, fcc, integrate
    from membrax.triaxial import rigid as triaxial

    specimen = fcc.fcc_specimen(0.025, width, layers)
    single = triaxial.rigid_wall_test(specimen, 40e3)
    state = single.set_walls(single.initial_state, True, 0.0, 40e3)
    _, step = integrate.sphere_dem(
        single.particles, single.runner.neighbor_frame, single.dt, wall_friction=False
    )

    def loop(step_fn, num):
        return jax.jit(  # compiled as membrax compiles a run's chunks
            lambda s, p: jax.lax.fori_loop(0, num, lambda _, x: step_fn(x, p), s),
            compiler_options=native.compiler_options(),
        )

    run = loop(step, steps)
    _, compile_and_run = timed(run, state, single.params)
    _, run_time = timed(run, state, single.params)
    result = {
        "dtype": dtype,
        "particles": specimen.num_particles,
        "pairs": int(state.neighbors.idx.shape[1]),
        "dt": single.dt,
        "compile_s": compile_and_run - run_time,
        "steps_per_s": steps / run_time,
        "particle_steps_per_s": steps * specimen.num_particles / run_time,
    }

    friction = np.linspace(15.0, 35.0, CASES)
    stiffness = np.tile([0.5e7, 1e7, 2e7], 3)
    pressure = np.repeat([10e3, 40e3, 100e3], 3)

    def case_params(b=None):
        pick = (lambda a: a) if b is None else (lambda a: a[b])
        return integrate.DEMParams(
            contact.ContactParams(
                normal_stiffness=jnp.asarray(pick(stiffness)),
                tangential_stiffness=jnp.asarray(0.5 * pick(stiffness)),
                friction_coefficient=jnp.tan(jnp.deg2rad(jnp.asarray(pick(friction)))),
                wall_normal_stiffness=jnp.asarray(1e7 * np.ones_like(pick(stiffness))),
                wall_tangential_stiffness=jnp.asarray(5e6 * np.ones_like(pick(stiffness))),
                wall_friction_coefficient=jnp.asarray(0.0 * np.ones_like(pick(stiffness))),
            ),
            integrate.DampingParams.local(0.3),
        )

    batch_steps = max(steps // 5, 20)
    serial_run = loop(step, batch_steps)
    states = [single.set_walls(single.initial_state, True, 0.0, pressure[b]) for b in range(CASES)]
    timed(serial_run, states[0], case_params(0))  # compile
    serial_time = sum(timed(serial_run, states[b], case_params(b))[1] for b in range(CASES))

    folded = triaxial.rigid_wall_test(specimen, pressure, time_step=single.dt)
    _, folded_step = integrate.sphere_dem(
        folded.particles, folded.runner.neighbor_frame, single.dt, wall_friction=False
    )
    folded_state = folded.set_walls(folded.initial_state, True, 0.0, pressure)
    folded_run = loop(folded_step, batch_steps)
    timed(folded_run, folded_state, case_params())
    _, folded_time = timed(folded_run, folded_state, case_params())

    stacked_state = batch.stack(states)
    stacked_params = batch.stack([case_params(b) for b in range(CASES)])
    vmap_run = jax.jit(
        batch.vmap_members(lambda s, p: jax.lax.fori_loop(0, batch_steps, lambda _, x: step(x, p), s)),
        compiler_options=native.compiler_options(),
    )
    timed(vmap_run, stacked_state, stacked_params)
    _, vmap_time = timed(vmap_run, stacked_state, stacked_params)

    mapped_run = jax.jit(
        batch.map_members(lambda s, p: jax.lax.fori_loop(0, batch_steps, lambda _, x: step(x, p), s)),
        compiler_options=native.compiler_options(),
    )
    timed(mapped_run, stacked_state, stacked_params)
    _, mapped_time = timed(mapped_run, stacked_state, stacked_params)

    simulation_steps = CASES * batch_steps
    result.update(
        {
            "serial_sim_steps_per_s": simulation_steps / serial_time,
            "folded_sim_steps_per_s": simulation_steps / folded_time,
            "vmap_sim_steps_per_s": simulation_steps / vmap_time,
            "map_sim_steps_per_s": simulation_steps / mapped_time,
            "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "device": jax.devices()[0].platform,
        }
    )
    return result


def main():
    parser = benchmark_parser(__doc__)
    parser.add_argument("--width", type=int, default=10)
    parser.add_argument("--layers", type=int, default=25)
    parser.add_argument("--steps", type=int, default=500)

    def caption(_, first):
        return (
            f"DEM benchmark: {first['particles']} spheres, {first['pairs']} pair slots, "
            f"dt = {first['dt']:.3e} s, "
            f"device {first['device']}, {CASES}-case batch"
        )

    rows = benchmark_report(
        __file__,
        parser,
        measure,
        caption,
        "compile s|steps/s|particle-steps/s|9 serial|folded|map|vmap|peak MB",
        "{compile_s:>10.1f}{steps_per_s:>9.0f}{particle_steps_per_s:>18.3e}{serial_sim_steps_per_s:>10.0f}"
        "{folded_sim_steps_per_s:>9.0f}{map_sim_steps_per_s:>8.0f}{vmap_sim_steps_per_s:>8.0f}{peak_memory_mb:>9.0f}",
    )
    if rows is None:
        return
    print("9 serial / folded / map / vmap: simulation steps per second over the 9 cases (higher is better).")


if __name__ == "__main__":
    main()
