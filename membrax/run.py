"""One membrane triaxial test from a configuration to a results folder, with checkpoints and resume.

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
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from membrax import __version__, plots
from membrax.assemble import build_test, consolidation_tolerance, precision_scope
from membrax.config import TriaxialConfig, config_to_dict, dump_config_toml
from membrax.errors import RunError
from membrax.executor import build_batch
from membrax.io import VTKSeries, read_checkpoint_host, records_to_dataset, write_results
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
