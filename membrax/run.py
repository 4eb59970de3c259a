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
PeriodicTest`): the same phases, one cell through its chunk runner, checkpointed every
``checkpoint_every_chunks`` chunks and at each phase's end (a resumed run takes the same chunks and writes
the same bits). The folder receives ``results.nc``/``.csv`` and ``consolidation.nc``/``.csv`` (the cell's
records, :class:`membrax.triaxial.periodic.CellRecords`, with ``time``, ``radial_strain`` and
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
    build_periodic_test,
    build_test,
    consolidation_tolerance,
    loading,
    precision_scope,
)
from membrax.config import TriaxialConfig, config_to_dict, dump_config_toml
from membrax.errors import RunError, SimulationError
from membrax.executor import build_batch
from membrax.io import (
    VTKSeries,
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
    results_datasets,
    run_group,
    run_metadata,
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
    "run_test",
    "figure_title",
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


def _periodic_records(records) -> dict:
    """A chunk's :class:`~membrax.triaxial.periodic.CellRecords` as a dict of numpy arrays."""
    return {field.name: np.asarray(getattr(records, field.name)) for field in dataclasses.fields(records)}


@dataclasses.dataclass
class _PeriodicRun:
    """A periodic element run in progress (:func:`_run_periodic`): records by phase, checkpoints, progress."""

    config: TriaxialConfig
    test: object  # membrax.triaxial.periodic.PeriodicTest
    path: Path
    progress: bool
    interrupt_after_chunks: int | None
    parts: dict = dataclasses.field(default_factory=lambda: {phase: [] for phase in PHASES})
    chunks: int = 0
    elapsed_before: float = 0.0
    started: float = dataclasses.field(default_factory=time.perf_counter)

    def elapsed(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.started

    def save(self, state, phase_index: int, phase_steps: int) -> None:
        """Checkpoint: the state, its place in :data:`PHASES`, the records so far and the list's shape."""
        host = {
            "phase": phase_index,
            "phase_steps": phase_steps,
            "elapsed": self.elapsed(),
            "list_shape": self.test.list_shape(state),
            "record_phases": [phase for phase in PHASES if self.parts[phase]],
        }
        for phase in host["record_phases"]:
            for name, values in join_records(self.parts[phase]).items():
                host[f"{phase}__{name}"] = values
        save_checkpoint(self.path, state, host)

    def restore(self):
        """(state, phase index, steps done in it) from the checkpoint, the records so far put back."""
        saved = read_checkpoint_host(self.path)
        state, host = load_checkpoint(self.path, self.test.template(**saved["list_shape"]))
        self.elapsed_before = host["elapsed"]
        for phase in host["record_phases"]:
            names = [key.split("__", 1)[1] for key in host if key.startswith(f"{phase}__")]
            self.parts[phase].append({name: np.asarray(host[f"{phase}__{name}"]) for name in names})
        return state, host["phase"], host["phase_steps"]

    def run_phase(self, index: int, state, phase_steps: int, steps: int, record_every: int, tolerance: float):
        """Phase ``index`` of :data:`PHASES` from ``phase_steps`` of its ``steps`` on; returns the state."""
        from tqdm.auto import tqdm

        phase = PHASES[index]
        bar = tqdm(
            total=None if phase == "consolidation" else steps,
            initial=phase_steps,
            desc=phase,
            unit="step",
            disable=not self.progress or steps == 0,
            leave=False,
        )
        done_steps = [phase_steps]

        def consolidated(_, records):
            return phase == "consolidation" and self.test.is_consolidated(records, tolerance)

        def on_chunk(new, records):
            mine = _periodic_records(records)
            self.parts[phase].append(mine)
            self.chunks += 1
            done_steps[0] += len(mine["step"]) * record_every
            bar.update(len(mine["step"]) * record_every)
            bar.set_postfix(
                strain=f"{mine['axial_strain'][-1]:.4f}", ufr=f"{mine['unbalanced_force_ratio'][-1]:.1e}"
            )
            finished = done_steps[0] >= steps or consolidated(new, records)
            if finished or self.chunks % self.config.checkpoint_every_chunks == 0:
                self.save(new, *((index + 1, 0) if finished else (index, done_steps[0])))
            if self.interrupt_after_chunks is not None and self.chunks >= self.interrupt_after_chunks:
                raise KeyboardInterrupt(f"interrupted after {self.chunks} chunks (interrupt_after_chunks)")

        try:
            state, _ = self.test.runner.run(
                state,
                self.test.params,
                steps - phase_steps,
                self.config.chunk_steps,
                record_every,
                stop_fn=consolidated,
                on_chunk=on_chunk,
            )
        finally:
            bar.close()
        return state


def _run_periodic(config, folder: Path, resume, progress, interrupt_after_chunks, call_started) -> RunResult:
    """The periodic element test of ``config`` into ``folder`` (module docstring, "The periodic element").

    The phases of :data:`membrax.triaxial.protocol.PHASES` run one after another on one cell
    (:class:`membrax.triaxial.periodic.PeriodicTest`'s stages), each through its runner (the chunk driver);
    every ``checkpoint_every_chunks`` chunks, and at the end of each phase, the state, the phase and the
    records so far are saved, so a resumed run takes the same chunks as an uninterrupted one.
    """
    with precision_scope(config):
        started = time.perf_counter()
        test = build_periodic_test(config)
        build_seconds = time.perf_counter() - started
        programme = loading(config)
        plan = test.phase_plan(programme)
        run = _PeriodicRun(config, test, folder / CHECKPOINT_NAME, progress, interrupt_after_chunks)
        state, first_phase, phase_steps = test.initial_state, 0, 0
        if resume:
            state, first_phase, phase_steps = run.restore()
        for index in range(first_phase, len(PHASES)):
            if phase_steps == 0:  # a resumed phase was switched before its checkpoint
                state = test.start_phase(PHASES[index], state, programme)
            try:
                state = run.run_phase(
                    index, state, phase_steps, *plan[PHASES[index]], consolidation_tolerance(config)
                )
            except SimulationError as error:
                records = {phase: join_records(chunks) for phase, chunks in run.parts.items()}
                raise RunError(f"{error} Records so far are in {folder}.", records) from error
            phase_steps = 0
        return _finish_periodic(
            folder, config, test, run.parts, build_seconds, run.elapsed(), call_started, resume
        )


def _finish_periodic(folder, config, test, parts, build_seconds, elapsed, call_started, resumed) -> RunResult:
    """Write a periodic run's results, figure and summary (module docstring)."""
    consolidation = join_records(parts["consolidation"])
    shear = join_records(parts["shear_fine"] + parts["shear_coarse"])
    # The end of consolidation is the shearing's first record; its strains count from the shearing's box.
    first = {name: values[-1:] for name, values in consolidation.items()}
    first["axial_strain"] = np.zeros_like(first["axial_strain"])
    first["volumetric_strain"] = np.zeros_like(first["volumetric_strain"])
    shear = (
        {name: np.concatenate([first[name], values]) for name, values in shear.items()} if shear else first
    )
    for records in (consolidation, shear):
        records["time"] = records["step"] * test.dt
        records["love_weber_friction_angle_deg"] = analysis.friction_angle_deg(
            records["axial_stress"], records["lateral_stress"]
        )
        records["radial_strain"] = np.asarray(
            theory.radial_strain(records["axial_strain"], records["volumetric_strain"])
        )
    metadata = {
        "membrax_version": __version__,
        "config": config_to_dict(config),
        "cell": "periodic",
        "num_particles": int(test.particles.num_particles),
        "dt_s": test.dt,
        "consolidation_steps": int(consolidation["step"][-1]),
        "consolidation_tolerance": consolidation_tolerance(config),
        "shear_steps": int(shear["step"][-1] - consolidation["step"][-1]),
        "build_s": build_seconds,
        "run_s": elapsed,
        "dtype": "float64" if config.float64 else "float32",
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
    }
    shear_data = records_to_dataset(shear, attrs=metadata)
    consolidation_data = records_to_dataset(consolidation, attrs=metadata)
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
        f"{metadata['shear_steps']} steps in {elapsed:.0f} s"
        + (f" in all (resumed: this call {time.perf_counter() - call_started:.0f} s)" if resumed else "")
        + f" ({metadata['dtype']}, {metadata['jax_backend']}).\n\n"
    )
    summary = header + analysis.element_summary_table(shear_data, config.cell_pressure)
    (folder / "summary.md").write_text(summary + "\n")
    files["summary"] = folder / "summary.md"
    return RunResult(folder, shear_data, consolidation_data, summary, files, metadata)
