"""A batch's records: joined, one member's taken, kept in a checkpoint, and made its results.

Contract. Records come from :func:`membrax.runner.run_group` as chunk dicts by phase (each of
:data:`membrax.triaxial.protocol.PHASES` a list of dicts of stacked arrays, a ``valid`` mask per member).
:func:`join_records` joins them along time, :func:`member_chunk_records` takes one member's,
:func:`records_to_host`/:func:`records_from_host` turn them into a checkpoint's host values and back,
:func:`rebase_to_shear_start` counts strains, area and stresses from the start of shearing (the paper's
Table 3), and :func:`results_datasets` with :func:`run_metadata` makes a run's shear and consolidation
datasets. NumPy on the host only: nothing here runs in a compiled step.
"""

from __future__ import annotations

import platform

import jax
import numpy as np

from membrax import __version__, theory
from membrax.assemble import RunSettings
from membrax.io import records_to_dataset
from membrax.membrane.records import right_cylinder_stresses
from membrax.spheres.grading import mass_fractions
from membrax.triaxial import analysis
from membrax.triaxial.protocol import CONSOLIDATION_RECORD_EVERY, PHASES

__all__ = [
    "join_records",
    "member_chunk_records",
    "rebase_to_shear_start",
    "records_from_host",
    "records_to_host",
    "results_datasets",
    "run_metadata",
    "specimen_metadata",
]


def join_records(chunks: list[dict], axis: int = 0) -> dict:
    """Join chunk dicts of records along their time axis (0 for one member, 1 for stacked members)."""
    if not chunks:
        return {}
    return {name: np.concatenate([chunk[name] for chunk in chunks], axis=axis) for name in chunks[0]}


def rebase_to_shear_start(records: dict, start: dict) -> dict:
    """Strains, area and stresses counted from the start of shearing (the paper's Table 3 and figures).

    The area A = A₀ (1 − ε_v)/(1 − ε_a) starts from the platen area A₀ at the start of shearing
    (:func:`membrax.membrane.records.right_cylinder_stresses`), so at ε_a = 0 the external σ1 is the ram
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


def records_to_host(records: dict) -> dict:
    """A batch's records by phase (stacked chunk dicts) as a checkpoint's host values, each phase joined."""
    host = {}
    for phase in PHASES:
        joined = join_records(records[phase], axis=1)
        host[f"names_{phase}"] = list(joined)
        host.update({f"rec_{phase}_{name}": value for name, value in joined.items()})
    return host


def records_from_host(host: dict) -> dict:
    """The records by phase a checkpoint's host values hold (:func:`records_to_host`): one chunk each."""
    records = {}
    for phase in PHASES:
        names = host.get(f"names_{phase}", [])
        if names:
            records[phase] = [{name: np.asarray(host[f"rec_{phase}_{name}"]) for name in names}]
    return records


def run_metadata(settings: RunSettings, test, records, build_seconds, elapsed) -> dict:
    """The attributes of a run's datasets: configuration, version, sizes, Δt, steps, timings, machine.

    ``settings``: the member's :class:`membrax.assemble.RunSettings`; ``records``: its records by phase
    (:func:`member_chunk_records`).
    """
    consolidation = join_records(records["consolidation"])
    shear_steps = (
        sum(len(c["step"]) for c in records["shear_fine"]) * settings.loading.record_every_fine
        + sum(len(c["step"]) for c in records["shear_coarse"]) * settings.loading.record_every_coarse
    )
    return {
        "membrax_version": __version__,
        "config": settings.provenance,
        "num_particles": int(test.particles.num_particles),
        "num_membrane_nodes": int(test.mesh.num_nodes),
        "num_triangles": int(test.mesh.triangles.shape[0]),
        "dt_s": test.dt,
        "critical_dt_s": {key: float(value) for key, value in test.critical_dt.items()},
        "consolidation_steps": int(len(consolidation.get("step", [])) * CONSOLIDATION_RECORD_EVERY),
        "consolidation_tolerance": settings.consolidation_tolerance,
        "shear_steps": int(shear_steps),
        "build_s": build_seconds,
        "run_s": elapsed,
        "dtype": settings.precision,
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
        "specimen": specimen_metadata(test.specimen),
    }


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
