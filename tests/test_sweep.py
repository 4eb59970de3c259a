"""Sweeps: a batch equals its members run alone, sharded equals unsharded, resume, the paper's trends."""

import dataclasses
import itertools
import json
import math
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SMALL_SPECIMEN

from membrax import assemble, executor, paper, planning, runner, sweep
from membrax.config import ConfigError, TriaxialConfig
from membrax.errors import RunError
from membrax.io import read_results
from membrax.io.checkpoint import read_checkpoint_host
from membrax.run import run_test
from membrax.spheres.particles import GRANITE_DENSITY

# Every test here runs a batched simulation (the module fixture alone takes about a minute).
pytestmark = pytest.mark.slow

BASE = dict(
    SMALL_SPECIMEN,
    name="sw",
    membrane_edges_per_diameter=5.0,  # the paper's D/5: at D/3 the 2.5 mm membrane misses the pressure trend
    inertial_number=5e-3,
    target_axial_strain=0.003,
    fine_until_strain=0.0015,
    shear_ramp_strain=5e-4,  # short: the tests look at the stages, not at the peak
    consolidation_max_steps=6000,
    chunk_steps=1000,
    record_every_fine=50,
    record_every_coarse=100,
    checkpoint_every_chunks=2,
)
GRID = {"cell_pressure_kpa": (10.0, 40.0), "membrane_thickness_mm": (2.5, 5.0)}
COMPARED = ("external_axial_stress", "internal_axial_stress", "internal_radial_stress", "volumetric_strain")


@pytest.fixture(scope="module")
def grid_sweep(tmp_path_factory):
    """The 2 × 2 grid (10, 40 kPa × 2.5, 5 mm) on a 4 × 4 × 5 specimen, one batch, to 0.4 % strain."""
    return sweep.run_sweep(
        TriaxialConfig(**BASE), GRID, tmp_path_factory.mktemp("sweep"), progress=False, num_devices=1
    )


def _serial(config, dataset, pressure, thickness, folder):
    point = dict(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness)
    member = sweep.member_records(dataset, **point)
    alone = run_test(
        config.__class__(**{**BASE, **point}),
        folder,
        progress=False,
        time_step=float(member["dt_s"]),
        nodes_around=int(member["nodes_around"]),
    )
    return member, alone


def test_a_batched_member_equals_the_same_test_run_alone(grid_sweep, tmp_path):
    """Each member of the batch takes the steps of its test run alone (same Δt and mesh topology).

    The member (10 kPa, 5 mm) is not the batch's first (10 kPa, 2.5 mm, whose mesh the batch's step is
    built around): its thickness enters as its own rest geometry in the shared topology, and it finishes
    consolidation at another step than some of the others. The batch is compiled differently (``lax.map`` over
    members), so the two agree to rounding at first, and the granular packing's chaos then amplifies the
    last bits (measured at 10 kPa: 1e-16 relative after 200 steps, ×2–10 per 100 steps after; faster at
    40 kPa): the first 300 steps agree to 1e-10, the end of consolidation (the paper's Table 3 state) to
    1e-3, and the step counts exactly.
    """
    pressure, thickness = 10.0, 5.0
    member, alone = _serial(TriaxialConfig(**BASE), grid_sweep.dataset, pressure, thickness, tmp_path)
    assert int(member["consolidation_steps"]) == alone.metadata["consolidation_steps"]
    assert int(member["shear_steps"]) == alone.metadata["shear_steps"]
    assert member.sizes["record"] == alone.results.sizes["record"]
    point = dict(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness)
    consolidation = sweep.member_records(grid_sweep.consolidation, **point)
    for name in COMPARED:
        ours, theirs = np.asarray(consolidation[name]), np.asarray(alone.consolidation[name])
        scale = np.max(np.abs(theirs))
        assert np.max(np.abs(ours[:3] - theirs[:3])) <= 1e-10 * scale, name
        assert abs(float(member[name][0]) - float(alone.results[name][0])) <= 1e-3 * scale, name


def test_members_finish_their_stages_at_their_own_steps(grid_sweep):
    """Consolidation ends per member (the stop test on each member's chunks), and each member shears
    for its own number of steps: at a fixed inertial number ε̇ = I/(d √(ρ/σc)) (GDR MiDi), so the steps
    to a strain ε are ε/(ε̇ Δt) rounded up to whole records, the fine phase ε_ramp/(ε̇ Δt) more for the
    ramp's delay, by hand below."""
    ds = grid_sweep.dataset
    steps = ds["consolidation_steps"].values
    assert len(set(steps.ravel().tolist())) > 1, steps  # members stopped consolidating at different steps
    assert np.all(steps % 1000 == 0)  # whole chunks, as alone
    for i, pressure in enumerate(GRID["cell_pressure_kpa"]):
        for j, _ in enumerate(GRID["membrane_thickness_mm"]):
            rate = BASE["inertial_number"] / (0.025 * math.sqrt(GRANITE_DENSITY / (1e3 * pressure)))
            per_strain = 1.0 / (rate * float(ds["dt_s"].values[i, j]))
            fine = math.ceil(math.ceil((0.0015 + 5e-4) * per_strain) / 50) * 50
            coarse = math.ceil(math.ceil(0.0015 * per_strain) / 100) * 100
            assert int(ds["shear_steps"].values[i, j]) == fine + coarse
    # σc × 4 → ε̇ × 2: the 40 kPa members take about half the shearing steps of the 10 kPa ones
    ratio = ds["shear_steps"].values[0] / ds["shear_steps"].values[1]
    assert np.all(np.abs(ratio - 2.0) < 0.2), ratio


def test_initial_membrane_stresses_follow_the_papers_trends(grid_sweep):
    """Paper §5.2 / Table 3: the initial additional membrane stresses (internal − external) grow with cell
    pressure and with membrane thickness, while their size relative to σc falls with cell pressure.

    Radial: internal σ3 over the cylinder through the boundary spheres' centres
    (:func:`membrax.paper.centre_cylinder_radial_stress`, the reading found to give the paper's
    Δσ3 ≈ 0.1 σc at paper size) minus σc. Over the platen's own cylinder (membrax's default internal σ3) the
    radial excess is the membrane's net radial load alone, hoop tension against indentation, and on this
    4 × 4 × 5 specimen it is −1.5 kPa at 40 kPa with the 2.5 mm membrane (paper size: −2.4 kPa at 100 kPa):
    a shortfall not explained yet, so it is not asserted here.
    """
    ds = grid_sweep.dataset.isel(record=0)
    pressure = 1e3 * ds["cell_pressure_kpa"].values[:, None]
    axial = (ds["internal_axial_stress"] - ds["external_axial_stress"]).values
    radius = TriaxialConfig(**BASE).particle_radius
    radial = np.empty_like(axial)
    for (i, p), (j, t) in itertools.product(*map(enumerate, GRID.values())):
        member = sweep.member_records(grid_sweep.dataset, cell_pressure_kpa=p, membrane_thickness_mm=t)
        radial[i, j] = 1e3 * paper.centre_cylinder_radial_stress(member, radius) - pressure[i, 0]
    for excess in (axial, radial):
        assert np.all(excess > 0), excess
        assert np.all(excess[1] > excess[0]), excess  # grows with pressure
        assert np.all(excess[:, 1] > excess[:, 0]), excess  # grows with thickness
        relative = excess / pressure
        assert np.all(relative[1] < relative[0]), relative  # relatively smaller at higher pressure


def test_the_sweep_dataset_is_written_with_the_grid_as_dimensions(grid_sweep):
    """sweep.nc reads back with the grid's dimensions and values, padding marked by num_records."""
    back = read_results(grid_sweep.files["sweep"])
    assert back["internal_axial_stress"].dims == ("cell_pressure_kpa", "membrane_thickness_mm", "record")
    np.testing.assert_array_equal(back["cell_pressure_kpa"].values, GRID["cell_pressure_kpa"])
    counts = back["num_records"].values
    for index in np.ndindex(counts.shape):
        series = back["internal_axial_stress"].values[index]
        assert np.all(np.isfinite(series[: counts[index]])) and np.all(np.isnan(series[counts[index] :]))
    np.testing.assert_allclose(
        back["sigma1_internal_kpa"].values, 1e-3 * back["internal_axial_stress"].values[..., 0], rtol=1e-12
    )


SHORT = dict(
    BASE,
    membrane_edges_per_diameter=2.5,
    consolidation_max_steps=1000,
    chunk_steps=500,
    target_axial_strain=0.002,
    fine_until_strain=0.001,
)
SHORT_GRID = {"cell_pressure_kpa": (10.0, 40.0), "membrane_thickness_mm": (5.0,)}


@pytest.fixture(scope="module")
def short_sweep(tmp_path_factory):
    """The short grid (10, 40 kPa in a 5 mm membrane) run at once, in process, on one device: the reference
    of the resumed, the sabotaged and the sharded sweeps below (each ran it itself before)."""
    return sweep.run_sweep(
        TriaxialConfig(**SHORT), SHORT_GRID, tmp_path_factory.mktemp("short"), progress=False, num_devices=1
    )


def test_an_interrupted_sweep_resumes_to_the_same_results(short_sweep, tmp_path):
    """A sweep killed after 2 chunks (a checkpoint every 2) and resumed ends identical to one run at once."""
    base = TriaxialConfig(**SHORT)
    whole = short_sweep
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep(
            base, SHORT_GRID, tmp_path / "cut", progress=False, num_devices=1, interrupt_after_chunks=3
        )
    resumed = sweep.run_sweep(base, SHORT_GRID, tmp_path / "cut", resume=True, progress=False, num_devices=1)
    for name in COMPARED:
        np.testing.assert_array_equal(resumed.dataset[name].values, whole.dataset[name].values)


SHARDED = textwrap.dedent(
    """
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    from membrax import sweep
    from membrax.config import TriaxialConfig
    base = TriaxialConfig(**json.loads(sys.argv[1]))
    grid = json.loads(sys.argv[2])
    sweep.run_sweep(base, grid, sys.argv[3], progress=False, num_devices=2)
    print(json.dumps({"devices": len(jax.devices())}))
    """
)


#: The operations by which one device waits for another inside a compiled program.
COLLECTIVES = ("all-reduce", "all-gather", "collective-permute", "all-to-all", "reduce-scatter")


def _difference(a, b, first=None):
    """The largest difference of the compared records of ``a`` and ``b`` (to record ``first``), relative to
    ``a``'s largest value."""
    return max(
        float(np.nanmax(np.abs(a[n].values[..., :first] - b[n].values[..., :first])))
        / float(np.nanmax(np.abs(a[n].values)))
        for n in COMPARED
    )


def test_two_devices_give_the_results_of_one(short_sweep, tmp_path):
    """The member axis sharded over 2 (virtual CPU) devices with shard_map gives the unsharded results, and no
    program the sweep compiles makes one device wait for the other (XLA ends the process when a
    device reaches a cross-device all-reduce 40 s after the other). Every compiled module is dumped and read:
    none holds a collective; the 10 kPa member shears twice as long as the 40 kPa one, so its device works
    alone in the last chunks, under a collective timeout cut to 1 s.

    The unsharded reference is the module's one-device sweep of the same grid, run in this process: on one
    device, the same programs whichever process compiles them (it was run a second time in the subprocess)."""
    dump = tmp_path / "hlo"
    flags = (
        "--xla_force_host_platform_device_count=2 --xla_cpu_collective_call_terminate_timeout_seconds=1 "
        f"--xla_dump_to={dump} --xla_dump_hlo_as_text --xla_dump_hlo_module_re=.*"
    )
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    done = subprocess.run(
        [sys.executable, "-c", SHARDED, json.dumps(SHORT), json.dumps(SHORT_GRID), str(tmp_path / "two")],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {"devices": 2}
    one, folder = short_sweep, tmp_path / "two"
    two, two_consolidation = (read_results(folder / f) for f in ("sweep.nc", "sweep_consolidation.nc"))
    np.testing.assert_array_equal(
        two["consolidation_steps"].values, one.dataset["consolidation_steps"].values
    )
    early = _difference(one.consolidation, two_consolidation, 5)
    assert early <= 1e-9, (early, _difference(one.dataset, two))
    compiled = sorted(dump.glob("*after_optimizations.txt"))
    assert any("_chunk_impl" in path.name for path in compiled)
    waiting = [
        path.name
        for path in compiled
        if any(
            f" {op}(" in text or f" {op}-start(" in text for text in [path.read_text()] for op in COLLECTIVES
        )
    ]
    assert not waiting, waiting


def test_members_are_dealt_to_devices_with_balanced_work():
    """Table 1's work per member (consolidation limit + shear steps ∝ 1/√σc) on 2 devices: the order's
    busiest device carries the least load any split into 5 + 4 members can (exhaustive search)."""
    steps_10, steps_40, steps_100 = 24150, 12200, 7775  # shear steps of the small reproduction
    work = [10000 + w for w in (steps_10,) * 3 + (steps_40,) * 3 + (steps_100,) * 3]
    order = planning.balanced_order(work, 2)
    assert sorted(order) == list(range(9))
    busiest = max(sum(work[i] for i in order[:5]), sum(work[i] for i in order[5:]))
    best = min(
        max(sum(work[i] for i in first), sum(work) - sum(work[i] for i in first))
        for first in itertools.combinations(range(9), 5)
    )
    assert busiest == best == 112700  # 2 × 34150 + 2 × 22200 on the device with 4 members
    assert max(sum(work[:5]), sum(work[5:])) == 146850  # grid order: all three 10 kPa members on one device
    assert planning.balanced_order(work, 1) == list(range(9))


def test_grids_are_parsed_and_checked():
    """--grid items become the members in row-major order; bad items name the problem."""
    grid = sweep.parse_grid(["cell_pressure_kpa=10,40,100", "membrane_thickness_mm=2.5, 5"])
    coordinates, members = assemble.grid_members(TriaxialConfig(**BASE), grid)
    assert coordinates == {"cell_pressure_kpa": (10.0, 40.0, 100.0), "membrane_thickness_mm": (2.5, 5.0)}
    assert len(members) == 6
    assert members[1][0] == (0, 1) and members[1][1].cell_pressure_kpa == 10.0
    assert members[1][1].membrane_thickness_mm == 5.0 and members[1][1].name == "sw_1"
    for items, message in (
        (["cell_pressure_kpa"], "FIELD=V1"),
        (["cell_pressure_kpa=10", "cell_pressure_kpa=40"], "twice"),
        (["cell_pressure_kpa="], "FIELD=V1"),
    ):
        with pytest.raises(ConfigError, match=message):
            sweep.parse_grid(items)
    with pytest.raises(ConfigError, match="not a simulation field"):
        assemble.grid_members(TriaxialConfig(**BASE), {"cell_presure_kpa": (10.0,)})
    with pytest.raises(ConfigError, match="cell_pressure_kpa"):
        assemble.grid_members(TriaxialConfig(**BASE), {"cell_pressure_kpa": (-5.0,)})
    with pytest.raises(ConfigError, match="repeats"):
        assemble.grid_members(TriaxialConfig(**BASE), sweep.parse_grid(["cell_pressure_kpa=10,10.0"]))
    with pytest.raises(ValueError, match="layers"):
        executor.build_batch([TriaxialConfig(**BASE), TriaxialConfig(**dict(BASE, layers=6))])


def test_the_sweep_command_reports_a_bad_grid(tmp_path, capsys):
    """``membrax sweep`` exits with 2 and names the fix for a malformed --grid or an unknown field."""
    from membrax import cli
    from membrax.config import dump_config_toml

    path = tmp_path / "base.toml"
    path.write_text(dump_config_toml(TriaxialConfig(**BASE)))
    assert cli.main(["sweep", str(path), "--grid", "cell_pressure_kpa", "--no-progress"]) == 2
    assert "FIELD=V1" in capsys.readouterr().err
    assert cli.main(["sweep", str(path), "--grid", "cell_presure_kpa=10,40", "--no-progress"]) == 2
    assert "not a simulation field" in capsys.readouterr().err
    assert cli.main(["sweep", str(path), "--devices", "0", "--no-progress"]) == 2
    assert "at least 1 CPU device" in capsys.readouterr().err


SPLIT = textwrap.dedent(
    """
    import json, warnings
    import jax
    from membrax.devices import split_cpu_devices
    made = split_cpu_devices(3)
    from membrax import sweep  # imports jax_md, which starts the backend
    count = jax.local_device_count("cpu")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        late = split_cpu_devices(2)
    print(json.dumps({"made": made, "count": count, "late": late, "warned": len(caught)}))
    """
)


def test_the_cpu_splits_into_one_device_per_core_before_jax_starts():
    """split_cpu_devices(3) before JAX starts gives 3 CPU devices; afterwards it keeps 3 and warns."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env.pop("XLA_FLAGS", None)
    done = subprocess.run([sys.executable, "-c", SPLIT], env=env, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {"made": 3, "count": 3, "late": 3, "warned": 1}


@pytest.mark.slow
def test_a_member_that_blows_up_is_frozen_and_flagged_and_the_others_are_unchanged(
    short_sweep, tmp_path, monkeypatch
):
    """Failure isolation: the 100 kPa member's sphere stiffness raised 1e6-fold (the batch's Δt then far past
    its stable step, a test-only sabotage) goes non-finite in its first chunk. It is flagged with the error,
    the phase and the step; the 10 and 40 kPa members of the same batch end bitwise equal to a sweep of them
    alone; the sweep returns, and the same sweep killed after 3 chunks and resumed ends the same."""
    base = TriaxialConfig(**SHORT)
    grid = {"cell_pressure_kpa": (10.0, 40.0, 100.0), "membrane_thickness_mm": (5.0,)}
    build = sweep.build_batch

    def sabotaged(configs, *args, **kwargs):
        batch = build(configs, *args, **kwargs)
        bad = [t.cell_pressure for t in batch.tests].index(1e5)
        contact = batch.params.dem.contact
        stiffness = np.asarray(contact.normal_stiffness).copy()
        stiffness[bad] *= 1e6
        contact = contact.set(normal_stiffness=jnp.asarray(stiffness))
        batch.params = batch.params.set(dem=batch.params.dem.set(contact=contact))
        return batch

    monkeypatch.setattr(sweep, "build_batch", sabotaged)
    with pytest.warns(UserWarning, match="1 of 3 members failed"):
        mixed = sweep.run_sweep(base, grid, tmp_path / "mixed", progress=False, num_devices=1)
        # Killed after 3 chunks and resumed: the failure is kept in the checkpoint, the results the same.
        with pytest.raises(KeyboardInterrupt):
            sweep.run_sweep(
                base, grid, tmp_path / "cut", progress=False, num_devices=1, interrupt_after_chunks=3
            )
        resumed = sweep.run_sweep(base, grid, tmp_path / "cut", resume=True, progress=False, num_devices=1)
    np.testing.assert_array_equal(resumed.dataset["status"].values, mixed.dataset["status"].values)
    for name in COMPARED:
        np.testing.assert_array_equal(resumed.dataset[name].values, mixed.dataset[name].values)
    alone = short_sweep  # the same base, the grid without the 100 kPa member, unsabotaged
    assert SHORT_GRID == {**grid, "cell_pressure_kpa": (10.0, 40.0)}
    status = mixed.dataset["status"].values[:, 0]
    assert list(status[:2]) == ["completed", "completed"]
    # Its spheres go non-finite or leave the neighbour box within its first chunk of 500 steps.
    assert status[2].startswith("failed: ") and status[2].endswith(
        " in consolidation (chunk ending at step 500)"
    )
    assert set(status[2].split()[1].split("|")) <= {"NOT_FINITE", "OUTSIDE_BOX"}, status[2]
    assert str(read_results(tmp_path / "mixed" / "sweep.nc")["status"].values[2, 0]) == status[2]
    assert np.all(np.isnan(mixed.dataset["peak_external_friction_angle_deg"].values[2]))
    for name in COMPARED:
        np.testing.assert_array_equal(mixed.dataset[name].values[:2], alone.dataset[name].values)
    summary = (tmp_path / "mixed" / "summary.csv").read_text().splitlines()
    assert summary[0].endswith(",status") and summary[3].endswith(json.dumps(str(status[2])))


def test_a_runaway_kinetic_energy_freezes_the_member_and_a_sweep_of_only_runaways_fails(
    tmp_path, monkeypatch
):
    """The kinetic-energy guard (E_k > f σc V₀ after a chunk) with its fraction f set to 0, so every member
    trips it in its first chunk: each is frozen before that chunk's records and named with
    RUNAWAY_KINETIC_ENERGY, its phase and step; with no member left the sweep raises, listing both. A
    single test (run_test, no isolation) stops with the energy and the bound in the message."""
    monkeypatch.setattr(runner, "RUNAWAY_KINETIC_FRACTION", 0.0)
    base = TriaxialConfig(**SHORT)
    with pytest.raises(RunError, match="every member failed") as failed:
        sweep.run_sweep(base, SHORT_GRID, tmp_path / "sweep", progress=False, num_devices=1)
    lines = str(failed.value).splitlines()[1:]
    assert len(lines) == 2
    for line in lines:
        assert line.endswith(": RUNAWAY_KINETIC_ENERGY in consolidation (chunk ending at step 500)"), line
    for k in range(2):
        frozen = read_results(tmp_path / "sweep" / "groups" / "group_0" / f"consolidation_{k}.nc")
        assert frozen.sizes.get("record", 0) == 0  # the chunk that tripped the guard is not kept
    with pytest.raises(RunError, match=r"kinetic energy .* J exceeds 0\.0 σc V₀ = 0 J: the run is unstable"):
        run_test(base, tmp_path / "single", progress=False)
    # Checkpointed in the chunk that froze them, the members have no steps left there: resumed, they stay
    # frozen rather than run again.
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep(
            dataclasses.replace(base, checkpoint_every_chunks=1),
            SHORT_GRID,
            tmp_path / "cut",
            progress=False,
            num_devices=1,
            interrupt_after_chunks=1,
        )
    host = read_checkpoint_host(tmp_path / "cut" / "groups" / "group_0" / runner.CHECKPOINT_NAME)
    assert host["budgets"] == [0, 0] and sorted(host["failures"]) == ["0", "1"]
