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
through :func:`membrax.runner.run_group`, the one phase loop of membrane and periodic batches,
checkpointed every ``checkpoint_every_chunks`` chunks and at each phase's end (a resumed run takes the same
chunks and writes the same bits); error bits or a runaway kinetic energy (σc V₀ of the cell's first box
the scale) stop it with :class:`RunError` as a membrane run, and in a sweep freeze and flag the member
instead. The folder receives ``results.nc``/``.csv`` and ``consolidation.nc``/``.csv`` (the cell's
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
    build_test,
    consolidation_tolerance,
    precision_scope,
)
from membrax.config import TriaxialConfig, config_to_dict, dump_config_toml
from membrax.errors import RunError
from membrax.executor import build_batch, build_periodic_batch
from membrax.io import (
    VTKSeries,
    dataset_attrs_to_python,
    read_checkpoint_host,
    records_to_dataset,
    write_results,
)
from membrax.membrane.measure import triangle_stretches
from membrax.paper import PAPER_10KPA_5MM, paper_key
from membrax.run_records import join_records, member_chunk_records, results_datasets, run_metadata
from membrax.runner import CHECKPOINT_NAME, run_group
from membrax.triaxial import analysis
from membrax.triaxial.membrane_cell import MembraneTest

__all__ = [
    "CHECKPOINT_NAME",
    "RunResult",
    "build_test",
    "consolidation_tolerance",
    "default_folder",
    "figure_title",
    "periodic_datasets",
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

        mine, shear_start, elapsed = _run_alone(
            batch, config, folder, resume, progress, interrupt_after_chunks, after_chunk
        )
        return _finish(
            folder,
            config,
            test,
            run_metadata(batch.settings[0], test, mine, build_seconds, elapsed),
            mine,
            shear_start,
            elapsed,
            None if resumed_from is None else (resumed_from, time.perf_counter() - call_started),
        )


def _run_alone(batch, config, folder: Path, resume, progress, interrupt_after_chunks, after_chunk=None):
    """The one member of ``batch``, a membrane cell or a periodic element, through :func:`run_group`.

    Returns its records by phase, its start of shearing and the elapsed seconds.

    Raises:
      RunError: it blew up; the records so far are written to ``folder`` first, and the message says so.
    """
    try:
        records, shear_starts, elapsed = run_group(
            batch, folder, resume, progress, interrupt_after_chunks, after_chunk=after_chunk
        )
    except RunError as error:
        if error.records is not None:
            _write_partial(folder, member_chunk_records(error.records, 0), config)
        raise RunError(f"{error} Records so far are in {folder}.", error.records) from error
    return member_chunk_records(records, 0), shear_starts[0], elapsed


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


def _run_periodic(config, folder: Path, resume, progress, interrupt_after_chunks, call_started) -> RunResult:
    """The periodic element test of ``config`` into ``folder`` (module docstring, "The periodic element").

    A batch of one (:func:`membrax.executor.build_periodic_batch` on one device) through
    :func:`membrax.runner.run_group`, as a sweep's batches.
    """
    with precision_scope(config):
        started = time.perf_counter()
        batch = build_periodic_batch([config], num_devices=1)
        build_seconds = time.perf_counter() - started
        mine, _, elapsed = _run_alone(batch, config, folder, resume, progress, interrupt_after_chunks)
        test = batch.tests[0]
        shear, consolidation = periodic_datasets(test, batch.settings[0], mine, build_seconds, elapsed)
        return _finish_periodic(folder, config, test, shear, consolidation, call_started, resume)


def periodic_datasets(test, settings, records, build_seconds, elapsed, **attrs):
    """(shear, consolidation) datasets of a periodic element from its records by phase.

    The cell's records (:class:`membrax.triaxial.periodic.CellRecords`) with ``time``, ``radial_strain``
    and ``love_weber_friction_angle_deg``; the end of consolidation is the shearing's first record, its
    strains counted from the shearing's box.

    Args:
      test: the member's :class:`~membrax.triaxial.periodic.PeriodicTest`.
      settings: its :class:`membrax.assemble.RunSettings`.
      records: its records by phase (:func:`membrax.run_records.member_chunk_records`).
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
