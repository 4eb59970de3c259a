"""The steps compile once: traced parameters and stage controls change without a new trace.

The promises of :mod:`membrax.spheres.integrate` (``params`` traced), :mod:`membrax.membrane.coupled` (coupled
parameters traced) and :mod:`membrax.spheres.walls` (switching a stage never recompiles). A jitted function is
traced once per compilation, so a Python counter inside it counts compilations (optax's
``log_compilations`` test helper works the same way). The changed values must also change the numbers:
from rest, the first step gives a free membrane node the velocity Δt F/m with F ∝ p (Newton; no elastic or
contact force yet, and local damping needs a velocity), so ×4 on the cell pressure is ×4 on that speed.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tolerance

from membrax.spheres import fcc
from membrax.spheres.walls import set_control
from membrax.triaxial.membrane_cell import membrane_test
from membrax.triaxial.rigid import rigid_wall_test


def _counted(step_fn):
    traces = []

    def step(state, params):
        traces.append(1)
        return step_fn(state, params)

    return jax.jit(step), traces


@pytest.mark.slow
@pytest.mark.parametrize("float64", [True, False])
def test_the_coupled_step_compiles_once_for_new_parameters_and_stages(float64):
    with jax.enable_x64(float64):
        _coupled_step_compiles_once()


def _coupled_step_compiles_once():
    test = membrane_test(
        fcc.fcc_specimen(0.025, 4, 5),
        cell_pressure=1e4,
        membrane_thickness=5e-3,
        edges_per_diameter=2.5,
    )
    step, traces = _counted(test.runner.step_fn)
    state, params = test.initial_state, test.params
    base = step(state, params)
    membrane = params.membrane.set(
        cell_pressure=4.0 * params.membrane.cell_pressure, modulus=2.0 * params.membrane.modulus
    )
    contact = params.dem.contact.set(friction_coefficient=0.5 * params.dem.contact.friction_coefficient)
    harder = step(state, params.set(membrane=membrane, dem=params.dem.set(contact=contact)))
    walls = set_control(state.dem.walls, servo=False, velocity=-1e-3, target_stress=0.0, acceleration=1.0)
    step(state.set(dem=state.dem.set(walls=walls)), params)
    assert len(traces) == 1

    rings = np.concatenate([np.asarray(test.mesh.bottom_ring), np.asarray(test.mesh.top_ring)])
    free = np.setdiff1d(np.arange(state.membrane.position.shape[0]), rings)
    speed = [np.linalg.norm(np.asarray(s.membrane.velocity)[free], axis=1) for s in (base, harder)]
    assert np.all(speed[0] > 0.0)
    np.testing.assert_allclose(speed[1], 4.0 * speed[0], rtol=100 * tolerance(speed[0].dtype))


@pytest.mark.parametrize("members", [1, 3])
@pytest.mark.parametrize("float64", [True, False])
def test_the_rigid_wall_step_compiles_once_for_new_parameters_and_stages(members, float64):
    with jax.enable_x64(float64):
        _rigid_wall_step_compiles_once(members)


def _rigid_wall_step_compiles_once(members):
    pressure = 40e3 if members == 1 else jnp.asarray([10e3, 40e3, 100e3])
    test = rigid_wall_test(fcc.fcc_specimen(0.025, 3, 4), pressure, time_step=1e-5)
    step, traces = _counted(test.runner.step_fn)
    state, params = test.initial_state, test.params
    step(state, params)
    contact = params.contact.set(friction_coefficient=0.5 * params.contact.friction_coefficient)
    damping = jax.tree_util.tree_map(lambda x: 0.5 * x, params.damping)
    step(state, params.set(contact=contact, damping=damping))
    walls = set_control(state.walls, servo=True, velocity=0.0, target_stress=2.0 * test.cell_pressure)
    step(state.set(walls=walls), params)
    assert len(traces) == 1


def test_a_stage_s_last_shorter_chunk_runs_the_program_of_the_whole_ones_with_the_same_bits():
    """250 steps in chunks of 100 (records every 25) run as 100 + 100 + 50 steps, the last chunk the
    same compiled program as the others with its last two blocks skipped (:func:`membrax.driver.drive`'s
    ``whole_chunks``): one compilation, and the state and the 10 records of one 250-step chunk, to the bit
    (the same steps in the same order; a skipped block changes nothing)."""
    with jax.enable_x64(True):
        test = rigid_wall_test(fcc.fcc_specimen(0.025, 3, 4), 40e3, time_step=1e-5)
        state = test.start_consolidation(test.initial_state)
        chunked, chunked_records = test.runner.run(state, test.params, 250, chunk_steps=100, record_every=25)
        assert test.runner._chunk._cache_size() == 1
        whole, whole_records = test.runner.run(state, test.params, 250, chunk_steps=250, record_every=25)
    assert float(np.abs(np.asarray(chunked.velocity)).max()) > 0.0  # it moved
    for a, b in zip(
        jax.tree.leaves((chunked, chunked_records)), jax.tree.leaves((whole, whole_records)), strict=True
    ):
        np.testing.assert_array_equal(a, b)
    assert jax.tree.leaves(chunked_records)[0].shape[0] == 10


def test_phases_with_other_record_intervals_run_one_compiled_chunk_with_the_same_bits():
    """Two stages of 100 steps recorded every 25 and then every 50 steps (:func:`membrax.driver.run_phases`):
    the record interval is an argument of the chunk, not a constant, so both run one compiled program, and
    they take the same steps as one 200-step stage recorded every 25: the same final state and, in the
    second stage, every other of its records, to the bit."""
    from membrax.driver import run_phases

    with jax.enable_x64(True):
        test = rigid_wall_test(fcc.fcc_specimen(0.025, 3, 4), 40e3, time_step=1e-5)
        state = test.start_consolidation(test.initial_state)
        staged, staged_records = run_phases(test.runner, state, test.params, [(100, 25), (100, 50)], 100)
        assert test.runner._chunk._cache_size() == 1
        straight, straight_records = test.runner.run(
            state, test.params, 200, chunk_steps=100, record_every=25
        )
    assert float(np.abs(np.asarray(staged.velocity)).max()) > 0.0  # it moved
    for a, b in zip(jax.tree.leaves(staged), jax.tree.leaves(straight), strict=True):
        np.testing.assert_array_equal(a, b)
    # Records at steps 25, 50, 75, 100 (every 25), then 150, 200 (every 50).
    np.testing.assert_array_equal(np.ravel(staged_records.step), [25, 50, 75, 100, 150, 200])
    for a, b in zip(jax.tree.leaves(staged_records), jax.tree.leaves(straight_records), strict=True):
        np.testing.assert_array_equal(a, np.asarray(b)[[0, 1, 2, 3, 5, 7]])


def test_every_phase_of_a_batch_runs_one_compiled_chunk(tmp_path):
    """A periodic element (the smoke element: 64 spheres) through :func:`membrax.runner.run_group`'s three
    phases, each with its own record interval (consolidation, fine and coarse shearing), compiles its
    chunk once; every phase's records are spaced by that phase's own interval."""
    from helpers import SMALL_ELEMENT

    from membrax.assemble import precision_scope
    from membrax.config import TriaxialConfig
    from membrax.executor import build_periodic_batch
    from membrax.run_records import member_chunk_records
    from membrax.runner import run_group

    config = TriaxialConfig(name="one_chunk", **SMALL_ELEMENT)
    with precision_scope(config):
        batch = build_periodic_batch([config], num_devices=1)
        records, _, _ = run_group(batch, tmp_path, progress=False)
    plan = batch.tests[0].phase_plan(batch.settings[0].loading)
    assert len({every for steps, every in plan.values() if steps > 0}) > 1  # other intervals to share
    assert batch._chunk._cache_size() == 1
    mine = member_chunk_records(records, 0)
    for phase, (steps, every) in plan.items():
        if steps > 0:
            step = np.concatenate([np.asarray(chunk["step"]) for chunk in mine[phase]])
            np.testing.assert_array_equal(np.diff(step), every)
