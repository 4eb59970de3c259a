"""One membrane triaxial test from a configuration to a results folder, with checkpoints and resume.

Contract. :func:`run_test` takes a :class:`membrax.config.TriaxialConfig` and a folder and runs the paper's
protocol (:mod:`membrax.membrane_triaxial`): stage 1, consolidation under the cell pressure until the
unbalanced-force ratio is below the tolerance and the ram stress equals σc; stage 2, drained shearing at
the strain rate of ``inertial_number`` to ``target_axial_strain``, recorded every ``record_every_fine``
steps below ``fine_until_strain`` and every ``record_every_coarse`` steps after. The folder receives:

- ``results.nc`` / ``results.csv``: the shearing records
  (:class:`membrax.membrane_measure.MembraneMeasurements` plus the derived quantities of
  :func:`membrax.analysis.derived_quantities`), the first one being the last consolidation record (the initial
  state of the paper's Table 3), with axial, radial and volumetric strain counted from the start of shearing
  (the paper's figures start at 0 %), the configuration, version, N, dt, step counts and timings as
  attributes;
- ``consolidation.nc`` / ``consolidation.csv``: the stage-1 records (strains from the built specimen);
- ``fig5_friction.png`` … ``fig8_radial_ratio.png`` (:func:`membrax.plots.save_test_figures`),
  ``summary.md`` (Table 2/3-style numbers beside the paper's for 10 kPa / 5 mm);
- ``config.toml`` (the configuration as run), ``checkpoint.npz`` (the last checkpoint), and, when
  ``vtk_every_steps`` > 0, VTK snapshots ``vtk/membrane_*.vtu`` and ``vtk/particles_*.vtu`` with
  ``.pvd`` indexes for ParaView.

Long runs. The simulation advances in jitted chunks of ``chunk_steps``; a tqdm bar shows the stage, the
axial strain, the external and internal φ' and the steps per second. Every ``checkpoint_every_chunks``
chunks the state, the records so far and the position in the protocol are written atomically
(:func:`membrax.io.save_checkpoint`). ``resume=True`` continues from the checkpoint: the remaining steps
of the interrupted phase run in the same chunks as they would have uninterrupted, so the results are
identical. A non-finite state (the driver's error bits) or a runaway kinetic energy (above
``RUNAWAY_KINETIC_FRACTION`` × σc V₀, the work scale of the cell pressure) stops the run with
:class:`RunError`, naming the step and what to change; the records so far are written first.
"""

from __future__ import annotations

import dataclasses
import math
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from membrax import __version__, analysis, membrane_measure, plots, theory
from membrax import io as io_lib
from membrax import paper as paper_lib
from membrax.config import TriaxialConfig, config_to_dict, default_consolidation_tolerance, dump_config_toml
from membrax.contact import ContactParams
from membrax.driver import SimulationError
from membrax.membrane_contact import MembraneContactParams
from membrax.membrane_dem import grow_candidates
from membrax.membrane_triaxial import MembraneTest, membrane_test
from membrax.packing import fcc_specimen, with_imperfection

__all__ = [
    "RUNAWAY_KINETIC_FRACTION",
    "RunError",
    "RunResult",
    "build_test",
    "consolidation_tolerance",
    "results_datasets",
    "run_metadata",
    "run_test",
]

#: Kinetic energy above this fraction of σc V₀ stops the run (a quasi-static test stays below 1e-4).
RUNAWAY_KINETIC_FRACTION = 0.05
#: Steps between consolidation records.
CONSOLIDATION_RECORD_EVERY = 100
PHASES = ("consolidation", "shear_fine", "shear_coarse")
CHECKPOINT_NAME = "checkpoint.npz"


class RunError(RuntimeError):
    """The simulation stopped (non-finite values or runaway energy); the message says what to change."""


@dataclasses.dataclass
class RunResult:
    """What :func:`run_test` produced."""

    folder: Path
    results: object  # xarray.Dataset of the shearing records
    consolidation: object  # xarray.Dataset of the consolidation records
    summary: str
    files: dict
    metadata: dict


def build_test(
    config: TriaxialConfig, time_step: float | None = None, nodes_around: int | None = None
) -> MembraneTest:
    """The membrane test of a configuration (specimen, membrane, platens; nothing compiled yet).

    ``time_step`` (s) and ``nodes_around`` (membrane nodes per ring) override the test's own choices, as a
    batch does (:mod:`membrax.sweep`: one Δt and one mesh topology for all its members).
    """
    specimen = fcc_specimen(config.particle_diameter, config.particles_across, config.layers)
    if config.imperfection_fraction > 0.0:
        specimen = with_imperfection(specimen, config.imperfection_fraction, config.imperfection_seed)
    contact = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    membrane_contact = MembraneContactParams.default(friction_angle_deg=config.membrane_friction_angle_deg)
    return membrane_test(
        specimen,
        cell_pressure_kpa=config.cell_pressure_kpa,
        membrane_thickness_mm=config.membrane_thickness_mm,
        membrane_modulus_kpa=config.membrane_modulus_kpa,
        contact_params=contact,
        membrane_contact=membrane_contact,
        density=config.particle_density_kg_m3,
        edges_per_diameter=config.membrane_edges_per_diameter,
        dt_safety=config.dt_safety,
        bending_factor=config.membrane_bending_factor,
        time_step=time_step,
        nodes_around=nodes_around,
        contact_offset_factor=config.membrane_contact_offset_factor,
    )


def consolidation_tolerance(config: TriaxialConfig) -> float:
    """The unbalanced-force ratio that ends consolidation.

    The configuration's, else the membrane cell's default for its precision
    (:func:`membrax.config.default_consolidation_tolerance`).
    """
    tolerance = config.consolidation_tolerance_or_none
    if tolerance is None:
        tolerance = default_consolidation_tolerance("membrane", config.float64)
    return tolerance


def _records_dict(records) -> dict:
    return {field.name: np.asarray(getattr(records, field.name)) for field in dataclasses.fields(records)}


def _join(chunks: list[dict]) -> dict:
    if not chunks:
        return {}
    return {name: np.concatenate([chunk[name] for chunk in chunks]) for name in chunks[0]}


def _last(records: dict, name: str) -> float:
    return float(np.asarray(records[name])[-1].ravel()[0])


def _friction_angle(axial: float, radial: float) -> float:
    if not (axial > 0.0 and radial > 0.0):
        return math.nan
    major, minor = max(axial, radial), min(axial, radial)
    return float(theory.mobilised_friction_angle_deg(major, minor))


def _capacities(state) -> dict:
    candidates = state.membrane.candidates
    return {
        "node_candidates": candidates.capacity,
        "sphere_slots": candidates.sphere_capacity,
        "neighbor_pairs": int(state.dem.neighbors.idx.shape[1]),
    }


def _template(test: MembraneTest, capacities: dict):
    """The initial state grown to the capacities of a checkpoint (the driver may have grown its tables)."""
    state = test.initial_state
    if _capacities(state) == capacities:
        return state
    state = grow_candidates(
        state,
        test.particles,
        capacities["node_candidates"],
        test.params.membrane.contact_thickness,
        capacities["sphere_slots"],
    )
    extra = capacities["neighbor_pairs"] - int(state.dem.neighbors.idx.shape[1])
    if extra != 0:
        neighbors = test.runner.neighbor_frame.allocate(state.dem.position, extra_capacity=extra)
        spring = jnp.zeros((neighbors.idx.shape[1], 3), state.dem.position.dtype)
        state = state.set(dem=state.dem.set(neighbors=neighbors, pair_spring=spring))
    return state


def _rebase(records: dict, start: dict) -> dict:
    """Strains, area and stresses counted from the start of shearing (the paper's Table 3 and figures).

    The area A = A₀ (1 − ε_v)/(1 − ε_a) starts from the platen area A₀ at the start of shearing
    (:func:`membrax.membrane_measure.right_cylinder_stresses`), so at ε_a = 0 the external σ1 is the ram
    servo's σc. The consolidation stage's strains (from the as-built specimen, the membrane's penetration into
    the voids included) are kept in their own columns, ``consolidation_axial_strain`` and
    ``consolidation_volumetric_strain``, the same in every row.
    """
    out = dict(records)
    height, volume = np.asarray(records["height"]), np.asarray(records["volume"])
    height0, volume0 = float(start["height"]), float(start["volume"])
    out["consolidation_axial_strain"] = np.full_like(height, float(np.ravel(records["axial_strain"])[0]))
    out["consolidation_volumetric_strain"] = np.full_like(
        height, float(np.ravel(records["volumetric_strain"])[0])
    )
    out["axial_strain"] = (height0 - height) / height0
    out["volumetric_strain"] = (volume0 - volume) / volume0
    out["radial_strain"] = 1.0 - np.sqrt((volume / height) / (volume0 / height0))
    area, external_axial, internal_axial, internal_radial = membrane_measure.right_cylinder_stresses(
        np.asarray(records["ram_force"]),
        np.asarray(records["received_axial_force"]),
        np.asarray(records["membrane_radial_force"]) + np.asarray(records["clamp_radial_force"]),
        height,
        volume,
        height0,
        volume0,
        float(start["platen_area"]),
    )
    out.update(
        platen_area=area,
        external_axial_stress=external_axial,
        internal_axial_stress=internal_axial,
        internal_radial_stress=internal_radial,
    )
    return out


def _vtk_snapshot(series, state, test: MembraneTest) -> None:
    nodes, spheres = state.membrane, state.dem
    stretch = np.asarray(membrane_measure.triangle_stretches(nodes.position, test.mesh)).T
    series.add(
        int(state.step),
        float(state.step) * test.dt,
        membrane=(
            np.asarray(nodes.position),
            np.asarray(test.mesh.triangles),
            {"force": np.asarray(nodes.node_force), "velocity": np.asarray(nodes.velocity)},
            {"stretch": stretch},
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
    """
    from tqdm.auto import tqdm

    # The configuration's precision, scoped to this call (thread-local): the process's global setting,
    # the entry point's (membrax.cli) or the user's, is never changed.
    with jax.enable_x64(config.float64):
        return _run(
            config, Path(folder), resume, progress, interrupt_after_chunks, tqdm, time_step, nodes_around
        )


def _run(
    config, folder: Path, resume, progress, interrupt_after_chunks, tqdm, time_step=None, nodes_around=None
) -> RunResult:
    folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    test = build_test(config, time_step, nodes_around)
    build_seconds = time.perf_counter() - started
    checkpoint_path = folder / CHECKPOINT_NAME
    tolerance = consolidation_tolerance(config)
    records: dict[str, list[dict]] = {phase: [] for phase in PHASES}
    phase_index, phase_done, elapsed = 0, 0, 0.0
    shear_start: dict | None = None
    state = test.start_consolidation(test.initial_state)
    if resume:
        if not checkpoint_path.exists():
            raise FileNotFoundError(
                f"no checkpoint at '{checkpoint_path}' to resume from; run without --resume to start afresh."
            )
        host = io_lib.read_checkpoint_host(checkpoint_path)
        state, host = io_lib.load_checkpoint(checkpoint_path, _template(test, host["capacities"]))
        phase_index, phase_done, elapsed = host["phase_index"], host["phase_done"], host["elapsed_s"]
        shear_start = host.get("shear_start")
        for phase in PHASES:
            names = host.get(f"names_{phase}", [])
            if names:
                records[phase] = [{name: np.asarray(host[f"rec_{phase}_{name}"]) for name in names}]
    else:
        (folder / "config.toml").write_text(dump_config_toml(config))
    series = None
    if config.vtk_every_steps > 0:
        series = io_lib.VTKSeries(folder / "vtk", "specimen", resume_step=int(state.step) if resume else None)
        if not resume:
            series.truncate_after(-1)
            _vtk_snapshot(series, state, test)

    fine, coarse = test.shear_plan(
        config.target_axial_strain, config.inertial_number, config.fine_until_strain, config.shear_ramp_strain
    )
    plan = {
        "consolidation": (config.consolidation_max_steps, CONSOLIDATION_RECORD_EVERY),
        "shear_fine": (fine, config.record_every_fine),
        "shear_coarse": (coarse, config.record_every_coarse),
    }
    volume_work = test.cell_pressure * test.initial_volume
    chunks_this_call = 0
    stage_clock = time.perf_counter()

    def save(current_state):
        host = {
            "phase_index": phase_index,
            "phase_done": phase_done,
            "elapsed_s": elapsed + time.perf_counter() - stage_clock,
            "capacities": _capacities(current_state),
            "shear_start": shear_start,
        }
        for phase in PHASES:
            joined = _join(records[phase])
            host[f"names_{phase}"] = list(joined)
            host.update({f"rec_{phase}_{name}": value for name, value in joined.items()})
        io_lib.save_checkpoint(checkpoint_path, current_state, host)

    try:
        while phase_index < len(PHASES):
            phase = PHASES[phase_index]
            total, record_every = plan[phase]
            if phase == "shear_fine" and phase_done == 0:
                last = _join(records["consolidation"])
                shear_start = {
                    "height": _last(last, "height"),
                    "volume": _last(last, "volume"),
                    "platen_area": test.platen_area,
                }
                state = test.start_shear(
                    state, config.inertial_number, config.shear_ramp_strain, config.symmetric_loading
                )
            remaining = total - phase_done
            bar = tqdm(
                total=total, initial=phase_done, desc=phase, unit="step", disable=not progress, leave=False
            )

            def on_chunk(new_state, chunk, phase=phase, bar=bar, record_every=record_every):
                nonlocal phase_done, chunks_this_call, state
                chunk = _records_dict(chunk)
                records[phase].append(chunk)
                steps = len(chunk["step"]) * record_every
                phase_done += steps
                state = new_state
                kinetic = _last(chunk, "kinetic_energy")
                if not math.isfinite(kinetic) or kinetic > RUNAWAY_KINETIC_FRACTION * volume_work:
                    raise RunError(
                        f"kinetic energy {kinetic:.3g} J exceeds {RUNAWAY_KINETIC_FRACTION} σc V₀ = "
                        f"{RUNAWAY_KINETIC_FRACTION * volume_work:.3g} J at step {int(new_state.step)}: the "
                        f"run is unstable. Lower dt_safety (now {config.dt_safety}) or "
                        f"particle_stiffness_n_m (now {config.particle_stiffness_n_m:g})."
                    )
                bar.update(steps)
                external = _friction_angle(_last(chunk, "external_axial_stress"), config.cell_pressure)
                internal = _friction_angle(
                    _last(chunk, "internal_axial_stress"), _last(chunk, "internal_radial_stress")
                )
                bar.set_postfix(
                    strain=f"{100 * _last(chunk, 'axial_strain'):.3f}%",
                    phi_ext=f"{external:.1f}",
                    phi_int=f"{internal:.1f}",
                )
                if (
                    series is not None
                    and int(new_state.step) // config.vtk_every_steps
                    > (int(new_state.step) - steps) // config.vtk_every_steps
                ):
                    _vtk_snapshot(series, new_state, test)
                chunks_this_call += 1
                if chunks_this_call % config.checkpoint_every_chunks == 0:
                    save(new_state)
                if interrupt_after_chunks is not None and chunks_this_call >= interrupt_after_chunks:
                    raise KeyboardInterrupt(f"interrupted after {chunks_this_call} chunks (testing aid)")

            stop_fn = None
            if phase == "consolidation":

                def stop_fn(_, chunk):
                    return test.is_consolidated(chunk, tolerance)

            if remaining > 0:
                state, _ = test.runner.run(
                    state,
                    test.params,
                    remaining,
                    config.chunk_steps,
                    record_every,
                    stop_fn=stop_fn,
                    on_chunk=on_chunk,
                )
            bar.close()
            phase_index += 1
            phase_done = 0
            save(state)
    except SimulationError as error:
        _write_partial(folder, records, test, config)
        raise RunError(
            f"{error}. Records so far are in {folder}. Lower dt_safety (now {config.dt_safety}) or "
            f"particle_stiffness_n_m (now {config.particle_stiffness_n_m:g}); a membrane modulus far above "
            f"the paper's 1400 kPa also shortens the stable step."
        ) from error
    except RunError:
        _write_partial(folder, records, test, config)
        raise
    elapsed += time.perf_counter() - stage_clock
    return _finish(folder, config, test, records, shear_start, build_seconds, elapsed, tolerance)


def run_metadata(config, test, records, build_seconds, elapsed, tolerance) -> dict:
    """The attributes of a run's datasets: configuration, version, sizes, Δt, steps, timings, machine."""
    consolidation = _join(records["consolidation"])
    shear_steps = (
        sum(len(c["step"]) for c in records["shear_fine"]) * config.record_every_fine
        + sum(len(c["step"]) for c in records["shear_coarse"]) * config.record_every_coarse
    )
    return {
        "membrax_version": __version__,
        "config": config_to_dict(config),
        "num_particles": int(test.particles.num_particles),
        "num_membrane_nodes": int(test.mesh.num_nodes),
        "num_triangles": int(test.mesh.triangles.shape[0]),
        "dt_s": test.dt,
        "critical_dt_s": {key: float(value) for key, value in test.critical_dt.items()},
        "consolidation_steps": int(len(consolidation.get("step", [])) * CONSOLIDATION_RECORD_EVERY),
        "consolidation_tolerance": tolerance,
        "shear_steps": int(shear_steps),
        "build_s": build_seconds,
        "run_s": elapsed,
        "dtype": "float64" if config.float64 else "float32",
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
    }


def results_datasets(records: dict, shear_start: dict, metadata: dict):
    """(shear dataset or None, consolidation dataset) from the records of the three phases (module docstring).

    ``records`` maps each of :data:`PHASES` to a list of chunk dicts; ``shear_start`` holds the height and
    volume at the start of shearing (strains are rebased on them); ``metadata`` becomes the attributes.
    """
    consolidation = io_lib.records_to_dataset(_join(records["consolidation"]), attrs=metadata)
    shear = _join(records["shear_fine"] + records["shear_coarse"])
    if not shear:
        return None, consolidation
    # The end of consolidation is the shearing's first record (strain 0: the "initial" state of Table 3).
    last = {name: value[-1:] for name, value in _join(records["consolidation"]).items()}
    shear = {name: np.concatenate([last[name], value]) for name, value in shear.items()}
    shear = _rebase(shear, shear_start)
    shear.update(analysis.derived_quantities(shear))
    return io_lib.records_to_dataset(shear, attrs=metadata), consolidation


def _write_partial(folder, records, test, config) -> None:
    metadata = {"membrax_version": __version__, "config": config_to_dict(config), "partial": True}
    consolidation = _join(records["consolidation"])
    if consolidation:
        io_lib.write_results(
            io_lib.records_to_dataset(consolidation, attrs=metadata), folder, "consolidation"
        )
    shear = _join(records["shear_fine"] + records["shear_coarse"])
    if shear:
        io_lib.write_results(io_lib.records_to_dataset(shear, attrs=metadata), folder, "results_partial")


def _finish(folder, config, test, records, shear_start, build_seconds, elapsed, tolerance) -> RunResult:
    metadata = run_metadata(config, test, records, build_seconds, elapsed, tolerance)
    shear, consolidation = results_datasets(records, shear_start, metadata)
    files = {"consolidation": io_lib.write_results(consolidation, folder, "consolidation")}
    files["results"] = io_lib.write_results(shear, folder, "results")
    files["figures"] = plots.save_test_figures(shear, folder)
    paper = (
        paper_lib.PAPER_10KPA_5MM
        if paper_lib.paper_key(config.cell_pressure_kpa, config.membrane_thickness_mm) == (10.0, 5.0)
        else None
    )
    summary = analysis.summary_table(shear, paper=paper)
    header = (
        f"# membrax {__version__}: {config.name}\n\n"
        f"{metadata['num_particles']} spheres, {metadata['num_membrane_nodes']} membrane nodes, "
        f"σc = {config.cell_pressure_kpa:g} kPa, t_m = {config.membrane_thickness_mm:g} mm, "
        f"E_m = {config.membrane_modulus_kpa:g} kPa, I = {config.inertial_number:g}, dt = {test.dt:.3g} s, "
        f"{metadata['consolidation_steps']} + {metadata['shear_steps']} steps in {elapsed:.0f} s "
        f"({metadata['dtype']}, {metadata['jax_backend']}).\n\n"
    )
    summary = header + summary
    (folder / "summary.md").write_text(summary + "\n")
    files["summary"] = folder / "summary.md"
    return RunResult(folder, shear, consolidation, summary, files, metadata)
