"""One triaxial test from a configuration to a results folder, with checkpoints and resume.

Contract. :func:`run_test` takes a :class:`membrax.config.TriaxialConfig` and a folder and runs the paper's
protocol (:mod:`membrax.triaxial.membrane_cell`): stage 1, consolidation under the cell pressure until the
unbalanced-force ratio is below the tolerance and the ram stress equals σc; stage 2, drained shearing at
the strain rate of ``inertial_number`` to ``target_axial_strain``, recorded every ``record_every_fine``
steps below ``fine_until_strain`` and every ``record_every_coarse`` steps after. The folder receives:

- ``results.nc`` / ``results.csv``: the shearing records
  (:class:`membrax.membrane.records.MembraneMeasurements` plus the derived quantities of
  :func:`membrax.triaxial.analysis.derived_quantities`), the first one being the last consolidation record
  (the initial state of the paper's Table 3), with axial, radial and volumetric strain counted from the start
  of shearing (the paper's figures start at 0 %), the configuration, version, N, dt, step counts and timings
  as attributes;
- ``consolidation.nc`` / ``consolidation.csv``: the stage-1 records (strains from the built specimen);
- ``fig5_friction.png`` … ``fig8_radial_ratio.png`` (:func:`membrax.plots.save_test_figures`),
  ``summary.md`` (Table 2/3-style numbers beside the paper's for 10 kPa / 5 mm);
- ``config.toml`` (the configuration as run), ``checkpoint.npz`` (the last checkpoint), and, when
  ``vtk_every_steps`` > 0, VTK snapshots ``vtk/membrane_*.vtu`` and ``vtk/particles_*.vtu`` with
  ``.pvd`` indexes for ParaView.

Long runs. The test is a batch of one of :mod:`membrax.runner` (the loop every run and sweep shares): the
simulation advances in jitted chunks of ``chunk_steps``; a tqdm bar shows the phase, the axial strain and
the external and internal φ'. Every
``checkpoint_every_chunks`` chunks the state, the records so far and the position in the protocol are
written atomically (:func:`membrax.io.save_checkpoint`). ``resume=True`` continues from the checkpoint:
the remaining steps of the interrupted phase run in the same chunks as they would have uninterrupted, so
the results are identical. A non-finite state (the driver's error bits) or a runaway kinetic energy
(above :data:`membrax.runner.RUNAWAY_KINETIC_FRACTION` × σc V₀, the work scale of the cell pressure) stops
the run with :class:`RunError`, naming the step and what to change; the records so far are written first.

The periodic element. A configuration with ``cell = "periodic"`` runs the boundary-free element test of its
spheres instead (:func:`membrax.assemble.build_periodic_test`, :class:`membrax.triaxial.periodic.
PeriodicTest`): the same phases, the element a batch of one (:func:`membrax.executor.build_periodic_batch`)
through :func:`run_periodic_group`, the loop a sweep's periodic batches share, checkpointed every
``checkpoint_every_chunks`` chunks and at each phase's end (a resumed run takes the same chunks and writes
the same bits); error bits or a runaway kinetic energy (σc V₀ of the cell's first box the scale) stop it with
:class:`RunError` as a membrane run, and in a sweep freeze and flag the member instead. The folder
receives ``results.nc``/``.csv`` and ``consolidation.nc``/``.csv`` (the cell's records,
:class:`membrax.triaxial.periodic.CellRecords`, with ``time``, ``radial_strain`` and
``love_weber_friction_angle_deg``; the first shearing record the end of consolidation, strains from the
start of shearing), ``element.png`` (:func:`membrax.plots.save_element_figure`), ``summary.md``
(:func:`membrax.triaxial.analysis.element_summary_table`), ``config.toml`` and ``checkpoint.npz``.
"""

from __future__ import annotations

import dataclasses
import platform
import time
from pathlib import Path

import jax
import numpy as np

from membrax import __version__, plots, theory
from membrax.assemble import (
    build_test,
    consolidation_tolerance,
    precision_scope,
)
from membrax.config import TriaxialConfig, config_to_dict, dump_config_toml
from membrax.errors import RunError, SimulationError
from membrax.executor import PeriodicBatch, build_batch, build_periodic_batch
from membrax.io import (
    VTKSeries,
    dataset_attrs_to_python,
    load_checkpoint,
    read_checkpoint_host,
    records_to_dataset,
    save_checkpoint,
    write_results,
)
from membrax.membrane.measure import triangle_stretches
from membrax.paper import PAPER_10KPA_5MM, paper_key
from membrax.runner import (
    CHECKPOINT_NAME,
    join_records,
    member_chunk_records,
    phase_bar,
    records_from_host,
    records_to_host,
    results_datasets,
    run_group,
    run_metadata,
    stop_runaways,
)
from membrax.triaxial import analysis
from membrax.triaxial.membrane_cell import MembraneTest
from membrax.triaxial.protocol import PHASES

__all__ = [
    "CHECKPOINT_NAME",
    "RunResult",
    "build_test",
    "consolidation_tolerance",
    "default_folder",
    "figure_title",
    "periodic_datasets",
    "run_periodic_group",
    "run_test",
]


@dataclasses.dataclass
class RunResult:
    """What :func:`run_test` produced.

    Attributes:
      folder: the results folder.
      results: xarray.Dataset of the shearing records (stresses in Pa, strains as fractions, SI throughout;
        the columns of :class:`membrax.membrane.records.MembraneMeasurements`).
      consolidation: xarray.Dataset of the consolidation records, the same columns.
      summary: the Markdown summary (Table 2/3 numbers in kPa and degrees).
      files: {kind: path} of the files written.
      metadata: the run's provenance (configuration, version, steps, wall times in s).
    """

    folder: Path
    results: object  # xarray.Dataset of the shearing records
    consolidation: object  # xarray.Dataset of the consolidation records
    summary: str
    files: dict
    metadata: dict


def default_folder(config: TriaxialConfig, suffix: str = "") -> Path:
    """Where a run of ``config`` writes by default: ``results_<name><suffix>``."""
    return Path(f"results_{config.name}{suffix}")


def _vtk_snapshot(series, state, test: MembraneTest) -> None:
    nodes, spheres = state.membrane, state.dem
    largest, smallest = np.asarray(triangle_stretches(nodes.position, test.mesh))
    series.add(
        int(state.step),
        float(state.step) * test.dt,
        membrane=(
            np.asarray(nodes.position),
            np.asarray(test.mesh.triangles),
            {"force": np.asarray(nodes.node_force), "velocity": np.asarray(nodes.velocity)},
            {"stretch_largest": largest, "stretch_smallest": smallest},
        ),
        particles=(
            np.asarray(spheres.position),
            np.asarray(test.particles.radius),
            {"velocity": np.asarray(spheres.velocity), "membrane_force": np.asarray(nodes.sphere_force)},
        ),
    )


def run_test(
    config: TriaxialConfig,
    folder,
    resume: bool = False,
    progress: bool = True,
    interrupt_after_chunks: int | None = None,
    time_step: float | None = None,
    nodes_around: int | None = None,
) -> RunResult:
    """Run the test of ``config`` into ``folder`` (module docstring).

    Args:
      config: the configuration (validated on construction).
      folder: results folder (created).
      resume: continue from ``folder/checkpoint.npz`` instead of starting afresh.
      progress: show a tqdm progress bar.
      interrupt_after_chunks: testing aid: raise ``KeyboardInterrupt`` after this many chunks of this call
        (after any checkpoint of that chunk), as a killed process would stop.
      time_step: Δt, s, overriding the test's own (as a sweep's common Δt, :mod:`membrax.sweep`).
      nodes_around: membrane nodes per ring, overriding the mesh's own (as a sweep's common topology).

    Returns:
      A :class:`RunResult`.

    Raises:
      RunError: the simulation blew up (non-finite values or runaway kinetic energy).
      FileNotFoundError: ``resume`` without a checkpoint in ``folder``.
    """
    call_started = time.perf_counter()
    folder = Path(folder)
    if resume and not (folder / CHECKPOINT_NAME).exists():
        raise FileNotFoundError(
            f"no checkpoint at '{folder / CHECKPOINT_NAME}' to resume from; run without --resume to start "
            "afresh."
        )
    folder.mkdir(parents=True, exist_ok=True)
    if not resume:
        (folder / "config.toml").write_text(dump_config_toml(config))
    if config.cell == "periodic":
        return _run_periodic(config, folder, resume, progress, interrupt_after_chunks, call_started)
    # The configuration's precision, scoped to this call (thread-local).
    with precision_scope(config):
        started = time.perf_counter()
        # One member on one device: the loop of every run and sweep (membrax.runner).
        batch = build_batch([config], num_devices=1, time_step=time_step, nodes_around=nodes_around)
        test = batch.tests[0]
        build_seconds = time.perf_counter() - started
        resumed_from = (
            int(read_checkpoint_host(folder / CHECKPOINT_NAME)["member_steps"][0]) if resume else None
        )
        after_chunk = None
        if config.vtk_every_steps > 0:
            if resume:
                # Snapshots after the checkpoint's step are dropped: the resumed run writes them again.
                start = int(read_checkpoint_host(folder / CHECKPOINT_NAME)["member_steps"][0])
                series = VTKSeries(folder / "vtk", "specimen", resume_step=start)
            else:
                series = VTKSeries(folder / "vtk", "specimen")
                series.truncate_after(-1)
                state = batch.unstack(batch.initial_state)[0]
                _vtk_snapshot(series, state, test)
                start = int(state.step)
            last_step = [start]

            def after_chunk(states, _phase):
                step = int(np.asarray(states.dem.step)[0])
                if step // config.vtk_every_steps > last_step[0] // config.vtk_every_steps:
                    _vtk_snapshot(series, batch.unstack(states)[0], test)
                last_step[0] = step

        try:
            records, shear_start, elapsed = run_group(
                batch, folder, resume, progress, interrupt_after_chunks, after_chunk=after_chunk
            )
        except RunError as error:
            if error.records is not None:
                _write_partial(folder, member_chunk_records(error.records, 0), config)
            raise RunError(f"{error} Records so far are in {folder}.", error.records) from error
        mine = member_chunk_records(records, 0)
        return _finish(
            folder,
            config,
            test,
            run_metadata(batch.settings[0], test, mine, build_seconds, elapsed),
            mine,
            shear_start[0],
            elapsed,
            None if resumed_from is None else (resumed_from, time.perf_counter() - call_started),
        )


def _write_partial(folder, records, config) -> None:
    metadata = {"membrax_version": __version__, "config": config_to_dict(config), "partial": True}
    consolidation = join_records(records["consolidation"])
    if consolidation:
        write_results(records_to_dataset(consolidation, attrs=metadata), folder, "consolidation")
    shear = join_records(records["shear_fine"] + records["shear_coarse"])
    if shear:
        write_results(records_to_dataset(shear, attrs=metadata), folder, "results_partial")


def figure_title(config, metadata: dict) -> str:
    """A figure's line saying which test it is: the name, cell pressure, membrane and packing."""
    if config.packing == "fcc":
        packing = f"FCC {config.particles_across} × {config.layers}"
    else:
        mould = f"{config.specimen_diameter_mm:g} × {config.specimen_height_mm:g} mm"
        packing = f"random {mould}, seed {config.packing_seed}"
    return (
        f"{config.name}: σc {config.cell_pressure_kpa:g} kPa, membrane {config.membrane_thickness_mm:g} mm "
        f"of {config.membrane_modulus_kpa:g} kPa, {packing} ({metadata['num_particles']} spheres)"
    )


def _finish(folder, config, test, metadata, records, shear_start, elapsed, resumed=None) -> RunResult:
    """Write the results, figures and summary; ``resumed`` is (checkpoint step, this call's seconds)."""
    shear, consolidation = results_datasets(records, shear_start, metadata)
    files = {"consolidation": write_results(consolidation, folder, "consolidation")}
    files["results"] = write_results(shear, folder, "results")
    files["figures"] = plots.save_test_figures(shear, folder, title=figure_title(config, metadata))
    paper = (
        PAPER_10KPA_5MM
        if paper_key(config.cell_pressure_kpa, config.membrane_thickness_mm) == (10.0, 5.0)
        else None
    )
    summary = analysis.summary_table(shear, paper=paper)
    header = (
        f"# membrax {__version__}: {config.name}\n\n"
        f"{metadata['num_particles']} spheres, {metadata['num_membrane_nodes']} membrane nodes, "
        f"σc = {config.cell_pressure_kpa:g} kPa, t_m = {config.membrane_thickness_mm:g} mm, "
        f"E_m = {config.membrane_modulus_kpa:g} kPa, I = {config.inertial_number:g}, dt = {test.dt:.3g} s, "
        f"{metadata['consolidation_steps']} + {metadata['shear_steps']} steps in {elapsed:.0f} s"
        + (
            ""
            if resumed is None
            else f" in all (resumed from the checkpoint at step {resumed[0]}: this call {resumed[1]:.0f} s)"
        )
        + f" ({metadata['dtype']}, {metadata['jax_backend']}).\n\n"
    )
    summary = header + summary
    if paper is not None and config.packing != "fcc":
        summary += (
            "\nThe Paper column is the reference study's FCC lattice (10 × 25 uniform spheres), another "
            f"packing than this {config.packing} one: compare the trends, not the values.\n"
        )
    (folder / "summary.md").write_text(summary + "\n")
    files["summary"] = folder / "summary.md"
    return RunResult(folder, shear, consolidation, summary, files, metadata)


# ----------------------------------------------------------------------------------------------------------
# The periodic element test
# ----------------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _PeriodicGroup:
    """A batch of periodic elements in progress (:func:`run_periodic_group`): records, checkpoints, progress.

    ``records`` maps each phase of :data:`PHASES` to the chunks' stacked records ((B, T, ...) arrays and
    ``valid``, as :meth:`membrax.executor.StackedMembers.run_phase` hands them over); ``failures`` is the
    batch's (member → error, step, phase of the members frozen by ``isolate_failures``).
    """

    batch: PeriodicBatch
    path: Path
    progress: bool
    interrupt_after_chunks: int | None
    chunk_counter: list
    isolate_failures: bool = False
    records: dict = dataclasses.field(default_factory=lambda: {phase: [] for phase in PHASES})
    elapsed_before: float = 0.0
    started: float = dataclasses.field(default_factory=time.perf_counter)

    def __post_init__(self):
        self.batch.failures = {}
        # σc V₀ of each member: the runaway stop's scale (membrax.runner.stop_runaways).
        self.volume_work = np.array(
            [t.cell_pressure * float(np.prod(np.asarray(t.initial_state.length))) for t in self.batch.tests]
        )

    @property
    def failures(self) -> dict:
        return self.batch.failures

    def elapsed(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.started

    def save(self, states, phase_index: int, budgets) -> None:
        """Checkpoint: the states, their phase and budgets, the records so far, the lists' shape, failures."""
        host = {
            "phase": phase_index,
            # None at a phase's end: the next phase is entered (and its budgets planned) on resume.
            "budgets": None if budgets is None else [int(v) for v in budgets],
            "elapsed": self.elapsed(),
            "list_shape": self.batch.list_shape(states),
            "member_steps": [int(v) for v in np.asarray(states.step)[: self.batch.num_members]],
            "failures": {str(b): failure for b, failure in self.failures.items()},
            **records_to_host(self.records),
        }
        save_checkpoint(self.path, states, host)

    def restore(self):
        """(states, phase index, budgets or None) from the checkpoint, the records and failures put back."""
        saved = read_checkpoint_host(self.path)
        states, host = load_checkpoint(self.path, self.batch.template(saved["list_shape"]))
        self.elapsed_before = host["elapsed"]
        self.records.update(records_from_host(host))
        self.failures.update({int(b): failure for b, failure in host.get("failures", {}).items()})
        budgets = None if host["budgets"] is None else np.asarray(host["budgets"], dtype=np.int64)
        return states, host["phase"], budgets

    def run_phase(self, index: int, states, budgets, plans):
        """Phase ``index`` of :data:`PHASES` until every member's ``budgets`` is spent; returns the states."""
        batch, phase = self.batch, PHASES[index]
        settings = batch.settings[0]  # chunk steps, checkpoints: not batched fields
        record_every = plans[0][phase][1]
        total = int(np.ceil(np.max(budgets, initial=0) / record_every) * record_every)
        bar = phase_bar(phase, batch.num_members, total, self.progress)
        tolerances = [s.consolidation_tolerance for s in batch.settings]

        def consolidated(b, records):
            return phase == "consolidation" and batch.tests[b].is_consolidated(records, tolerances[b])

        def on_failure(b, names, step):
            self.failures[b] = {"error": names, "step": step, "phase": phase}

        def on_chunk(current, chunk, left):
            stop = stop_runaways(
                chunk,
                self.volume_work,
                self.failures,
                [s.name for s in batch.settings],
                np.asarray(current.step),
                settings.dt_safety,
                on_failure if self.isolate_failures else None,
            )
            self.records[phase].append(chunk)
            bar.update(chunk["valid"].shape[1] * record_every)
            ratio = chunk["unbalanced_force_ratio"][chunk["valid"]]
            bar.set_postfix(ufr=f"{np.max(ratio, initial=0.0):.1e}", active=int(np.sum(left > 0)))
            self.chunk_counter[0] += 1
            if self.chunk_counter[0] % settings.checkpoint_every_chunks == 0:
                left = left.copy()
                left[stop] = 0
                self.save(current, index, left)
            interrupt = self.interrupt_after_chunks
            if interrupt is not None and self.chunk_counter[0] >= interrupt:
                raise KeyboardInterrupt(f"interrupted after {self.chunk_counter[0]} chunks (testing aid)")
            return stop

        try:
            states, _ = batch.run_phase(
                states,
                budgets,
                settings.chunk_steps,
                record_every,
                stop_fn=consolidated,
                on_chunk=on_chunk,
                on_failure=on_failure if self.isolate_failures else None,
            )
        except SimulationError as error:
            hint = f"Lower dt_safety (now {settings.dt_safety}) or particle_stiffness_n_m."
            raise RunError(f"{error}. {hint}", self.records) from error
        except RunError as error:
            error.records = self.records
            raise
        finally:
            bar.close()
        return states


def run_periodic_group(
    batch: PeriodicBatch,
    folder: Path,
    resume: bool = False,
    progress: bool = True,
    interrupt_after_chunks: int | None = None,
    chunk_counter: list | None = None,
    isolate_failures: bool = False,
):
    """Run a batch of periodic elements through the phases of :data:`PHASES` (module docstring).

    Each phase is entered by every member's test (:meth:`~membrax.triaxial.protocol.StagedTest.start_phase`
    under its own loading, its budget from its own ``phase_plan``) and advanced by
    :meth:`membrax.executor.StackedMembers.run_phase` (the driver's loop: error bits, list growth, each
    member's consolidation stop test); after each chunk the runaway-energy stop
    (:func:`membrax.runner.stop_runaways`) as in a membrane run; every ``checkpoint_every_chunks`` chunks,
    and at each phase's end, the stacked states, the phase, the budgets, the failures and the records so
    far are saved, so a resumed run takes the same chunks as an uninterrupted one.

    Args:
      batch: from :func:`membrax.executor.build_periodic_batch`.
      folder: where ``checkpoint.npz`` is written (and read with ``resume``).
      resume: continue from the folder's checkpoint, if there is one.
      progress: a tqdm bar per phase.
      interrupt_after_chunks: testing aid: ``KeyboardInterrupt`` after this many chunks (counted in
        ``chunk_counter``, after that chunk's checkpoint).
      chunk_counter: a one-element list counting chunks across groups (default: this call's own).
      isolate_failures: a member that blows up (error bits other than a list overflow, or a runaway kinetic
        energy) is frozen at its last good records (its budget ends, the chunk runs again without it, it
        enters no later phase) and the others go on; ``batch.failures`` maps it to its error, step and
        phase (kept in checkpoints). False: the first raises.

    Returns:
      (records by phase: lists of chunk dicts of stacked (B, T, ...) arrays with ``valid``, as
      :func:`membrax.runner.member_chunk_records` takes them; the elapsed seconds).

    Raises:
      RunError: a member blew up (without ``isolate_failures``); ``error.records`` holds the records so far.
    """
    group = _PeriodicGroup(
        batch,
        folder / CHECKPOINT_NAME,
        progress,
        interrupt_after_chunks,
        chunk_counter or [0],
        isolate_failures,
    )
    plans = [t.phase_plan(s.loading) for t, s in zip(batch.tests, batch.settings, strict=True)]
    states, first, budgets = batch.initial_state, 0, None
    if resume and group.path.exists():
        states, first, budgets = group.restore()
    for index in range(first, len(PHASES)):
        phase = PHASES[index]
        if budgets is None:  # entering the phase (the first is entered by build_periodic_batch)
            if index > 0:
                members = batch.unstack(states)
                started = [
                    member if b in group.failures else test.start_phase(phase, member, s.loading)
                    for b, (member, test, s) in enumerate(
                        zip(members, batch.tests, batch.settings, strict=True)
                    )
                ]
                if any(new is not old for new, old in zip(started, members, strict=True)):
                    states = batch.restack(started)
            budgets = np.array([plan[phase][0] for plan in plans], dtype=np.int64)
            budgets[list(group.failures)] = 0  # a failed member stays frozen
        states = group.run_phase(index, states, budgets, plans)
        budgets = None
        group.save(states, index + 1, None)
    return group.records, group.elapsed()


def _run_periodic(config, folder: Path, resume, progress, interrupt_after_chunks, call_started) -> RunResult:
    """The periodic element test of ``config`` into ``folder`` (module docstring, "The periodic element").

    A batch of one (:func:`membrax.executor.build_periodic_batch` on one device) through
    :func:`run_periodic_group`, as a sweep's batches.
    """
    with precision_scope(config):
        started = time.perf_counter()
        batch = build_periodic_batch([config], num_devices=1)
        build_seconds = time.perf_counter() - started
        try:
            records, elapsed = run_periodic_group(batch, folder, resume, progress, interrupt_after_chunks)
        except RunError as error:
            _write_partial(folder, member_chunk_records(error.records, 0), config)
            raise RunError(f"{error} Records so far are in {folder}.", error.records) from error
        test = batch.tests[0]
        shear, consolidation = periodic_datasets(
            test, batch.settings[0], member_chunk_records(records, 0), build_seconds, elapsed
        )
        return _finish_periodic(folder, config, test, shear, consolidation, call_started, resume)


def periodic_datasets(test, settings, records, build_seconds, elapsed, **attrs):
    """(shear, consolidation) datasets of a periodic element from its records by phase.

    The cell's records (:class:`membrax.triaxial.periodic.CellRecords`) with ``time``, ``radial_strain``
    and ``love_weber_friction_angle_deg``; the end of consolidation is the shearing's first record, its
    strains counted from the shearing's box.

    Args:
      test: the member's :class:`~membrax.triaxial.periodic.PeriodicTest`.
      settings: its :class:`membrax.assemble.RunSettings`.
      records: its records by phase (:func:`membrax.runner.member_chunk_records`).
      build_seconds: the batch's build time, s.
      elapsed: the run's time, s.
      **attrs: further attributes (a sweep's batch size, status).

    A member frozen before its first record (``status`` failed) gets two datasets without records.
    """
    consolidation = join_records(records["consolidation"])
    shear = join_records(records["shear_fine"] + records["shear_coarse"])
    first = {name: values[-1:] for name, values in consolidation.items()}
    if first:
        first["axial_strain"] = np.zeros_like(first["axial_strain"])
        first["volumetric_strain"] = np.zeros_like(first["volumetric_strain"])
    shear = (
        {name: np.concatenate([first[name], values]) for name, values in shear.items()} if shear else first
    )
    # A member frozen in its first chunk (a sweep's failure isolation) has no records at all.
    for values in (consolidation, shear) if consolidation else ():
        values["time"] = values["step"] * test.dt
        values["love_weber_friction_angle_deg"] = analysis.friction_angle_deg(
            values["axial_stress"], values["lateral_stress"]
        )
        values["radial_strain"] = np.asarray(
            theory.radial_strain(values["axial_strain"], values["volumetric_strain"])
        )
    metadata = {
        "membrax_version": __version__,
        "config": settings.provenance,
        "cell": "periodic",
        "num_particles": int(test.particles.num_particles),
        "dt_s": test.dt,
        "consolidation_steps": int(consolidation["step"][-1]) if consolidation else 0,
        "consolidation_tolerance": settings.consolidation_tolerance,
        "shear_steps": int(shear["step"][-1] - consolidation["step"][-1]) if consolidation else 0,
        "build_s": build_seconds,
        "run_s": elapsed,
        "dtype": "float64" if settings.float64 else "float32",
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
        **attrs,
    }
    return records_to_dataset(shear, attrs=metadata), records_to_dataset(consolidation, attrs=metadata)


def _finish_periodic(folder, config, test, shear_data, consolidation_data, call_started, resumed):
    """Write a periodic run's results, figure and summary (module docstring)."""
    metadata = dataset_attrs_to_python(shear_data)
    files = {"consolidation": write_results(consolidation_data, folder, "consolidation")}
    files["results"] = write_results(shear_data, folder, "results")
    title = (
        f"{config.name}: periodic element of {metadata['num_particles']} spheres, "
        f"σc {config.cell_pressure_kpa:g} kPa, seed {config.packing_seed}"
    )
    files["figures"] = [plots.save_element_figure(shear_data, folder, title=title)]
    header = (
        f"# membrax {__version__}: {config.name}\n\n"
        f"Periodic element test: {metadata['num_particles']} spheres, σc = {config.cell_pressure_kpa:g} kPa, "
        f"I = {config.inertial_number:g}, dt = {test.dt:.3g} s, {metadata['consolidation_steps']} + "
        f"{metadata['shear_steps']} steps in {metadata['run_s']:.0f} s"
        + (f" in all (resumed: this call {time.perf_counter() - call_started:.0f} s)" if resumed else "")
        + f" ({metadata['dtype']}, {metadata['jax_backend']}).\n\n"
    )
    summary = header + analysis.element_summary_table(shear_data, config.cell_pressure)
    (folder / "summary.md").write_text(summary + "\n")
    files["summary"] = folder / "summary.md"
    return RunResult(folder, shear_data, consolidation_data, summary, files, metadata)
