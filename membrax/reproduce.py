"""The paper's whole study by one call: Table 1 as one sweep, then Tables 2–3 and Figs 5–9.

Contract. :func:`reproduce` runs the paper's Table 1 grid (10, 40, 100 kPa × 2.5, 3.33, 5 mm,
:data:`membrax.paper.TABLE_1_GRID`) with :func:`membrax.sweep.run_sweep` on the specimen of ``size`` and
writes into ``folder``:

- ``sweep.nc``, ``sweep_consolidation.nc``, ``summary.csv`` (the sweep's files);
- ``table2.csv``/``.md`` (peak φ' external and internal) and ``table3.csv``/``.md`` (initial σ3, σ1
  external and internal, and the additional membrane stresses), the paper's values beside ours with the
  differences (:mod:`membrax.paper`);
- ``fig5_friction.png`` … ``fig8_radial_ratio.png`` for the 10 kPa / 5 mm case
  (:func:`membrax.plots.save_test_figures`) and ``fig9_indentation.png`` (Molenkamp & Luger's
  indentation ratio, C = 0.275, and −(σ1,int/σ1,ext − 1) against cell pressure, ours and the paper's);
- ``reproduction.md``: both tables, the size, the timings and the figure list.

Sizes (:data:`SIZES`). ``small``: 6 spheres across and 10 layers (~330 spheres, a membrane of edge D/3,
I = 5e-3) — the demo's specimen, 2 min 52 s on 2 CPU cores for all nine cases;
``paper``: the paper's 10 × 25 specimen (1,816 spheres, edge D/5, I = 1e-3), a CPU command: 13 min 46 s
and 18 min 13 s on two machines' 2 cores with the compiled kernels of :mod:`membrax.native` (float64,
2026-12-07; peak RSS 2.9–3.0 GB). A faster coarse phase (``overrides={"coarse_inertial_number": 5e-3}``)
leaves Tables 2–3 bit-identical in about half the time but raises φ' after 1 % strain by 2.4–4.3° on
average (docs/loading_rate.md), so it is not the preset.
Random specimens (``packing="random"``, ``membrax reproduce --packing random``; the paper's open
question, its §6). Every case of Table 1 on ``seeds`` random packings (:data:`RANDOM_SIZES`: ``small`` in
a 150 × 250 mm mould, ``paper`` in 250 × 500 mm), the packing seed a third grid axis: equal 25 mm spheres
or railway ballast's grading or a uniform narrow one scaled to a largest sieve of D_s/6 (``grading``,
:func:`random_fields`), compacted without friction, medium or loose (``state``). Written into
``results_reproduce_{size}_random[_ballast|_narrow][_medium|_loose]``: the sweep's files,
``random_table2``/``random_table3`` (``.csv``/``.md``; :func:`membrax.paper.write_spread_tables`: per case
mean ± s.d. (min…max) over the seeds beside the FCC reproduction of the same size, read from
``reference_folder``'s ``sweep.nc`` when it exists, and the paper's), Figs 5–8 of the 10 kPa / 5 mm case
for each seed (``seed{k}_fig5_friction.png`` …), ``fig9_indentation.png`` (Fig. 9: the mean over the seeds
beside FCC, :func:`seed_mean_fig9`) and ``reproduction.md``. The command line adds the paper's
correlations for both families (:mod:`calibrate.correlations`: ``correlations.md/.csv/.png``). On 2 CPU
cores: ``small`` 5 min for 3 seeds (27 members), ballast one seed 7 min dense, 21 min loose; ``paper``
about 22 min per seed of equal spheres (44 min 27 s for 2, 2026-11-28).

Both use the paper's materials (25 mm granite spheres, μ = tan 25°, latex 1400 kPa without bending
stiffness) and protocol (platens ramped to full speed at 1 % strain, both moving,
:mod:`membrax.triaxial.membrane_cell`). Both run in float64 and end consolidation at an unbalanced-force
ratio of 1e-3 (:data:`TABLE_3_PRECISION`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from membrax import paper, plots
from membrax.assemble import report_values
from membrax.config import (
    BALLAST_GRADING_MM,
    DEMO_CONFIG,
    DEMO_RANDOM_CONFIG,
    TriaxialConfig,
    scaled_grading,
    with_overrides,
)
from membrax.defaults import COMPACTION_FRICTION_DEG
from membrax.io.results import read_results
from membrax.sweep import member_records, run_sweep

__all__ = [
    "BALLAST_LARGEST_FRACTION",
    "NARROW_GRADING",
    "RANDOM_GRADINGS",
    "RANDOM_SIZES",
    "SIZES",
    "TABLE_3_PRECISION",
    "default_folder",
    "fcc_cases",
    "fcc_dataset",
    "random_cases",
    "random_fields",
    "seed_mean_fig9",
    "reproduce",
]

#: Table 3 is read at the end of consolidation, which stops at an unbalanced-force ratio of 1e-3. float32
#: cannot get there with the membrane: its force round-off floors the ratio at ~1e-2 at 10 kPa (3e-3 at
#: 40, 1.2e-3 at 100 kPa, paper size), so the reproduction runs in float64, ~15 % slower per step.
TABLE_3_PRECISION = dict(float64=True, consolidation_tolerance=1e-3)

#: The two specimen sizes of ``membrax reproduce`` (configuration fields over the paper's defaults).
SIZES = {
    # The demo's specimen, membrane and rate (the grid sets pressure and thickness).
    "small": {
        **{
            key: value
            for key, value in DEMO_CONFIG.items()
            if key not in ("name", "cell_pressure_kpa", "membrane_thickness_mm", "target_axial_strain")
        },
        **TABLE_3_PRECISION,
    },
    "paper": dict(chunk_steps=5000, checkpoint_every_chunks=5, **TABLE_3_PRECISION),
}

#: ``packing="random"``'s changes to :data:`SIZES`: equal spheres compacted without friction in a mould of
#: the FCC specimen's size class: ``small`` the random demo's 150 × 250 mm (about 313 spheres, 6 diameters
#: across as the FCC demo), ``paper`` the paper's 250 × 500 mm (about 1,740 spheres).
RANDOM_SIZES = {
    "small": {key: value for key, value in DEMO_RANDOM_CONFIG.items() if key != "name"},
    "paper": dict(packing="random", specimen_diameter_mm=250.0, specimen_height_mm=500.0),
}

#: ``grading="ballast"``'s largest sieve as a fraction of the mould's diameter: 1/6, Marachi's limit for
#: laboratory specimens (the paper's §1), the cheapest end of the 1/6–1/10 used in practice (a smaller
#: fraction means more spheres and, the smallest sphere being smaller, a shorter time step).
BALLAST_LARGEST_FRACTION = 1.0 / 6.0

#: The gradings of ``membrax reproduce --packing random --grading``: ``equal`` spheres of the particle
#: diameter; railway ``ballast`` (:data:`membrax.config.BALLAST_GRADING_MM`) scaled parallel so that its
#: largest sieve is :data:`BALLAST_LARGEST_FRACTION` of the mould's diameter (25 mm in the small mould,
#: 41.7 mm in the paper's); or a uniform ``narrow`` one (:data:`NARROW_GRADING`), scaled the same way.
RANDOM_GRADINGS = ("equal", "ballast", "narrow")

#: ``grading="narrow"``: a uniformly graded material between 0.8 and 1 of its largest sieve, straight in
#: mass between them (a single-sized aggregate's sieve band, e.g. 20–25 mm; coefficient of uniformity
#: d60/d10 = 1.14), the second grading shape of the calibration besides ballast's wide one (1.43).
NARROW_GRADING = ((0.8, 0.0), (1.0, 100.0))


def random_fields(
    size: str, grading: str = "equal", state: str = "dense", mould_mm: tuple[float, float] | None = None
) -> dict:
    """The configuration fields of a random reproduction: :data:`SIZES`, :data:`RANDOM_SIZES`, grading, state.

    Args:
      size: ``"small"`` or ``"paper"``.
      grading: one of :data:`RANDOM_GRADINGS`.
      state: a key of :data:`membrax.defaults.COMPACTION_FRICTION_DEG` (``"dense"``, ``"medium"``,
        ``"loose"``).
      mould_mm: (diameter, height) mm of another mould than the size's (a ballast grading is scaled to it).

    Raises:
      ValueError: an unknown size, grading or state, named with the choices.
    """
    if size not in SIZES:
        raise ValueError(f"size = {size!r}; choose one of {sorted(SIZES)}.")
    if grading not in RANDOM_GRADINGS:
        raise ValueError(f"grading = {grading!r}; choose one of {list(RANDOM_GRADINGS)}.")
    if state not in COMPACTION_FRICTION_DEG:
        raise ValueError(f"state = {state!r}; choose one of {list(COMPACTION_FRICTION_DEG)}.")
    fields = {**SIZES[size], **RANDOM_SIZES[size], "compaction_friction_deg": COMPACTION_FRICTION_DEG[state]}
    if mould_mm is not None:
        fields.update(specimen_diameter_mm=float(mould_mm[0]), specimen_height_mm=float(mould_mm[1]))
    if grading != "equal":
        largest_mm = BALLAST_LARGEST_FRACTION * fields["specimen_diameter_mm"]
        shape = BALLAST_GRADING_MM if grading == "ballast" else NARROW_GRADING
        fields["grading"] = scaled_grading(shape, largest_mm)
    return fields


def default_folder(size: str, packing: str = "fcc", grading: str = "equal", state: str = "dense") -> Path:
    """Where a reproduction writes: ``results_reproduce_{size}``, suffixed for a random packing.

    The suffix: ``_random``, then ``_ballast`` or ``_narrow`` for a grading, ``_medium`` or ``_loose`` for a
    state.
    """
    suffix = ""
    if packing == "random":
        suffix = (
            "_random"
            + ("" if grading == "equal" else f"_{grading}")
            + ("" if state == "dense" else f"_{state}")
        )
    return Path(f"results_reproduce_{size}{suffix}")


def reproduce(
    size: str = "small",
    folder=None,
    resume: bool = False,
    progress: bool = True,
    num_devices: int | None = None,
    overrides: dict | None = None,
    scheduler=None,
    members_per_task: int | None = None,
    packing: str = "fcc",
    seeds: int = 3,
    reference_folder=None,
    grading: str = "equal",
    state: str = "dense",
) -> dict:
    """Run the paper's Table 1 and write its Tables 2–3 and Figs 5–9 (module docstring).

    Args:
      size: ``"small"`` or ``"paper"`` (:data:`SIZES`).
      folder: output folder (default ``results_reproduce_{size}``).
      resume: continue an interrupted reproduction from its checkpoints.
      progress: progress bars.
      num_devices: devices to shard the batch over (default all).
      overrides: further configuration fields (e.g. ``{"target_axial_strain": 0.05}``).
      scheduler: run the members on Dask (:func:`membrax.sweep.run_sweep`); None: in this process.
      members_per_task: with ``scheduler``, members per task.
      packing: ``"fcc"`` (the paper's lattice) or ``"random"`` (:data:`RANDOM_SIZES`: every case on
        ``seeds`` random specimens, Tables 2–3 as spreads over them beside the FCC lattice's and the
        paper's).
      seeds: with ``packing="random"``, the packing seeds 0 … seeds − 1 (at least 1; 3 by default).
      reference_folder: with ``packing="random"``, an FCC reproduction of the same size
        (``results_reproduce_{size}`` by default) whose ``sweep.nc``, when present, gives the FCC columns.
      grading: with ``packing="random"``, ``"equal"`` spheres or scaled railway ``"ballast"``
        (:func:`random_fields`).
      state: with ``packing="random"``, ``"dense"`` (compacted without friction) or ``"loose"``.

    Returns:
      ``{"folder", "sweep" (the SweepResult), "files", "seconds"}``; with ``packing="random"`` also
      ``"reference"`` (the FCC cases, or None) and ``"reference_dataset"`` (its ``sweep.nc``, or None).

    Raises:
      ValueError: an unknown size, packing, grading or state, or a bad number of seeds.
    """
    if size not in SIZES:
        raise ValueError(f"size = {size!r}; choose one of {sorted(SIZES)}.")
    if packing not in ("fcc", "random"):
        raise ValueError(f"packing = {packing!r}; choose 'fcc' or 'random'.")
    if packing == "random" and (isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1):
        raise ValueError(f"seeds = {seeds!r}; give the number of random specimens per case, at least 1.")
    started = time.perf_counter()
    random = packing == "random"
    suffix = default_folder(size, packing, grading, state).name[len(f"results_reproduce_{size}") :]
    folder = Path(folder) if folder is not None else default_folder(size, packing, grading, state)
    fields = random_fields(size, grading, state) if random else SIZES[size]
    base = with_overrides(TriaxialConfig(name=f"reproduce_{size}{suffix}", **fields), **(overrides or {}))
    result = run_sweep(
        base,
        {**paper.TABLE_1_GRID, "packing_seed": tuple(range(seeds))} if random else None,
        folder,
        resume=resume,
        progress=progress,
        num_devices=num_devices,
        scheduler=scheduler,
        members_per_task=members_per_task,
    )
    values = report_values(base)
    if random:
        return _random_outputs(result, values, size, folder, resume, reference_folder, started)
    dataset = result.dataset
    cases = fcc_cases(dataset)
    files = dict(result.files)
    files.update(paper.write_tables(cases, folder, particle_radius=values["particle_radius"]))
    files["figures"] = plots.save_test_figures(cases[(10.0, 5.0)], folder) if (10.0, 5.0) in cases else []
    diameter_mm = 1e3 * values["particle_diameter"]
    ours = paper.fig9_data(
        cases, particle_diameter_mm=diameter_mm, membrane_modulus_kpa=values["membrane_modulus_kpa"]
    )
    files["fig9"] = plots.save_fig9(ours, folder, paper=paper.paper_fig9_data())
    seconds = time.perf_counter() - started
    # A resumed call times only its own part of the run.
    timed = "this call (resumed from any checkpoints) ran the sweep in" if resume else "the sweep ran in"
    text = [
        f"# membrax reproduction ({size})\n",
        f"Specimen {values['particles_across']} × {values['layers']} layers, "
        f"membrane edge D/{values['membrane_edges_per_diameter']:g}, "
        f"I = {values['inertial_number']:g}"
        + (
            f" (then {values['coarse_inertial_number']:g} after {100 * values['fine_until_strain']:g} %)"
            if values["coarse_inertial_number"]
            else ""
        )
        + f", to {100 * values['target_axial_strain']:g} % axial strain, "
        f"{values['precision']}; {timed} {result.seconds:.0f} s, "
        f"everything in {seconds:.0f} s.\n",
        "Members' consolidation steps (rows σc, columns t_m):\n",
        "```\n" + str(dataset["consolidation_steps"].values.astype(int)) + "\n```\n",
        (folder / "table2.md").read_text(),
        (folder / "table3.md").read_text(),
        "Figures: " + ", ".join(p.name for p in [*files["figures"], files["fig9"]]) + "\n",
    ]
    (folder / "reproduction.md").write_text("\n".join(text))
    files["report"] = folder / "reproduction.md"
    return {"folder": folder, "sweep": result, "files": files, "seconds": seconds}


def _spheres_words(values: dict) -> str:
    """The spheres of a random reproduction in words: equal ones, or the grading's sieves and d50."""
    if not values["grading"]:
        return f"equal {1e3 * values['particle_diameter']:g} mm spheres"
    sieves = ", ".join(f"{size:.3g} mm {percent:g} %" for size, percent in values["grading"])
    return (
        f"spheres graded as scaled railway ballast (percent passing by mass: {sieves}; d50 "
        f"{values['characteristic_size_mm']:.3g} mm)"
    )


def seed_mean_fig9(per_seed: list) -> dict:
    """The mean over seeds of :func:`membrax.paper.fig9_data` (each seed's own dict, same theory columns).

    A thickness whose pressures differ between seeds (a failed member) is averaged over the seeds that
    have the first seed's pressures.
    """
    mean = {}
    for thickness, first in per_seed[0].items():
        same = [
            seed[thickness]
            for seed in per_seed
            if thickness in seed
            and np.array_equal(seed[thickness]["cell_pressure_kpa"], first["cell_pressure_kpa"])
        ]
        ratios = np.mean([seed["negative_relative_axial_stress_ratio"] for seed in same], axis=0)
        mean[thickness] = {**first, "negative_relative_axial_stress_ratio": ratios}
    return mean


def random_cases(dataset) -> dict:
    """``{seed: {(cell_pressure_kpa, membrane_thickness_mm): shear records}}`` of a random reproduction.

    Members that failed (``status`` other than completed) are left out; a seed with none left is dropped.
    """
    by_seed = {}
    for seed in dataset["packing_seed"].values:
        cases = {}
        for pressure in dataset["cell_pressure_kpa"].values:
            for thickness in dataset["membrane_thickness_mm"].values:
                where = dict(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness, packing_seed=seed)
                if str(dataset["status"].sel(**where).values) != "completed":
                    continue
                cases[(float(pressure), float(thickness))] = member_records(dataset, **where)
        if cases:
            by_seed[int(seed)] = cases
    return by_seed


def fcc_dataset(folder):
    """The ``sweep.nc`` of an FCC reproduction in ``folder``, or None when there is none."""
    path = Path(folder) / "sweep.nc"
    return read_results(path) if path.is_file() else None


def fcc_cases(dataset) -> dict:
    """``{(cell_pressure_kpa, membrane_thickness_mm): shear records}`` of an FCC reproduction's dataset.

    Members that failed (``status`` other than completed) are left out.
    """
    return {
        (float(pressure), float(thickness)): member_records(
            dataset, cell_pressure_kpa=pressure, membrane_thickness_mm=thickness
        )
        for pressure in dataset["cell_pressure_kpa"].values
        for thickness in dataset["membrane_thickness_mm"].values
        if str(dataset["status"].sel(cell_pressure_kpa=pressure, membrane_thickness_mm=thickness).values)
        == "completed"
    }


def _random_outputs(result, values, size, folder, resume, reference_folder, started) -> dict:
    """:func:`reproduce`'s files for ``packing="random"``: spread tables, figures per seed, the report."""
    by_seed = random_cases(result.dataset)
    reference_folder = Path(reference_folder if reference_folder is not None else f"results_reproduce_{size}")
    reference_dataset = fcc_dataset(reference_folder)
    reference = fcc_cases(reference_dataset) if reference_dataset is not None else None
    files = dict(result.files)
    # A graded specimen's particle radius: half its d50 (the size a laboratory quotes).
    radius = 0.5e-3 * values["characteristic_size_mm"]
    files.update(paper.write_spread_tables(by_seed, folder, reference=reference, particle_radius=radius))
    files["figures"] = []
    for seed, cases in by_seed.items():
        if (10.0, 5.0) in cases:
            files["figures"] += plots.save_test_figures(cases[(10.0, 5.0)], folder, stem=f"seed{seed}_fig")
    fig9 = dict(particle_diameter_mm=1e3 * 2.0 * radius, membrane_modulus_kpa=values["membrane_modulus_kpa"])
    ours = seed_mean_fig9([paper.fig9_data(cases, **fig9) for cases in by_seed.values()])
    fcc = paper.fig9_data(reference, **fig9) if reference else None
    files["fig9"] = plots.save_fig9(ours, folder, paper=fcc, labels=("random", "FCC"))
    files["figures"].append(files["fig9"])
    seconds = time.perf_counter() - started
    timed = "this call (resumed from any checkpoints) ran the sweep in" if resume else "the sweep ran in"
    fcc_note = (
        f"FCC columns from {reference_folder / 'sweep.nc'}."
        if reference is not None
        else f"No FCC reproduction in {reference_folder}: run `membrax reproduce --size {size}` for the "
        "FCC columns."
    )
    dataset = result.dataset
    per_seed = [
        f"seed {seed}: {int(dataset['num_particles'].sel(packing_seed=seed).max())} spheres, solid fraction "
        f"{float(dataset['solid_fraction'].sel(packing_seed=seed).max()):.4f}"
        for seed in by_seed
    ]
    text = [
        f"# membrax reproduction on random specimens ({size})\n",
        f"Random packings of {_spheres_words(values)} in a mould "
        f"{values['specimen_diameter_mm']:g} × {values['specimen_height_mm']:g} mm, compacted with an "
        f"interparticle friction of {values['compaction_friction_deg']:.4g}°, seeds "
        f"{', '.join(map(str, by_seed))}; "
        f"membrane edge D/{values['membrane_edges_per_diameter']:g}, I = {values['inertial_number']:g}, to "
        f"{100 * values['target_axial_strain']:g} % axial strain, {values['precision']}; {timed} "
        f"{result.seconds:.0f} s, everything in {seconds:.0f} s. {fcc_note}\n",
        "Specimens: " + "; ".join(per_seed) + ".\n",
        (folder / "random_table2.md").read_text(),
        (folder / "random_table3.md").read_text(),
        "Figures (Figs 5–8 of 10 kPa, 5 mm, one set per seed; Fig. 9 over the seeds beside FCC): "
        + ", ".join(p.name for p in files["figures"])
        + "\n",
    ]
    (folder / "reproduction.md").write_text("\n".join(text))
    files["report"] = folder / "reproduction.md"
    return {
        "folder": folder,
        "sweep": result,
        "files": files,
        "seconds": seconds,
        "reference": reference,
        "reference_dataset": reference_dataset,
    }
