"""The runner: a batch of membrane tests from configurations, through consolidation and shearing.

Contract. Every membrane test that runs to a results folder goes through here, alone or in a grid: a single
test (:func:`membrax.run.run_test`) is a batch of one, a sweep (:func:`membrax.sweep.run_sweep`) runs its
grid as batches. :func:`build_batch` builds the members of one compiled batch (:class:`BatchedTest`:
states stacked on a member axis, one Δt, one mesh topology) and :func:`run_group` takes them through the
protocol's stage sequence (:data:`membrax.triaxial.protocol.PHASES`, each member's steps and record
intervals from :meth:`~membrax.triaxial.protocol.StagedTest.phase_plan` of its :func:`loading`):

- ``consolidation``: the ram servo on, until each member's own stop test holds
  (:meth:`membrax.triaxial.membrane_cell.MembraneTest.is_consolidated`) or it reaches
  ``consolidation_max_steps``;
- ``shear_fine`` and ``shear_coarse``: drained shearing at the strain rate of ``inertial_number``
  (ramped from rest), recorded every ``record_every_fine`` steps below ``fine_until_strain`` and every
  ``record_every_coarse`` steps after, to ``target_axial_strain``; after ``fine_until_strain`` at the
  rate of ``coarse_inertial_number`` where it is set (the speed changed linearly over
  ``shear_ramp_strain``).

The loop (:func:`membrax.driver.drive`) reallocates tables and checks error bits; :func:`run_group` adds
what a long run needs: a progress bar per phase, a checkpoint (stacked state, records so far, budgets)
every ``checkpoint_every_chunks`` chunks and at each phase's end, ``resume`` continuing to results
identical to an uninterrupted run, a runaway-energy stop (kinetic energy above
:data:`RUNAWAY_KINETIC_FRACTION` × σc V₀) that raises :class:`RunError` with the records so far, and an
``after_chunk`` hook (VTK snapshots). :func:`results_datasets` turns a member's records into the shearing
and consolidation datasets (strains and areas counted from the start of shearing).

Batching: :mod:`membrax.executor`; configurations become tests in :mod:`membrax.assemble`.
"""

from __future__ import annotations

import contextlib
import platform
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from membrax import __version__, theory
from membrax.assemble import consolidation_tolerance, loading
from membrax.config import TriaxialConfig, config_to_dict
from membrax.errors import RunError, SimulationError
from membrax.executor import BatchedTest, batch_template, cast_state, float32_batch, table_capacities
from membrax.io import load_checkpoint, read_checkpoint_host, records_to_dataset, save_checkpoint
from membrax.membrane.records import right_cylinder_stresses
from membrax.spheres.grading import mass_fractions
from membrax.triaxial import analysis
from membrax.triaxial.protocol import CONSOLIDATION_RECORD_EVERY, PHASES

__all__ = [
    "CHECKPOINT_NAME",
    "RUNAWAY_KINETIC_FRACTION",
    "join_records",
    "member_chunk_records",
    "phase_bar",
    "precision_name",
    "rebase_to_shear_start",
    "results_datasets",
    "run_group",
    "run_metadata",
    "specimen_metadata",
]


#: Kinetic energy above this fraction of σc V₀ stops the run (a quasi-static test stays below 1e-4).
RUNAWAY_KINETIC_FRACTION = 0.05


CHECKPOINT_NAME = "checkpoint.npz"


#: Records a single test's progress bar reads (axial strain and the paper's §4.3 stresses).
_PROGRESS = (
    "axial_strain",
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
)


def join_records(chunks: list[dict], axis: int = 0) -> dict:
    """Join chunk dicts of records along their time axis (0 for one member, 1 for stacked members)."""
    if not chunks:
        return {}
    return {name: np.concatenate([chunk[name] for chunk in chunks], axis=axis) for name in chunks[0]}


def rebase_to_shear_start(records: dict, start: dict) -> dict:
    """Strains, area and stresses counted from the start of shearing (the paper's Table 3 and figures).

    The area A = A₀ (1 − ε_v)/(1 − ε_a) starts from the platen area A₀ at the start of shearing
    (:func:`membrax.membrane.measure.right_cylinder_stresses`), so at ε_a = 0 the external σ1 is the ram
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
    out["radial_strain"] = np.asarray(theory.radial_strain(out["axial_strain"], out["volumetric_strain"]))
    area, external_axial, internal_axial, internal_radial = right_cylinder_stresses(
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


def member_chunk_records(records: dict, b: int) -> dict:
    """Member b's records of every phase, as :func:`membrax.run.results_datasets` takes them."""
    out = {}
    for phase in PHASES:
        joined = join_records(records[phase], axis=1)
        if not joined:
            out[phase] = []
            continue
        valid = joined["valid"][b]
        if not valid.any():  # a member that never reached this phase (it failed before)
            out[phase] = []
            continue
        out[phase] = [{name: value[b][valid] for name, value in joined.items() if name != "valid"}]
    return out


def _last_member_value(chunks: list[dict], name: str, b: int) -> float:
    joined = join_records(chunks, axis=1)
    values = joined[name][b][joined["valid"][b]]
    return float(np.asarray(values)[-1].ravel()[0])


def phase_bar(phase: str, num: int, total: int, progress: bool):
    """The tqdm bar of one phase of :func:`run_group`.

    Consolidation ends on its criterion, not on its step cap: its bar counts steps with no total (no
    made-up ETA) and shows the unbalanced-force ratio against its stop value. A phase with no steps to run
    shows no bar; a single test's bar does not count members.
    """
    from tqdm.auto import tqdm

    return tqdm(
        total=None if phase == "consolidation" else total,
        desc=phase if num == 1 else f"{phase} ({num} members)",
        unit="step",
        disable=not progress or total == 0,
        leave=False,
    )


def run_group(
    batch: BatchedTest,
    folder: Path,
    resume: bool = False,
    progress: bool = True,
    interrupt_after_chunks: int | None = None,
    chunk_counter: list | None = None,
    after_chunk: Callable | None = None,
    isolate_failures: bool = False,
):
    """Run one batch through the three phases of :data:`PHASES` (module docstring).

    With ``float32_shearing`` (and ``float64``) consolidation runs in float64 and the shearing in float32:
    at the start of shearing the batch is rebuilt in float32 (:func:`float32_batch`) and the state carried
    over (:func:`cast_state`); the rest runs inside ``jax.enable_x64(False)``.

    Args:
      batch: from :func:`build_batch`.
      folder: where ``checkpoint.npz`` is written (and read with ``resume``).
      resume: continue from the folder's checkpoint, if there is one.
      progress: a tqdm bar per phase.
      interrupt_after_chunks: testing aid: ``KeyboardInterrupt`` after this many chunks (counted in
        ``chunk_counter``, after that chunk's checkpoint), as a killed process would stop.
      chunk_counter: a one-element list counting chunks across groups (default: this call's own).
      after_chunk: ``after_chunk(states, phase)`` after each accepted chunk (e.g. VTK snapshots).
      isolate_failures: a member that blows up (error bits, or a runaway kinetic energy) is frozen at its
        last good records and the others go on; ``batch.failures`` maps it to its error, step and phase
        (kept in checkpoints); the group runs on even when every member has failed (the caller judges: a
        sweep fails only when all its members did). False: the first raises.

    Returns:
      (records by phase: lists of chunk dicts of stacked (B, T, ...) arrays with ``valid``; the start of
      shearing per member: height, volume and platen area; the elapsed seconds).

    Raises:
      RunError: a member blew up (error bits or runaway kinetic energy); ``error.records`` holds the
        records so far, as returned.
    """
    # scope holds the float32 shearing's enable_x64(False) until the group ends.
    with contextlib.ExitStack() as scope:
        chunk_counter = [0] if chunk_counter is None else chunk_counter
        failures: dict[int, dict] = {}
        batch.failures = failures
        float32_shearing = batch.configs[0].float64 and batch.configs[0].float32_shearing

        def to_float32():
            """Rebuild the batch in float32 and run the rest in float32 (once)."""
            nonlocal batch
            if np.dtype(batch.initial_state.dem.position.dtype) == np.float32:
                return
            scope.enter_context(jax.enable_x64(False))
            batch = float32_batch(batch)

        config = batch.configs[0]
        checkpoint_path = folder / CHECKPOINT_NAME
        num = batch.num_members
        records: dict[str, list[dict]] = {phase: [] for phase in PHASES}
        phase_index, elapsed = 0, 0.0
        budgets = None
        shear_height = np.zeros(num)
        shear_volume = np.zeros(num)
        states = batch.initial_state
        if resume and checkpoint_path.exists():
            host = read_checkpoint_host(checkpoint_path)
            if float32_shearing and host.get("dtype") == "float32":
                to_float32()
            states, host = load_checkpoint(checkpoint_path, batch_template(batch, host["capacities"]))
            phase_index, elapsed = host["phase_index"], host["elapsed_s"]
            budgets = None if host["budgets"] is None else np.asarray(host["budgets"], dtype=np.int64)
            shear_height, shear_volume = np.asarray(host["shear_height"]), np.asarray(host["shear_volume"])
            failures.update({int(b): failure for b, failure in host.get("failures", {}).items()})
            for phase in PHASES:
                names = host.get(f"names_{phase}", [])
                if names:
                    records[phase] = [{name: np.asarray(host[f"rec_{phase}_{name}"]) for name in names}]
        tolerances = [consolidation_tolerance(c) for c in batch.configs]
        volume_work = np.array([t.cell_pressure * t.initial_volume for t in batch.tests])
        clock = time.perf_counter()

        def save(current, current_budgets):
            host = {
                "phase_index": phase_index,
                "elapsed_s": elapsed + time.perf_counter() - clock,
                "capacities": table_capacities(current),
                # None at a phase's end: the next phase computes its budgets (and starts shearing) on resume.
                "budgets": None if current_budgets is None else [int(v) for v in current_budgets],
                "shear_height": shear_height,
                "shear_volume": shear_volume,
                "member_steps": [int(step) for step in np.asarray(current.dem.step)[:num]],
                "dtype": str(np.dtype(current.dem.position.dtype)),
                "failures": {str(b): failure for b, failure in failures.items()},
            }
            for phase in PHASES:
                joined = join_records(records[phase], axis=1)
                host[f"names_{phase}"] = list(joined)
                host.update({f"rec_{phase}_{name}": value for name, value in joined.items()})
            save_checkpoint(checkpoint_path, current, host)

        # The protocol's stage sequence (membrax.triaxial.protocol): each member's steps and record interval
        # per phase. The record interval is shared: it is not a batched field, so all members have the same.
        plans = [t.phase_plan(loading(c)) for t, c in zip(batch.tests, batch.configs, strict=True)]
        while phase_index < len(PHASES):
            phase = PHASES[phase_index]
            if budgets is None:
                if phase == "shear_fine" and float32_shearing:
                    capacities = table_capacities(states)
                    to_float32()
                    states = cast_state(states, batch_template(batch, capacities))
                if phase == "shear_fine":
                    members = batch.unstack(states)
                    for b, test in enumerate(batch.tests):
                        if b in failures:  # frozen: it never shears
                            continue
                        shear_height[b] = _last_member_value(records["consolidation"], "height", b)
                        shear_volume[b] = _last_member_value(records["consolidation"], "volume", b)
                        c = batch.configs[b]
                        members[b] = test.start_shear(
                            members[b], c.inertial_number, c.shear_ramp_strain, c.symmetric_loading
                        )
                    states = batch.restack(members)
                elif phase == "shear_coarse" and any(c.coarse_inertial_number for c in batch.configs):
                    members = batch.unstack(states)
                    for b, test in enumerate(batch.tests):
                        c = batch.configs[b]
                        if b not in failures and c.coarse_inertial_number:
                            members[b] = test.change_shear_rate(
                                members[b], c.inertial_number, c.coarse_inertial_number, c.shear_ramp_strain
                            )
                    states = batch.restack(members)
                budgets = np.array([plan[phase][0] for plan in plans], dtype=np.int64)
                budgets[list(failures)] = 0  # a failed member stays frozen
            record_every = plans[0][phase][1]
            total = int(np.ceil(np.max(budgets, initial=0) / record_every) * record_every)
            bar = phase_bar(phase, num, total, progress)

            def on_chunk(current, chunk, left, phase=phase, bar=bar, record_every=record_every):
                nonlocal budgets
                budgets = left
                kinetic = chunk["kinetic_energy"].reshape(num, chunk["valid"].shape[1], -1)[:, -1, 0]
                runaway = ~np.isfinite(kinetic) | (kinetic > RUNAWAY_KINETIC_FRACTION * volume_work)
                runaway[list(failures)] = False
                stop = []
                for b in np.flatnonzero(runaway):
                    message = (
                        f"member {b} ({batch.configs[b].name}): kinetic energy {kinetic[b]:.3g} J exceeds "
                        f"{RUNAWAY_KINETIC_FRACTION} σc V₀ = "
                        f"{RUNAWAY_KINETIC_FRACTION * volume_work[b]:.3g} J: "
                        f"the run is unstable. Lower dt_safety (now {config.dt_safety}) or the stiffness."
                    )
                    if not isolate_failures:
                        raise RunError(message)
                    chunk["valid"][b] = False  # frozen at its last good records
                    stop.append(int(b))
                    on_failure(int(b), "RUNAWAY_KINETIC_ENERGY", int(np.asarray(current.dem.step)[b]), phase)
                records[phase].append(chunk)
                bar.update(chunk["valid"].shape[1] * record_every)
                postfix = {"active": int(np.sum(left > 0)), "step": int(np.max(np.asarray(current.dem.step)))}
                if phase == "consolidation":
                    # The worst member's unbalanced-force ratio against the stop value (tqdm sorts the keys).
                    ratio = chunk["unbalanced_force_ratio"].reshape(num, chunk["valid"].shape[1], -1)[..., 0]
                    last = [ratio[b][chunk["valid"][b]][-1] for b in range(num) if chunk["valid"][b].any()]
                    postfix = {
                        "unbalanced": f"{max(last, default=0.0):.1e}",
                        "until": f"{min(tolerances):.0e}",
                        **({} if num == 1 else {"active": postfix["active"]}),
                    }
                elif num == 1:
                    # A single test (run_test) shows where it stands, as in the paper's Fig. 5.
                    valid = chunk["valid"][0]
                    last = {name: float(chunk[name][0][valid][-1].ravel()[0]) for name in _PROGRESS}
                    external, internal = analysis.friction_angle_deg(
                        [last["external_axial_stress"], last["internal_axial_stress"]],
                        [last["external_radial_stress"], last["internal_radial_stress"]],
                    )
                    postfix = {
                        "strain": f"{100 * last['axial_strain']:.3f}%",
                        "phi_ext": f"{external:.1f}",
                        "phi_int": f"{internal:.1f}",
                    }
                bar.set_postfix(**postfix)
                if after_chunk is not None:
                    after_chunk(current, phase)
                chunk_counter[0] += 1
                if chunk_counter[0] % config.checkpoint_every_chunks == 0:
                    save(current, left)
                if interrupt_after_chunks is not None and chunk_counter[0] >= interrupt_after_chunks:
                    raise KeyboardInterrupt(f"interrupted after {chunk_counter[0]} chunks (testing aid)")
                return stop

            def on_failure(b, names, step, phase=phase):
                failures[b] = {"error": names, "step": step, "phase": phase}

            stop_fn = None
            if phase == "consolidation":

                def stop_fn(b, mine):
                    return batch.tests[b].is_consolidated(mine, tolerances[b])

            try:
                states, budgets = batch.run_phase(
                    states,
                    budgets,
                    config.chunk_steps,
                    record_every,
                    stop_fn=stop_fn,
                    on_chunk=on_chunk,
                    on_failure=on_failure if isolate_failures else None,
                )
            except SimulationError as error:
                raise RunError(
                    f"{error}. Lower dt_safety (now {config.dt_safety}) or particle_stiffness_n_m; a "
                    "membrane modulus far above the paper's 1400 kPa also shortens the stable step.",
                    records,
                ) from error
            except RunError as error:
                error.records = records
                raise
            finally:
                bar.close()
            phase_index += 1
            budgets = None
            save(states, None)
        elapsed += time.perf_counter() - clock
        shear_start = [
            {"height": shear_height[b], "volume": shear_volume[b], "platen_area": batch.tests[b].platen_area}
            for b in range(num)
        ]
        return records, shear_start, elapsed


def run_metadata(config, test, records, build_seconds, elapsed, tolerance) -> dict:
    """The attributes of a run's datasets: configuration, version, sizes, Δt, steps, timings, machine."""
    consolidation = join_records(records["consolidation"])
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
        "dtype": precision_name(config),
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
        "specimen": specimen_metadata(test.specimen),
    }


def precision_name(config: TriaxialConfig) -> str:
    """The run's precision: ``"float64"``, ``"float32"`` or ``"float64 consolidation, float32 shearing"``."""
    if not config.float64:
        return "float32"
    return "float64 consolidation, float32 shearing" if config.float32_shearing else "float64"


def specimen_metadata(specimen) -> dict:
    """The specimen's record for a run's attributes: packing, size, solid fraction, grading.

    For a random specimen sampled from a grading: the sieve sizes (mm) and percent passing beside the
    percent passing of the sampled spheres (:func:`membrax.spheres.grading.mass_fractions`).
    """
    radius = np.asarray(specimen.radius, dtype=float)
    solid = float(np.sum(4.0 / 3.0 * np.pi * radius**3))
    record = {
        "packing": "random" if specimen.cross_section == "circle" else "fcc",
        "num_spheres": int(radius.size),
        "width_mm": 1e3 * specimen.width_across_flats,
        "height_mm": 1e3 * specimen.height,
        "solid_fraction": solid / (specimen.cross_section_area * specimen.height),
    }
    # A compacted packing's stress, and the jump that kept it out of the compaction's window, if any.
    measures = dict(getattr(specimen, "packing_measures", ()))
    for name in ("compaction_stress", "compaction_stress_below", "compaction_stress_above"):
        if name in measures:
            record[f"{name}_kpa"] = 1e-3 * float(measures[name])
    if specimen.cross_section == "circle" and specimen.grading:
        sizes, passing = specimen.grading
        sampled = np.concatenate([[0.0], np.cumsum(mass_fractions(2.0 * radius, sizes))])
        record.update(
            seed=specimen.seed,
            grading_size_mm=[1e3 * size for size in sizes],
            grading_percent_passing=[100.0 * value for value in passing],
            sampled_percent_passing=[float(100.0 * value) for value in sampled],
        )
    return record


def results_datasets(records: dict, shear_start: dict, metadata: dict):
    """(shear dataset or None, consolidation dataset) from the records of the three phases (module docstring).

    ``records`` maps each of :data:`PHASES` to a list of chunk dicts; ``shear_start`` holds the height and
    volume at the start of shearing (strains are rebased on them); ``metadata`` becomes the attributes.
    """
    consolidation = records_to_dataset(join_records(records["consolidation"]), attrs=metadata)
    shear = join_records(records["shear_fine"] + records["shear_coarse"])
    if not shear:
        return None, consolidation
    # The end of consolidation is the shearing's first record (strain 0: the "initial" state of Table 3).
    last = {name: value[-1:] for name, value in join_records(records["consolidation"]).items()}
    shear = {name: np.concatenate([last[name], value]) for name, value in shear.items()}
    shear = rebase_to_shear_start(shear, shear_start)
    shear.update(analysis.derived_quantities(shear))
    return records_to_dataset(shear, attrs=metadata), consolidation
