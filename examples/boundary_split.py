"""The boundary split: how much of a membrane specimen's φ' is its boundary: the membrane's, the specimen's.

Three cells on the same spheres (equal 25 mm spheres or the ballast grading, φ_μ = 25°, k_n = 1e7 N/m,
k_t = k_n/2, 2650 kg/m³, Cundall local damping 0.3, I = 1e-3, σc 10/40/100 kPa, to 10 % axial strain):

1. the membrane cell: read from the lab grid (``--lab``, :data:`calibrate.designs.LAB_CALIBRATION`), every
   group of the state whose ``sweep.nc`` exists when the script runs: φ' from the external stresses (ram
   force, cell pressure: what a laboratory measures), the internal ones (the reference study's §4.3: the
   platen's and the membrane's forces on the spheres) and the Love–Weber average over the spheres;
2. the rigid-wall cell (:func:`membrax.triaxial.rigid.rigid_wall_test`) on the same packing as a lab group
   (``--rigid-groups``, built by :func:`membrax.assemble.build_specimen` from the group's configuration),
   consolidated to σc and sheared with symmetric platens after the 1 % ramp, as the membrane cell is: φ'
   from the walls and Love–Weber;
3. the periodic element (:mod:`membrax.triaxial.periodic`): ``--periodic-spheres`` spheres compacted once
   per (state, seed) at :data:`membrax.defaults.COMPACTION_STRESS` (frictionless for dense and ballast,
   the state's compaction friction for loose), consolidated to each σc and sheared: the boundary-free φ'.

For each (state, σc, cell, D_s/D, membrane thickness) it writes the peak φ', the late φ' (the mean over
axial strains ≥ 0.8 × the last, 8–10 %, as docs/validation.md's YADE table) and ε_v at the end
(compression positive), averaged over the seeds with their spread (max − min), to ``boundary_split.csv``;
the split at each D_s/D (gap = external − periodic; membrane part = external − internal; specimen part =
internal − periodic) to ``boundary_split_parts.csv`` and the console; and ``boundary_split.png``.

Each rigid and periodic run's records go to their own ``.npz`` under ``--out``; a rerun reloads them, so an
interrupted script resumes where it stopped (delete a file to rerun that case). The periodic arm also
checkpoints within a run (:class:`membrax.triaxial.stage_checkpoint.StageCheckpoint`), every
``--checkpoint-seconds``: a compaction to ``periodic_<state>_s<seed>_packing.ckpt`` (its overload and
unloading stages), a test to ``periodic_<state>_s<seed>_<σc>kpa.ckpt`` (its consolidation and shear);
rerun, it resumes from there, losing only the minutes since the last checkpoint, and prints a line per
checkpoint (stage, step). A checkpoint is deleted once its ``.npz`` is written; a checkpoint of other
settings (another ``--periodic-spheres``, ``--x64``) is refused with its name: delete it to start afresh.

Run: ``python examples/boundary_split.py [--out results/boundary_split] [--states dense,loose,ballast]
[--pressures 10,40,100] [--seeds 0,2] [--periodic-spheres 500] [--skip-rigid] [--skip-periodic]
[--keep calibrate/data/boundary_split.csv] [--checkpoint-seconds 120] [--x64]``.
Cost, measured on 2 CPU cores shared with other jobs (load average 8–10), float32: the periodic dense
compaction of 500 spheres 1,053 s per seed; a periodic case 150–489 s (10 kPa the slowest: the strain rate
grows with √σc); a rigid case of the 150 × 375 mm mould (470 spheres) 73–320 s, of the loose 150 × 300 mm
one (376 spheres) 82–274 s. The ballast mould has 1,853 spheres (not run here).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from calibrate.grid import find_sweep

#: Lab-grid groups of each state (the number in a name: the mould diameter over the largest sieve).
MEMBRANE_GROUPS = {
    "dense": ("e6", "e6_h25", "e8", "e10", "e12"),
    "loose": ("e6_loose",),
    "ballast": ("g6",),
}

#: The lab group whose packing, configuration and protocol the rigid and periodic arms take, per state.
RIGID_GROUPS = {"dense": "e6_h25", "loose": "e6_loose", "ballast": "g6"}

#: Axial strains at or above this fraction of the last count as "late" (the last fifth of 0–10 %).
LATE_FRACTION = 0.8

#: Seconds between the checkpoints of a periodic compaction or test (at most this much is lost to a kill).
CHECKPOINT_SECONDS = 120.0


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/boundary_split", help="output folder")
    parser.add_argument(
        "--lab",
        default=str(Path(__file__).resolve().parents[1] / "data" / "sweeps" / "lab"),
        help="the lab grid's sweeps: its archive (<group>.nc.gz, the default: the repository's "
        "data/sweeps/lab) or its run folder (<group>/sweep.nc)",
    )
    parser.add_argument("--states", default="dense,loose,ballast")
    parser.add_argument("--pressures", default="10,40,100", help="σc, kPa")
    parser.add_argument("--seeds", default="0,2")
    parser.add_argument("--periodic-spheres", type=int, default=500)
    parser.add_argument(
        "--keep",
        metavar="CSV",
        help="a boundary_split.csv whose rows of the states not run here join the table (e.g. the shipped "
        "calibrate/data/boundary_split.csv, to add one state to it)",
    )
    parser.add_argument(
        "--rigid-groups",
        default=",".join(f"{k}={v}" for k, v in RIGID_GROUPS.items()),
        help="state=group pairs: the lab group each state's rigid cell copies (e.g. dense=e6_h25,dense=e8)",
    )
    parser.add_argument("--skip-rigid", action="store_true")
    parser.add_argument("--skip-periodic", action="store_true")
    parser.add_argument(
        "--reload-only", action="store_true", help="run nothing: tabulate the runs already saved under --out"
    )
    parser.add_argument(
        "--checkpoint-seconds",
        type=float,
        default=CHECKPOINT_SECONDS,
        help="seconds between a periodic run's checkpoints (.ckpt beside its .npz), s",
    )
    parser.add_argument("--x64", action="store_true", help="run the DEM in float64 (default float32)")
    return parser.parse_args(argv)


def summary(axial_strain, angle, volumetric_strain=None) -> dict:
    """Peak φ', late φ' (mean over ε_a ≥ LATE_FRACTION × the last) and ε_v at the last record."""
    axial_strain, angle = np.asarray(axial_strain, float), np.asarray(angle, float)
    late = axial_strain >= LATE_FRACTION * axial_strain[-1]
    out = {"peak": float(np.nanmax(angle)), "late": float(np.nanmean(angle[late]))}
    if volumetric_strain is not None:
        out["ev"] = float(np.asarray(volumetric_strain, float)[-1])
    return out


def size_ratio(config) -> float:
    """D_s/D of a configuration (a mapping or a ``TriaxialConfig``).

    D is the particle size ``membrax correct`` takes (:func:`membrax.config.characteristic_size_mm`: d50 of
    a grading, else the diameter), so a user's D_s/D finds its row: the ballast group g6 is 6 largest sieves
    across, D_s/d50 = 9.3.
    """
    from membrax.config import characteristic_size_mm, config_to_dict

    values = config if isinstance(config, dict) else config_to_dict(config)
    return float(values["specimen_diameter_mm"]) / characteristic_size_mm(values)


def group_config(lab: Path, group: str):
    """The group's configuration: its sweep's base configuration, or the design's where it has not run."""
    from membrax.config import TriaxialConfig
    from membrax.io import read_results

    sweep = find_sweep(lab, group)
    if sweep is not None:
        return TriaxialConfig(**json.loads(read_results(sweep).attrs["base_config"]))
    from calibrate.designs import LAB_CALIBRATION, specimen_fields

    return TriaxialConfig(name=f"calibration_{group}", **specimen_fields(LAB_CALIBRATION[group][0]))


# ---------------------------------------------------------------------------------------------- membrane


def membrane_rows(lab: Path, states, pressures, seeds):
    """Per-seed summaries of the lab grid's members, and the groups found and missing."""
    from membrax.io import read_results

    rows, used, missing = [], [], []
    for state in states:
        for base in MEMBRANE_GROUPS[state]:
            for seed in seeds:
                group = f"{base}_s{seed}"
                sweep = find_sweep(lab, group)
                if sweep is None:
                    missing.append(group)
                    continue
                used.append(group)
                with read_results(sweep) as ds:
                    config = json.loads(ds.attrs["base_config"])
                    for pressure in pressures:
                        if pressure not in ds.cell_pressure_kpa.values:
                            continue
                        for thickness in ds.membrane_thickness_mm.values:
                            member = ds.sel(
                                cell_pressure_kpa=pressure,
                                membrane_thickness_mm=thickness,
                                membrane_modulus_kpa=config["membrane_modulus_kpa"],
                            )
                            if str(member.status.values) != "completed":
                                continue
                            n = int(member.num_records)
                            strain = member.axial_strain.values[:n]
                            ev = member.volumetric_strain.values[:n]
                            row = {
                                "state": state,
                                "cell": "membrane",
                                "group": base,
                                "d_over_ds": size_ratio(config),
                                "h_over_d": config["specimen_height_mm"] / config["specimen_diameter_mm"],
                                "thickness_mm": float(thickness),
                                "pressure_kpa": float(pressure),
                                "seed": seed,
                            }
                            for key, name in (
                                ("ext", "external_friction_angle_deg"),
                                ("int", "internal_friction_angle_deg"),
                                ("lw", "love_weber_friction_angle_deg"),
                            ):
                                s = summary(strain, member[name].values[:n], ev)
                                row[f"peak_{key}"], row[f"late_{key}"], row["ev"] = (
                                    s["peak"],
                                    s["late"],
                                    s["ev"],
                                )
                            rows.append(row)
    return rows, used, missing


# ------------------------------------------------------------------------------------------------- rigid


def lab_packing(lab: Path, group: str, config):
    """The packing the lab grid's group ran on, and where it came from.

    :func:`membrax.assemble.build_specimen` keys its disk cache by a hash of the compaction's sources, so a
    packing compacted before a change to them (even to a comment) is compacted again under a new name. The
    cache's files carry their seed, sphere count and solid fraction; the one matching the group's sweep
    (``num_particles``, ``solid_fraction``) is the lab grid's packing and is loaded as it is. Without a
    match (or a sweep), ``build_specimen`` compacts it (deterministic: recompactions of one key in the
    cache agree to every printed digit).
    """
    from membrax import assemble, native
    from membrax.io import read_results
    from membrax.spheres.compaction import Compaction

    sweep = find_sweep(lab, group)
    if sweep is not None:
        with read_results(sweep) as ds:
            count = int(np.ravel(ds.num_particles.values)[0])
            fraction = float(np.ravel(ds.solid_fraction.values)[0])
        for path in sorted((native.cache_dir() / "specimens").glob("compaction_*.npz")):
            try:
                with np.load(path) as data:
                    if data["position"].shape[0] != count:
                        continue
                    scalars = json.loads(str(data["scalars"]))
            except (OSError, ValueError, KeyError):  # a file being written, or another kind
                continue
            measures = scalars.get("measures", {})
            if (
                scalars.get("seed") == config.packing_seed
                and abs(measures.get("solid_fraction", 0) - fraction) < 1e-6
            ):
                return Compaction.load(path).specimen(config.particle_grading), f"cache {path.name}"
    return assemble.build_specimen(config), "build_specimen"


def run_rigid(config, specimen, pressure_kpa: float, path: Path) -> dict:
    """One rigid-wall run of ``specimen`` (``config``'s packing) at σc; its records saved to ``path``."""
    from membrax import assemble
    from membrax.spheres.contact import ContactParams
    from membrax.triaxial.rigid import rigid_wall_test

    contact = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    test = rigid_wall_test(
        specimen,
        1e3 * pressure_kpa,
        contact_params=contact,
        damping=assemble.damping_params(config),
        density=config.particle_density_kg_m3,
        dt_safety=config.dt_safety,
    )
    start = time.perf_counter()
    consolidated, consolidation = test.consolidate(
        tolerance=config.consolidation_tolerance, max_steps=config.consolidation_max_steps
    )
    consolidation_seconds = time.perf_counter() - start
    steps0 = int(consolidated.step)
    _, records = test.shear(
        consolidated,
        target_axial_strain=config.target_axial_strain,
        inertial_number=config.inertial_number,
        ramp_strain=config.shear_ramp_strain,
        symmetric=True,
        record_every_fine=config.record_every_fine,
        fine_until_strain=config.fine_until_strain,
        record_every_coarse=config.record_every_coarse,
    )
    seconds = time.perf_counter() - start
    # Strains from the start of shearing (the consolidated state), as the lab grid's records are.
    height0 = float(np.asarray(consolidation.height)[-1, 0])
    volume0 = height0 * float(np.asarray(consolidation.area)[-1, 0])
    height = np.concatenate([[height0], np.asarray(records.height)[:, 0]])
    volume = height * np.concatenate([[volume0 / height0], np.asarray(records.area)[:, 0]])
    out = {
        "axial_strain": 1.0 - height / height0,
        "volumetric_strain": 1.0 - volume / volume0,
        "wall_friction_angle_deg": np.concatenate([[0.0], np.asarray(records.wall_friction_angle)[:, 0]]),
        "love_weber_friction_angle_deg": np.concatenate(
            [[np.nan], np.asarray(records.love_weber_friction_angle)[:, 0]]
        ),
        "wall_radial_stress": np.asarray(records.wall_radial_stress)[:, 0],
        "seconds": seconds,
        "consolidation_seconds": consolidation_seconds,
        "num_particles": specimen.num_particles,
        "consolidation_steps": steps0,
        "shear_steps": int(np.asarray(records.step)[-1, 0]) - steps0,
        "dt": test.dt,
    }
    np.savez(path, **out)
    return out


def rigid_rows(args, lab, states, pressures, seeds, out: Path, times: list):
    rows = []
    for item in args.rigid_groups.split(","):
        state, base = item.split("=")
        if state not in states:
            continue
        for seed in seeds:
            group = f"{base}_s{seed}"
            config = group_config(lab, group)
            specimen = None
            for pressure in pressures:
                path = out / f"rigid_{group}_{pressure:g}kpa.npz"
                if not path.exists():
                    if args.reload_only:
                        continue
                    if specimen is None:
                        start = time.perf_counter()
                        specimen, source = lab_packing(lab, group, config)
                        print(
                            f"{group}: {specimen.num_particles} spheres from {source} "
                            f"({time.perf_counter() - start:.1f} s)",
                            flush=True,
                        )
                    print(f"rigid {group} {pressure:g} kPa ...", flush=True)
                    run_rigid(config, specimen, pressure, path)
                data = np.load(path)
                times.append(_time_row(f"rigid {group} {pressure:g} kPa", data, int(data["num_particles"])))
                wall = summary(
                    data["axial_strain"], data["wall_friction_angle_deg"], data["volumetric_strain"]
                )
                lw = summary(data["axial_strain"], data["love_weber_friction_angle_deg"])
                rows.append(
                    {
                        "state": state,
                        "cell": "rigid",
                        "group": base,
                        "d_over_ds": size_ratio(config),
                        "h_over_d": config.specimen_height_mm / config.specimen_diameter_mm,
                        "thickness_mm": np.nan,
                        "pressure_kpa": pressure,
                        "seed": seed,
                        "peak_ext": wall["peak"],
                        "late_ext": wall["late"],
                        "peak_lw": lw["peak"],
                        "late_lw": lw["late"],
                        "ev": wall["ev"],
                    }
                )
    return rows


# ---------------------------------------------------------------------------------------------- periodic


def report_checkpoint(line: str) -> None:
    """Print a checkpoint's line (stage, step), indented under its run's."""
    print(f"  {line}", flush=True)


def periodic_packing(
    config, spheres: int, seed: int, path: Path, checkpoint_seconds: float = CHECKPOINT_SECONDS
) -> dict:
    """The (state, seed) packing compacted at the moulds' stress in a periodic cell, saved to ``path``.

    The compaction checkpoints to ``path`` with the suffix ``.ckpt`` every ``checkpoint_seconds`` and
    resumes from it (:func:`membrax.triaxial.periodic_packing.compact_periodic`); ``seconds`` counts this
    process's time only (a resumed compaction's earlier processes are not counted).
    """
    from membrax.assemble import damping_params
    from membrax.defaults import COMPACTION_STRESS
    from membrax.spheres.contact import ContactParams
    from membrax.spheres.periodic import sample_element
    from membrax.triaxial.periodic_packing import compact_periodic

    if path.exists():
        return dict(np.load(path))
    # The configuration path's sampler (assemble.build_periodic_test): ``spheres`` of the grading, by mass.
    diameters = sample_element(config.particle_grading, spheres, seed)
    contact = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    start = time.perf_counter()
    test, packed, records = compact_periodic(
        diameters,
        COMPACTION_STRESS,
        friction_coefficient=config.compaction_friction_coefficient,
        seed=seed,
        contact_params=contact,
        damping=damping_params(config),
        density=config.particle_density_kg_m3,
        checkpoint_path=path.with_suffix(".ckpt"),
        checkpoint_every_seconds=checkpoint_seconds,
        report=report_checkpoint,
    )
    out = {
        "fraction": np.asarray(packed.fraction + packed.fraction_compensation, dtype=float),
        "length": np.asarray(packed.box_length, dtype=float),
        "radius": np.asarray(test.particles.radius, dtype=float),
        "solid_fraction": float(np.asarray(records.solid_fraction)[-1]),
        "seconds": time.perf_counter() - start,
    }
    np.savez(path, **out)
    return out


def _time_row(label: str, data, spheres: int) -> tuple:
    """A wall-time table row of one saved run: (label, consolidation s, total s, shear steps, spheres)."""
    return (
        label,
        float(data["consolidation_seconds"]),
        float(data["seconds"]),
        int(data["shear_steps"]),
        spheres,
    )


def run_periodic(
    config, packing: dict, pressure_kpa: float, path: Path, checkpoint_seconds: float = CHECKPOINT_SECONDS
) -> dict:
    """One periodic element test of ``packing`` at σc; its records saved to ``path`` (.npz).

    Its consolidation and shear checkpoint to ``path`` with the suffix ``.ckpt`` every
    ``checkpoint_seconds`` (:class:`membrax.triaxial.stage_checkpoint.StageCheckpoint`: the state, the
    stage, the records so far), and a rerun resumes from there into the remaining steps, to the same
    records as a run straight through; the checkpoint is deleted once ``path`` is written. The seconds
    count every process's time up to its last checkpoint.
    """
    import hashlib

    import jax.numpy as jnp

    from membrax.assemble import damping_params
    from membrax.spheres.contact import ContactParams
    from membrax.theory import mobilised_friction_angle_deg
    from membrax.triaxial.periodic import periodic_test
    from membrax.triaxial.stage_checkpoint import StageCheckpoint

    contact = ContactParams.paper(
        friction_angle_deg=config.friction_angle_deg,
        normal_stiffness=config.particle_stiffness_n_m,
        tangential_stiffness=0.5 * config.particle_stiffness_n_m,
    )
    test = periodic_test(
        jnp.asarray(packing["fraction"], dtype=jnp.zeros(()).dtype),
        packing["length"],
        packing["radius"],
        1e3 * pressure_kpa,
        contact_params=contact,
        damping=damping_params(config),
        density=config.particle_density_kg_m3,
    )
    signature = {
        "packing_sha256": hashlib.sha256(np.ascontiguousarray(packing["fraction"]).tobytes()).hexdigest(),
        "num_spheres": int(packing["radius"].shape[0]),
        "cell_pressure_kpa": float(pressure_kpa),
        "consolidation_tolerance": float(config.consolidation_tolerance),
        "target_axial_strain": float(config.target_axial_strain),
        "inertial_number": float(config.inertial_number),
        "dtype": str(test.initial_state.length.dtype),
    }
    checkpoint = StageCheckpoint(
        path.with_suffix(".ckpt"),
        test,
        ("consolidation", "shear"),
        signature,
        every_seconds=checkpoint_seconds,
        report=report_checkpoint,
    )
    if checkpoint.progress is not None:
        progress = checkpoint.progress
        print(f"  resuming {checkpoint.path.name}: stage {progress.stage}, step {int(progress.state.step)}")
    consolidated, consolidation = checkpoint.consolidate(
        "consolidation", test, tolerance=config.consolidation_tolerance
    )
    # The consolidated state's step (its last record's: consolidation stops on a record; ``consolidated``
    # is the checkpoint's state where shearing resumes).
    steps0 = int(np.asarray(consolidation.step)[-1])
    _, records = checkpoint.shear(
        "shear",
        test,
        consolidated,
        target_axial_strain=config.target_axial_strain,
        inertial_number=config.inertial_number,
    )
    consolidation_seconds = checkpoint.stage_seconds["consolidation"]
    seconds = checkpoint.elapsed_seconds
    angle = np.asarray(mobilised_friction_angle_deg(records.axial_stress, records.lateral_stress))
    out = {
        "axial_strain": np.concatenate([[0.0], np.asarray(records.axial_strain)]),
        "volumetric_strain": np.concatenate([[0.0], np.asarray(records.volumetric_strain)]),
        "love_weber_friction_angle_deg": np.concatenate([[np.nan], angle]),
        "solid_fraction": float(np.asarray(records.solid_fraction)[0]),
        "seconds": seconds,
        "consolidation_seconds": consolidation_seconds,
        "shear_steps": int(np.asarray(records.step)[-1]) - steps0,
    }
    np.savez(path, **out)
    checkpoint.remove()
    return out


def periodic_rows(args, lab, states, pressures, seeds, out: Path, times: list):
    rows = []
    groups = dict(item.split("=") for item in args.rigid_groups.split(","))
    for state in states:
        for seed in seeds:
            config = group_config(lab, f"{groups.get(state, RIGID_GROUPS[state])}_s{seed}")
            if args.reload_only and not (out / f"periodic_{state}_s{seed}_packing.npz").exists():
                continue
            packing = periodic_packing(
                config,
                args.periodic_spheres,
                seed,
                out / f"periodic_{state}_s{seed}_packing.npz",
                args.checkpoint_seconds,
            )
            for pressure in pressures:
                path = out / f"periodic_{state}_s{seed}_{pressure:g}kpa.npz"
                if not path.exists():
                    if args.reload_only:
                        continue
                    print(f"periodic {state} seed {seed} {pressure:g} kPa ...", flush=True)
                    run_periodic(config, packing, pressure, path, args.checkpoint_seconds)
                data = np.load(path)
                times.append(
                    _time_row(
                        f"periodic {state} s{seed} {pressure:g} kPa", data, int(packing["radius"].shape[0])
                    )
                )
                lw = summary(
                    data["axial_strain"], data["love_weber_friction_angle_deg"], data["volumetric_strain"]
                )
                rows.append(
                    {
                        "state": state,
                        "cell": "periodic",
                        "group": "periodic",
                        "d_over_ds": 0,
                        "h_over_d": np.nan,
                        "thickness_mm": np.nan,
                        "pressure_kpa": pressure,
                        "seed": seed,
                        "peak_lw": lw["peak"],
                        "late_lw": lw["late"],
                        "ev": lw["ev"],
                        "solid_fraction_10kpa": float(packing["solid_fraction"]),
                    }
                )
    return rows


# ----------------------------------------------------------------------------------------------- summary

VALUES = ("peak_ext", "peak_int", "peak_lw", "late_ext", "late_int", "late_lw", "ev")
KEYS = ("state", "pressure_kpa", "cell", "group", "d_over_ds", "h_over_d", "thickness_mm")


def seed_means(rows):
    """Rows averaged over seeds (value) with the spread (max − min) of each value and the seeds used."""
    import pandas as pd

    frame = pd.DataFrame(rows)
    for name in VALUES:
        if name not in frame:
            frame[name] = np.nan
    keyed = frame.fillna({"thickness_mm": -1.0, "h_over_d": -1.0})
    out = []
    for key, part in keyed.groupby(list(KEYS), sort=True):
        row = dict(zip(KEYS, key, strict=True))
        row["thickness_mm"] = np.nan if row["thickness_mm"] < 0 else row["thickness_mm"]
        row["h_over_d"] = np.nan if row["h_over_d"] < 0 else row["h_over_d"]
        row["seeds"] = "+".join(str(s) for s in sorted(part.seed))
        for name in VALUES:
            row[name] = float(part[name].mean())
            row[f"{name}_spread"] = float(part[name].max() - part[name].min()) if len(part) > 1 else np.nan
        out.append(row)
    return pd.DataFrame(out)


def kept_rows(path: Path, states, table):
    """``table`` after the rows of ``path`` (a ``boundary_split.csv``) whose state was not run here."""
    import pandas as pd

    previous = pd.read_csv(path, dtype={"seeds": str})
    missing = sorted(set(table.columns) ^ set(previous.columns))
    if missing:
        raise SystemExit(f"--keep {path}: its columns differ from this script's in {', '.join(missing)}")
    kept = previous[~previous.state.isin(states)]
    print(f"kept from {path}: {len(kept)} rows of {', '.join(sorted(set(kept.state))) or 'no state'}")
    merged = pd.concat([kept, table[previous.columns]], ignore_index=True)
    return merged.sort_values(list(KEYS), kind="stable", ignore_index=True)


def split_table(table):
    """gap = external − periodic, membrane = external − internal, specimen = internal − periodic."""
    import pandas as pd

    rows = []
    for _, part in table.groupby(["state", "pressure_kpa"]):
        periodic = part[part.cell == "periodic"]
        base = {
            stage: float(periodic[f"{stage}_lw"].iloc[0]) if len(periodic) else np.nan
            for stage in ("peak", "late")
        }
        for _, row in part[part.cell != "periodic"].iterrows():
            item = {
                k: row[k] for k in ("state", "pressure_kpa", "cell", "group", "d_over_ds", "thickness_mm")
            }
            for stage in ("peak", "late"):
                ext, internal = row[f"{stage}_ext"], row[f"{stage}_int"]
                item[f"{stage}_gap"] = ext - base[stage]
                item[f"{stage}_membrane"] = ext - internal
                item[f"{stage}_specimen"] = internal - base[stage]
            rows.append(item)
    return pd.DataFrame(rows)


def figure(table, path: Path):
    """Peak and late φ' against D/D_s (particle over specimen diameter), one column per state, σc as colour.

    D/D_s = 0 is the periodic element.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    states = [state for state in MEMBRANE_GROUPS if state in set(table.state)]
    pressures = sorted(set(table.pressure_kpa))
    palette = ("tab:blue", "tab:orange", "tab:red", "tab:green", "tab:purple")
    colours = dict(zip(pressures, palette[: len(pressures)], strict=True))
    fig, axes = plt.subplots(2, len(states), figsize=(4.2 * len(states), 7.5), squeeze=False, sharex=True)
    markers = {
        ("membrane", "ext"): ("o", "membrane, external"),
        ("membrane", "int"): ("s", "membrane, internal"),
        ("membrane", "lw"): ("^", "membrane, Love–Weber"),
        ("rigid", "ext"): ("D", "rigid walls, walls"),
        ("rigid", "lw"): ("v", "rigid walls, Love–Weber"),
        ("periodic", "lw"): ("*", "periodic, Love–Weber"),
    }
    for column, state in enumerate(states):
        for r, stage in enumerate(("peak", "late")):
            ax = axes[r, column]
            part = table[table.state == state]
            for (cell, kind), (marker, _) in markers.items():
                sub = part[part.cell == cell]
                for _, row in sub.iterrows():
                    value = row[f"{stage}_{kind}"]
                    if not np.isfinite(value):
                        continue
                    x = 0.0 if cell == "periodic" else 1.0 / row.d_over_ds
                    # Thin membranes drawn open; a small shift keeps cells at one D_s/D apart.
                    shift = {"membrane": 0.0, "rigid": 0.006, "periodic": 0.0}[cell]
                    thin = cell == "membrane" and row.thickness_mm < 4.0
                    ax.plot(
                        x + shift,
                        value,
                        marker,
                        color=colours[row.pressure_kpa],
                        mfc="none" if thin else colours[row.pressure_kpa],
                        ms=9 if marker == "*" else 6,
                    )
            ax.set(
                title=f"{state}, {stage}",
                xlabel="D/D_s, particle / specimen diameter (0: periodic)",
                ylabel=f"{stage} φ' (°)",
            )
            ax.grid(alpha=0.3)
    handles = [
        plt.Line2D([], [], ls="", marker=m, color="k", label=label) for (m, label) in markers.values()
    ] + [plt.Line2D([], [], ls="-", color=colours[p], label=f"σc = {p:g} kPa") for p in pressures]
    handles.append(
        plt.Line2D([], [], ls="", marker="o", mfc="none", color="k", label="membrane ≤ 2.5 mm (open)")
    )
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, bbox_to_anchor=(0.5, -0.06))
    fig.tight_layout()
    fig.savefig(path, dpi=130, bbox_inches="tight")


def main(argv=None) -> None:
    args = parse_args(argv)
    import jax

    if args.x64:
        jax.config.update("jax_enable_x64", True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lab = Path(args.lab)
    states = args.states.split(",")
    pressures = [float(p) for p in args.pressures.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    rows, used, missing = membrane_rows(lab, states, pressures, seeds)
    print(f"membrane groups used: {', '.join(used) or 'none'}")
    print(f"membrane groups missing (no sweep.nc): {', '.join(missing) or 'none'}")
    times = []
    if not args.skip_periodic:
        rows += periodic_rows(args, lab, states, pressures, seeds, out, times)
    if not args.skip_rigid:
        rows += rigid_rows(args, lab, states, pressures, seeds, out, times)
    table = seed_means(rows)
    if args.keep:
        table = kept_rows(Path(args.keep), states, table)
    table.to_csv(out / "boundary_split.csv", index=False, float_format="%.4f")
    parts = split_table(table)
    parts.to_csv(out / "boundary_split_parts.csv", index=False, float_format="%.4f")
    figure(table, out / "boundary_split.png")
    with open(out / "groups.txt", "w") as handle:
        handle.write(f"used {' '.join(used)}\nmissing {' '.join(missing)}\n")
    print(f"\n{'run':<34}{'consol. s':>10}{'total s':>9}{'shear steps':>12}{'spheres':>9}")
    for name, consolidation, seconds, steps, count in times:
        print(f"{name:<34}{consolidation:>10.0f}{seconds:>9.0f}{steps:>12d}{count:>9d}")

    def two_places(value):
        return f"{value:.2f}"

    with_pd_options(lambda: print("\n", table.to_string(index=False, float_format=two_places)))
    with_pd_options(
        lambda: print("\nsplit (degrees)\n", parts.to_string(index=False, float_format=two_places))
    )


def with_pd_options(fn):
    import pandas as pd

    with pd.option_context("display.width", 250, "display.max_columns", 40, "display.max_rows", 500):
        fn()


if __name__ == "__main__":
    main()
