"""Batched periodic elements against the same elements run one by one, the servo and the imposed strain.

A sweep of ``cell = "periodic"`` members of one packing runs them stacked in one compiled chunk
(:class:`membrax.executor.PeriodicBatch`). Each test checks a number: the batched members' records are those
of :func:`membrax.run.run_test` of each member alone (to the bit: one device, ``lax.map``, the same
arithmetic), each member's servo holds its own σc and its box shortens at its own imposed log strain rate;
an interrupted batch resumes to the same bits; a step under ``jit(vmap(...))`` is the single steps, and the
batch in ``vmap`` mode is the ``lax.map`` batch to round-off; lists grown together hold every member's pairs;
a member that blows up (error bits, runaway kinetic energy) is frozen and flagged while the others' records
stay those of the sweep without it, and a single element that blows up raises with its records.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SMALL_ELEMENT

from membrax.assemble import build_periodic_test, precision_scope, run_settings
from membrax.batch import stack
from membrax.config import TriaxialConfig, with_overrides
from membrax.driver import advance
from membrax.errors import RunError
from membrax.executor import PeriodicBatch, build_periodic_batch
from membrax.io import read_results
from membrax.run import run_test
from membrax.spheres.integrate import DampingParams
from membrax.sweep import _ELEMENT_SCALARS, run_sweep
from membrax.triaxial.periodic import periodic_test

DIAMETER = 0.025  # m, the equal spheres of the configuration's default grading
DENSITY = 2650.0  # kg/m³, the configuration's default
PRESSURES_KPA = (20.0, 40.0)
#: The small element (64 spheres, a short shear) in float64, two cell pressures.
BASE = TriaxialConfig(name="periodic_batch", float64=True, **SMALL_ELEMENT)
GRID = {"cell_pressure_kpa": list(PRESSURES_KPA)}
COMPARED = ("step", "stress", "axial_strain", "volumetric_strain", "length", "unbalanced_force_ratio")


@pytest.fixture(scope="module")
def batched(tmp_path_factory):
    """The two members as one batch (a sweep, one device: ``lax.map`` over the members)."""
    return run_sweep(BASE, GRID, tmp_path_factory.mktemp("batched"), progress=False, num_devices=1)


def test_a_batch_of_periodic_elements_is_its_members_run_one_by_one(batched, tmp_path):
    """Each member of the batch writes the records of its element run alone (run_test), to the bit: one
    packing and one list shape, the same step on one device (``lax.map`` runs each member's own program),
    and each member ends consolidation at its own step (its stop test). Each one's servo held its own σc:
    every σ_kk within 1 % at the end of consolidation; its box shortened at its own rate, ε̇ = I/(d √(ρ/σc))
    (GDR MiDi): ε_a = 1 − exp(−ε̇ t) to round-off, faster at 40 kPa than at 20 by √2. The sweep's layout is
    that of the element's (its scalars per member, ``summary.csv``'s columns)."""
    assert batched.dataset.attrs["groups"] == 1
    rates = []
    for pressure in PRESSURES_KPA:
        alone = run_test(
            with_overrides(BASE, cell_pressure_kpa=pressure), tmp_path / f"{pressure:g}", progress=False
        )
        member = batched.member(cell_pressure_kpa=pressure)
        for name in COMPARED:
            np.testing.assert_array_equal(member[name].values, alone.results[name].values, err_msg=name)
        consolidation = batched.consolidation.sel(cell_pressure_kpa=pressure)
        count = alone.consolidation.sizes["record"]
        np.testing.assert_array_equal(
            consolidation["stress"].values[:count], alone.consolidation["stress"].values
        )
        assert int(consolidation["num_records"]) == count
        start = np.diagonal(member["stress"].values[0])
        np.testing.assert_allclose(start, 1e3 * pressure, rtol=0.01)
        rate = 5e-3 / (DIAMETER * math.sqrt(DENSITY / (1e3 * pressure)))
        steps = member["step"].values - member["step"].values[0]
        # L_{n+1} = L_n (1 − ε̇ Δt) per step: the log strain ε̇ t, stepped.
        imposed = 1.0 - (1.0 - rate * alone.metadata["dt_s"]) ** steps
        np.testing.assert_allclose(member["axial_strain"].values, imposed, rtol=1e-9, atol=1e-15)
        rates.append(rate)
    assert rates[1] / rates[0] == pytest.approx(math.sqrt(2.0), rel=1e-12)
    steps = batched.dataset["shear_steps"].values
    assert steps[0] > steps[1]  # the slower member sheared for more steps
    for name in _ELEMENT_SCALARS:
        assert np.all(np.isfinite(batched.dataset[name].values)), name
    header = (batched.folder / "summary.csv").read_text().splitlines()[0].split(",")
    assert header == [
        "cell_pressure_kpa",
        "consolidation_steps",
        "shear_steps",
        "num_records",
        *_ELEMENT_SCALARS,
        "status",
    ]


def test_an_interrupted_batch_resumes_to_the_same_bits(batched, tmp_path):
    """The batch killed after 3 chunks (a consolidation chunk's checkpoint: stacked states, budgets, the
    lists' shape, the records so far) and resumed writes the records of the uninterrupted batch, to the
    bit, in both phases."""
    with pytest.raises(KeyboardInterrupt):
        run_sweep(BASE, GRID, tmp_path, progress=False, num_devices=1, interrupt_after_chunks=3)
    resumed = run_sweep(BASE, GRID, tmp_path, resume=True, progress=False, num_devices=1)
    for name in (*COMPARED, "num_records", "consolidation_steps", "shear_steps"):
        np.testing.assert_array_equal(
            resumed.dataset[name].values, batched.dataset[name].values, err_msg=name
        )
    np.testing.assert_array_equal(
        resumed.consolidation["stress"].values, batched.consolidation["stress"].values
    )


def test_the_batched_step_is_jit_of_vmap_of_the_cell_s_step():
    """The batch in ``vmap`` mode (the GPU's) advances the stacked members as ``jit(vmap(step))``: after one
    chunk of 300 steps (3 records) each member's stress is that of the single cell's ``jit`` of the same
    steps from its own state, to round-off (the vmapped reductions sum in another order: within 1e-10 of σc,
    measured 1e-12; viscous damping, since local damping's sign(u) flips on round-off where u ≈ 0 and
    would part the two at once); the ``lax.map`` batch too (a program compiled around ``lax.map`` and
    ``lax.cond`` may fuse the step's arithmetic otherwise than the bare ``jit``: 5e-12 of σc)."""
    configs = [with_overrides(BASE, cell_pressure_kpa=p, viscous_damping=True) for p in PRESSURES_KPA]
    with precision_scope(BASE):
        mapped = build_periodic_batch(configs, num_devices=1, mode="map", order=[0, 1])
        vmapped = build_periodic_batch(configs, num_devices=1, mode="vmap", order=[0, 1])
        left = jnp.full((2,), 300)
        ends = {}
        for label, batch in (("map", mapped), ("vmap", vmapped)):
            ends[label] = batch._chunk(
                batch.initial_state, batch.params, batch.members, left, 3, 100, slots=3
            )
        runner = mapped.tests[0].runner

        @jax.jit
        def single(state, params):
            return runner.record_fn(advance(runner.step_fn, state, params, 300), params)

        for b, state in enumerate(mapped.unstack(mapped.initial_state)):
            expected = np.asarray(single(state, mapped.tests[b].params).stress)
            for mode, end in ends.items():
                stress = np.asarray(end[2].stress)[b, -1]
                np.testing.assert_allclose(
                    stress, expected, rtol=0, atol=1e-10 * 1e3 * PRESSURES_KPA[b], err_msg=mode
                )
            assert int(np.asarray(ends["vmap"][0].error)[b]) == 0
        # The two members are apart: each servo works to its own target.
        stress = np.asarray(ends["map"][2].stress)[:, -1]
        assert not np.allclose(stress[0], stress[1], rtol=1e-3)


def test_a_member_in_error_is_frozen_and_its_neighbour_in_the_batch_goes_on_in_both_modes():
    """The executor's isolation on a PeriodicBatch: of two cells (20 and 40 kPa, viscous damping), the
    second starts with NaN velocities. One chunk of 300 steps sets its NOT_FINITE bit; ``on_failure`` names
    it with the chunk's end (step 300), its budget ends and the chunk runs again without it: it stays at its
    start (step 0), none of its records valid, while the first member's stress is that of the single cell's
    ``jit`` of the same steps, within 1e-10 of σc, under ``lax.map`` (the CPU's mode) and ``vmap`` (the
    GPU's: both branches run, the NaN member's discarded)."""
    configs = [with_overrides(BASE, cell_pressure_kpa=p, viscous_damping=True) for p in PRESSURES_KPA]
    with precision_scope(BASE):
        for mode in ("map", "vmap"):
            batch = build_periodic_batch(configs, num_devices=1, mode=mode, order=[0, 1])
            members = batch.unstack(batch.initial_state)
            healthy = members[0]
            members[1] = members[1].set(velocity=np.full_like(members[1].velocity, np.nan))
            failures, chunks = [], []

            def on_chunk(states, chunk, left, chunks=chunks):
                chunks.append(chunk)

            end, left = batch.run_phase(
                batch.restack(members),
                [300, 300],
                300,
                100,
                on_chunk=on_chunk,
                on_failure=lambda b, names, step, failures=failures: failures.append((b, names, step)),
            )
            assert failures == [(1, "NOT_FINITE", 300)], mode
            assert list(np.asarray(end.step)) == [300, 0] and list(left) == [0, 0]
            (chunk,) = chunks
            assert chunk["valid"][0].all() and not chunk["valid"][1].any()
            runner = batch.tests[0].runner
            expected = jax.jit(lambda s, p, r=runner: r.record_fn(advance(r.step_fn, s, p, 300), p))(
                healthy, batch.tests[0].params
            )
            np.testing.assert_allclose(
                chunk["stress"][0, -1], np.asarray(expected.stress), rtol=0, atol=1e-10 * 2e4, err_msg=mode
            )


def test_lists_grown_together_hold_every_member_s_pairs():
    """Two cells of one jittered 4³ lattice at 100 and 300 kPa whose lists are cut to 40 slots and rebuilt
    at the first step overflow; the batch grows both lists together (one shape, driver.grow_tables with the
    cell's allocate hook) from the chunk's start and reruns it, and each member ends where its cell run with
    an ample list ends (viscous damping: no sign flips on round-off; the rebuilt lists order the pairs
    otherwise, so to round-off)."""
    fraction = (np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) + 0.5) / 4
    fraction = (fraction + 0.03 * np.random.default_rng(0).uniform(-1, 1, fraction.shape) / 4) % 1.0
    length = np.full(3, 4 * 0.97 * DIAMETER)
    tests = [
        periodic_test(
            jnp.asarray(fraction),
            length,
            np.full(64, 0.5 * DIAMETER),
            p,
            damping=DampingParams.viscous(2000.0),
        )
        for p in (1e5, 3e5)
    ]
    settings = [run_settings(BASE)] * 2
    # Listed at twice the box: the first step rebuilds the list.
    states = [test.initial_state.set(list_length=2.0 * test.initial_state.length) for test in tests]
    template = tests[0].initial_state.neighbors
    short = template.set(idx=template.idx[:, :40], max_occupancy=40)
    cut = [s.set(neighbors=short, pair_spring=s.pair_spring[:40]) for s in states]
    batch = PeriodicBatch(
        settings=settings,
        tests=tests,
        dt=tests[0].dt,
        num_devices=1,
        mode="map",
        params=stack([t.params for t in tests]),
        members={},
        initial_state=stack(cut),
    )
    grown, left = batch.run_phase(batch.initial_state, [400, 400], 200, 100)
    assert batch.reallocations >= 1 and np.all(left == 0)
    assert grown.neighbors.idx.shape[-1] > 40
    # Each servo worked to its own target: the boxes parted.
    assert not np.allclose(np.asarray(grown.length[0]), np.asarray(grown.length[1]), rtol=1e-6)
    for b, (test, state) in enumerate(zip(tests, states, strict=True)):
        reference, _ = test.runner.run(state.set(neighbors=template), test.params, 400, 200, 100)
        box = float(test.initial_state.length[0])
        np.testing.assert_allclose(
            np.asarray(batch.unstack(grown)[b].position), np.asarray(reference.position), atol=1e-9 * box
        )


def _sabotaged_builder(monkeypatch, module, pressure_pa: float):
    """``module.build_periodic_batch`` whose member at ``pressure_pa`` starts shearing with NaN velocities
    (a test-only sabotage: its first shearing chunk goes non-finite)."""
    build = module.build_periodic_batch

    def sabotaged(configs, *args, **kwargs):
        batch = build(configs, *args, **kwargs)
        test = batch.tests[[t.cell_pressure for t in batch.tests].index(pressure_pa)]
        start_shear = test.start_shear

        def poisoned(state, *options, **named):
            state = start_shear(state, *options, **named)
            return state.set(velocity=jnp.full_like(state.velocity, jnp.nan))

        test.start_shear = poisoned
        return batch

    monkeypatch.setattr(module, "build_periodic_batch", sabotaged)


def test_a_periodic_member_that_blows_up_is_frozen_and_flagged_and_the_others_are_unchanged(
    batched, tmp_path, monkeypatch
):
    """Failure isolation of periodic elements: the 60 kPa member of a 20/40/60 kPa sweep starts shearing
    with NaN velocities (sabotage), so its first shearing chunk sets NOT_FINITE. It is frozen at its last
    good records and flagged with the error, the phase and the step: the chunk ending at the end of its
    consolidation plus one chunk (500 steps, or its whole fine phase rounded to records if shorter). Its
    consolidation is kept (every σ_kk within 1 % of 60 kPa at its end), no shearing record. The 20 and 40
    kPa members end bitwise equal to the sweep of them alone; the same sweep killed after 3 chunks and
    resumed (the failure kept in the checkpoint) ends the same."""
    from membrax import sweep

    _sabotaged_builder(monkeypatch, sweep, 6e4)
    grid = {"cell_pressure_kpa": [*PRESSURES_KPA, 60.0]}
    with pytest.warns(UserWarning, match="1 of 3 members failed"):
        mixed = run_sweep(BASE, grid, tmp_path / "mixed", progress=False, num_devices=1)
        with pytest.raises(KeyboardInterrupt):
            run_sweep(BASE, grid, tmp_path / "cut", progress=False, num_devices=1, interrupt_after_chunks=3)
        resumed = run_sweep(BASE, grid, tmp_path / "cut", resume=True, progress=False, num_devices=1)
    status = [str(value) for value in mixed.dataset["status"].values]
    assert status[:2] == ["completed", "completed"]
    np.testing.assert_array_equal(resumed.dataset["status"].values, mixed.dataset["status"].values)
    for name in (*COMPARED, "num_records", "consolidation_steps", "shear_steps"):
        np.testing.assert_array_equal(
            mixed.dataset[name].values[:2], batched.dataset[name].values, err_msg=name
        )
        np.testing.assert_array_equal(resumed.dataset[name].values, mixed.dataset[name].values, err_msg=name)
    assert np.all(np.isnan(mixed.dataset["peak_friction_angle_deg"].values[2]))
    # The frozen member's records, in its group's folder: consolidation complete, then nothing.
    group = tmp_path / "mixed" / "groups" / "group_0"
    k = json.loads((group / "members.json").read_text()).index(2)
    consolidation = read_results(group / f"consolidation_{k}.nc")
    np.testing.assert_allclose(np.diagonal(consolidation["stress"].values[-1]), 6e4, rtol=0.01)
    last = int(consolidation["step"].values[-1])
    config = with_overrides(BASE, cell_pressure_kpa=60.0)
    with precision_scope(config):
        fine, every = build_periodic_test(config).phase_plan(run_settings(config).loading)["shear_fine"]
    chunk = min(BASE.chunk_steps, every * math.ceil(fine / every))
    assert status[2] == f"failed: NOT_FINITE in shear_fine (chunk ending at step {last + chunk})"
    shear = read_results(group / f"shear_{k}.nc")
    np.testing.assert_array_equal(shear["step"].values, [last])  # the end of consolidation only
    assert (tmp_path / "mixed" / "summary.csv").read_text().splitlines()[3].endswith(json.dumps(status[2]))


def test_a_single_periodic_run_that_blows_up_raises_with_its_records(tmp_path, monkeypatch):
    """``run_test`` of one periodic element (a batch of one, no isolation) that goes non-finite in its
    first shearing chunk raises a RunError naming the member, the step and the bit's message, with the
    hint, and keeps its consolidation records in the folder (every σ_kk within 1 % of σc at the end)."""
    from membrax import run

    _sabotaged_builder(monkeypatch, run, 4e4)
    stopped = r"member 0 \(periodic_batch\) stopped in the chunk ending at step"
    with pytest.raises(RunError, match=stopped) as raised:
        run_test(BASE, tmp_path, progress=False)
    assert "non-finite position or velocity" in str(raised.value)
    assert "Lower dt_safety" in str(raised.value)
    consolidation = read_results(tmp_path / "consolidation.nc")
    np.testing.assert_allclose(np.diagonal(consolidation["stress"].values[-1]), 4e4, rtol=0.01)


def test_a_runaway_periodic_member_is_frozen_and_a_sweep_of_only_runaways_fails(tmp_path, monkeypatch):
    """The kinetic-energy guard of the membrane cell (E_k > f σc V₀ after a chunk, V₀ the cell's volume)
    guards the periodic elements too: with f = 0 every member trips it in its first chunk, each is frozen
    before that chunk's records and named with RUNAWAY_KINETIC_ENERGY, its phase and step; with no member
    left the sweep raises, listing both."""
    from membrax import runner

    monkeypatch.setattr(runner, "RUNAWAY_KINETIC_FRACTION", 0.0)
    with pytest.raises(RunError, match="every member failed") as failed:
        run_sweep(BASE, GRID, tmp_path, progress=False, num_devices=1)
    lines = str(failed.value).splitlines()[1:]
    assert len(lines) == 2
    for line in lines:  # the cell's steps count from 0 at the start of consolidation
        expected = f": RUNAWAY_KINETIC_ENERGY in consolidation (chunk ending at step {BASE.chunk_steps})"
        assert line.endswith(expected), line
    for k in range(2):
        frozen = read_results(tmp_path / "groups" / "group_0" / f"consolidation_{k}.nc")
        assert frozen.sizes.get("record", 0) == 0  # the chunk that tripped the guard is not kept
