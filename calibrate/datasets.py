"""Fitting tables from membrax sweeps: laboratory measures as dimensionless groups, and the extra stresses.

Contract. :func:`fitting_table` takes a sweep dataset (``sweep.nc`` of :func:`membrax.sweep.run_sweep`,
opened with :func:`membrax.io.read_results` or ``xarray``) and returns a :class:`FittingTable`: one row per
shearing record of every member (NaN padding dropped), float64 numpy arrays.

Inputs, each a quantity a laboratory measures or knows (SI, compression positive):

- ``axial_strain`` ε_a, ``radial_strain`` ε_r (right cylinder, from ε_a and ε_v), both counted from the
  start of shearing; ``strain_ratio_change`` dε_r/dε_a (the paper's Fig. 7,
  :func:`membrax.triaxial.analysis.strain_ratio_change`); ``hoop_strain`` ε_θ, the mid-height
  circumferential strain from the start of shearing, extension positive (a tape measure);
- ``cell_pressure`` σc, ``membrane_thickness`` t_m, ``membrane_modulus`` E_m, ``particle_diameter`` D
  (d50 of a graded specimen, :func:`membrax.config.characteristic_size_mm`) and ``specimen_diameter`` D_s
  (√(4A₀/π), A₀ the platen area at the start of shearing);

and the dimensionless groups the models use:

- ``thickness_ratio`` t_m/D, ``stiffness_ratio`` E_m t_m/(σc D), ``size_ratio`` D/D_s;
- ``indentation_ratio`` α/D of Molenkamp & Luger (the paper's Eq. 2, C = 0.275, FCC void ratio;
  :func:`membrax.theory.molenkamp_luger_indentation_ratio`);
- ``hoop_ratio`` 2 E_m t_m (−ε_r)/(D_s σc): Henkel & Gilbert's hoop stress over σc with the hoop strain
  of the right cylinder, −ε_r (positive when the specimen bulges and stretches the membrane). Every
  laboratory record has it (from ε_v or ε_r);
- ``tape_hoop_ratio`` 2 E_m t_m ε_θ/(D_s σc), the same with the mid-height circumferential strain, where
  recorded (NaN otherwise).

:func:`measured_inputs` computes these columns from one test's strains and properties; the fitting table
of a sweep and the correction of a laboratory record (:mod:`calibrate.correct`) both use it.

Targets: ``axial_target`` Δσ_a/σc and ``radial_target`` Δσ_r/σc, internal − external (Δσ > 0 when the
specimen carries more than the cell and ram apply). The axial internal stress is the paper's §4.3 one. The
radial one is the table's ``radial_target_name``, one of :data:`RADIAL_TARGETS` (docs/model.md, "Which
internal stress a correction reproduces"): ``"received"`` (the default, :data:`DEFAULT_RADIAL_TARGET`), the
radial load the spheres and clamps receive over the membrane's radially projected area, σc exactly when
the membrane carries nothing; or ``"section_4_3"``, the paper's, which is the received one times R̄/R_A (the
indented surface's mean radius over the platen's) and so moves with the packing's roughness. Sweeps written
before membrax recorded ``received_radial_stress`` have only the second. ``case`` numbers the members (for
leave-one-case-out cross-validation) and ``initial`` marks each member's first record (the end of
consolidation: Table 3, Fig. 9).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from membrax import theory
from membrax.config import characteristic_size_mm, compaction_state

__all__ = [
    "DEFAULT_RADIAL_TARGET",
    "INPUTS",
    "LEGACY_RADIAL_TARGET",
    "RADIAL_TARGETS",
    "FittingTable",
    "aspect_ratios",
    "concatenate",
    "fitting_table",
    "grading_words",
    "load_table",
    "measured_inputs",
    "packing_family",
    "save_table",
    "sweep_members",
]

#: Names of the input columns, in order.
INPUTS = (
    "axial_strain",
    "radial_strain",
    "strain_ratio_change",
    "hoop_strain",
    "cell_pressure",
    "membrane_thickness",
    "membrane_modulus",
    "particle_diameter",
    "specimen_diameter",
    "thickness_ratio",
    "stiffness_ratio",
    "size_ratio",
    "indentation_ratio",
    "hoop_ratio",
    "tape_hoop_ratio",
)

#: The radial internal stresses a correction can reproduce: name → the record holding it (module docstring).
RADIAL_TARGETS = {"received": "received_radial_stress", "section_4_3": "internal_radial_stress"}
#: The radial target a new correction reproduces (docs/model.md gives the evidence).
DEFAULT_RADIAL_TARGET = "received"
#: What a table written before it carried a target's name holds.
LEGACY_RADIAL_TARGET = "section_4_3"


class FittingTable(NamedTuple):
    """Rows of (inputs, targets) for fitting; every field a float64 array of one length (module docstring).

    Attributes:
      inputs: name → column: σc, t_m, E_m, D, D_s in SI (Pa, m), the strains and ratios dimensionless.
      axial_target: Δσ_a/σc, dimensionless.
      radial_target: Δσ_r/σc, dimensionless.
      case: the member each row comes from (integer labels).
      initial: whether the row is a member's start of shearing (bool).
      radial_target_name: which internal radial stress ``radial_target`` is, a key of
        :data:`RADIAL_TARGETS`.
    """

    inputs: dict
    axial_target: np.ndarray
    radial_target: np.ndarray
    case: np.ndarray
    initial: np.ndarray
    radial_target_name: str = LEGACY_RADIAL_TARGET

    @property
    def num_rows(self) -> int:
        """Rows in the table."""
        return int(self.case.shape[0])

    @property
    def num_cases(self) -> int:
        """Members (cases) in the table."""
        return int(np.unique(self.case).shape[0])

    def select(self, rows) -> FittingTable:
        """The table restricted to ``rows`` (a boolean mask or indices)."""
        return FittingTable(
            {name: value[rows] for name, value in self.inputs.items()},
            self.axial_target[rows],
            self.radial_target[rows],
            self.case[rows],
            self.initial[rows],
            self.radial_target_name,
        )


def _attr(dataset, name):
    value = dataset.attrs[name]
    return json.loads(value) if isinstance(value, str) else value


def measured_inputs(
    axial_strain,
    radial_strain,
    strain_ratio_change,
    cell_pressure,
    membrane_thickness,
    membrane_modulus,
    particle_diameter,
    specimen_diameter,
    hoop_strain=None,
) -> dict:
    """The input columns (:data:`INPUTS`) of one test's records: the one rule for sweeps and lab records.

    Args:
      axial_strain: ε_a per record from the start of shearing (compression positive).
      radial_strain: ε_r per record, likewise (a bulging specimen has ε_r < 0).
      strain_ratio_change: dε_r/dε_a per record
        (:func:`membrax.triaxial.analysis.strain_ratio_change`).
      cell_pressure: σc (Pa), a scalar or per record.
      membrane_thickness: t_m (m).
      membrane_modulus: E_m (Pa).
      particle_diameter: D (m).
      specimen_diameter: D_s (m).
      hoop_strain: the mid-height circumferential strain per record, counted here from the first record;
        ``None`` when not recorded (``hoop_strain`` and ``tape_hoop_ratio`` are then NaN).

    Returns:
      {name: float64 array over the records} for every name of :data:`INPUTS` (module docstring).
    """
    axial = np.asarray(axial_strain, dtype=np.float64)
    count = axial.shape[0]
    pressure = np.broadcast_to(np.asarray(cell_pressure, dtype=np.float64), (count,)).copy()
    thickness, modulus = float(membrane_thickness), float(membrane_modulus)
    particle, specimen = float(particle_diameter), float(specimen_diameter)
    radial = np.asarray(radial_strain, dtype=np.float64)
    if hoop_strain is None:
        hoop = np.full(count, np.nan)
    else:
        hoop = np.asarray(hoop_strain, dtype=np.float64)
        hoop = hoop - hoop[0]
    # Henkel & Gilbert's hoop stress 2 E_m t_m ε_θ / D over σc, with ε_θ = −ε_r (extension positive).
    hoop_scale = 2.0 * modulus * thickness / (specimen * pressure)
    indentation = np.asarray(
        theory.molenkamp_luger_indentation_ratio(
            theory.FCC_VOID_RATIO, particle, thickness, np.maximum(pressure, 0.0), modulus
        ),
        dtype=np.float64,
    )
    return {
        "axial_strain": axial,
        "radial_strain": radial,
        "strain_ratio_change": np.asarray(strain_ratio_change, dtype=np.float64),
        "hoop_strain": hoop,
        "cell_pressure": pressure,
        "membrane_thickness": np.full(count, thickness),
        "membrane_modulus": np.full(count, modulus),
        "particle_diameter": np.full(count, particle),
        "specimen_diameter": np.full(count, specimen),
        "thickness_ratio": np.full(count, thickness / particle),
        "stiffness_ratio": modulus * thickness / (pressure * particle),
        "size_ratio": np.full(count, particle / specimen),
        "indentation_ratio": np.broadcast_to(indentation, (count,)).copy(),
        "hoop_ratio": -hoop_scale * radial,
        "tape_hoop_ratio": hoop_scale * hoop,
    }


def sweep_members(dataset):
    """Each member of a sweep dataset with records: (its configuration fields, its records).

    Yields:
      (dict of the base configuration with the member's grid values, the member's records without the NaN
      padding, an :class:`xarray.Dataset` along ``record``).

    Raises:
      ValueError: a dataset that is not a sweep's (no ``base_config``/``grid_fields`` attribute).
    """
    for name in ("base_config", "grid_fields"):
        if name not in dataset.attrs:
            raise ValueError(
                f"the dataset has no {name!r} attribute: give the sweep.nc that membrax sweep wrote."
            )
    base = _attr(dataset, "base_config")
    fields = [f for f in dataset.attrs["grid_fields"].split(",") if f]
    stacked = dataset.stack(member=fields) if fields else dataset.expand_dims(member=[0])
    for index in range(stacked.sizes["member"]):
        member = stacked.isel(member=index)
        count = int(member["num_records"])
        if count == 0:
            continue
        config = dict(base)
        for field in fields:
            config[field] = float(member[field])
        yield config, member.isel(record=slice(0, count))


def grading_words(config: dict) -> str:
    """A member's particle sizes in words: ``"equal 25 mm"``, or ``"8.89–25 mm, d50 16.1 mm"`` (a grading)."""
    pairs = config.get("grading") or ()
    if not pairs:
        return f"equal {float(config['particle_diameter_mm']):g} mm"
    return f"{pairs[0][0]:.3g}–{pairs[-1][0]:.3g} mm, d50 {characteristic_size_mm(config):.3g} mm"


def packing_family(sweeps) -> dict:
    """What the specimens of ``sweeps`` were: the packing family a correction fitted on them covers.

    Args:
      sweeps: sweep datasets (``sweep.nc``, :func:`sweep_members`).

    Returns:
      ``{"packings": sorted kinds ("fcc", "random"), "states": sorted compaction states of the random
      ones ("dense", "loose"), "gradings": the distinct gradings ("equal D mm" or "d_min–d_max mm, d50 …"),
      "solid_fraction": [min, max] over the random members (whole specimen; None when there are none)}``.
    """
    packings, states, gradings, fractions = set(), set(), set(), []
    for dataset in sweeps:
        for config, rows in sweep_members(dataset):
            packing = config.get("packing", "fcc")
            packings.add(packing)
            if packing != "random":
                continue
            states.add(compaction_state(config.get("compaction_friction_deg", 0.0)))
            gradings.add(grading_words(config))
            if "solid_fraction" in rows and np.isfinite(float(rows["solid_fraction"])):
                fractions.append(float(rows["solid_fraction"]))
    return {
        "packings": sorted(packings),
        "states": sorted(states),
        "gradings": sorted(gradings),
        "solid_fraction": [min(fractions), max(fractions)] if fractions else None,
    }


def aspect_ratios(sweeps) -> list[float]:
    """Each member's height over diameter H/D_s at the start of shearing, over ``sweeps``.

    No model reads H/D_s; a correction records the range it was fitted on so that ``membrax correct
    --specimen-height-mm`` can check a laboratory specimen against it. H is the record ``height`` at the
    first shearing record (over 1 − ε_a there, which is 0), D_s = √(4A₀/π) of the platen area as in
    :func:`fitting_table`; a sweep without the height record gives a random specimen's mould,
    ``specimen_height_mm``/``specimen_diameter_mm`` (the compacted specimen comes out within a few per cent
    of it), and an FCC one nothing.

    Args:
      sweeps: sweep datasets (``sweep.nc``, :func:`sweep_members`).

    Returns:
      H/D_s per member with records, in the order of the sweeps and their members.
    """
    ratios = []
    for dataset in sweeps:
        for config, rows in sweep_members(dataset):
            if "height" in rows and "platen_area" in rows:
                height = float(rows["height"][0]) / (1.0 - float(rows["axial_strain"][0]))
                ratios.append(height / math.sqrt(4.0 * float(rows["platen_area"][0]) / math.pi))
            elif config.get("packing", "fcc") == "random":
                ratios.append(float(config["specimen_height_mm"]) / float(config["specimen_diameter_mm"]))
    return ratios


def fitting_table(dataset, radial_target: str = DEFAULT_RADIAL_TARGET) -> FittingTable:
    """The fitting table of a sweep dataset (module docstring).

    Args:
      dataset: an :class:`xarray.Dataset` of :func:`membrax.sweep.run_sweep` (``sweep.nc``).
      radial_target: the internal radial stress Δσ_r is counted from, a key of :data:`RADIAL_TARGETS`.

    Raises:
      ValueError: a dataset that is not a sweep's (no ``base_config``/``grid_fields`` attributes or no
        records), an unknown ``radial_target``, or a sweep that does not record it, naming what is missing
        and the fix.
    """
    if radial_target not in RADIAL_TARGETS:
        raise ValueError(f"radial_target = {radial_target!r}; choose one of {sorted(RADIAL_TARGETS)}.")
    columns = {name: [] for name in INPUTS}
    axial, radial, cases, initial = [], [], [], []
    for config, rows in sweep_members(dataset):
        count = rows.sizes["record"]
        values = measured_inputs(
            axial_strain=np.asarray(rows["axial_strain"], dtype=np.float64),
            radial_strain=np.asarray(rows["radial_strain"], dtype=np.float64),
            strain_ratio_change=np.asarray(rows["strain_ratio_change"], dtype=np.float64),
            cell_pressure=1e3 * config["cell_pressure_kpa"],
            membrane_thickness=1e-3 * config["membrane_thickness_mm"],
            membrane_modulus=1e3 * config["membrane_modulus_kpa"],
            particle_diameter=1e-3 * characteristic_size_mm(config),
            specimen_diameter=math.sqrt(4.0 * float(rows["platen_area"][0]) / math.pi),
            hoop_strain=np.asarray(rows["hoop_strain"], dtype=np.float64),
        )
        cell_pressure = values["cell_pressure"]
        for name in INPUTS:
            columns[name].append(values[name])
        axial.append(np.asarray(rows["additional_axial_stress"], dtype=np.float64) / cell_pressure)
        radial.append(_radial_difference(rows, radial_target) / cell_pressure)
        cases.append(np.full(count, len(cases), dtype=np.int64))  # members with records, 0, 1, ...
        first = np.zeros(count, dtype=bool)
        first[0] = True
        initial.append(first)
    if not cases:
        raise ValueError("the dataset has no records (every member's num_records is 0).")
    return FittingTable(
        {name: np.concatenate(parts) for name, parts in columns.items()},
        np.concatenate(axial),
        np.concatenate(radial),
        np.concatenate(cases),
        np.concatenate(initial),
        radial_target,
    )


def _radial_difference(rows, radial_target: str) -> np.ndarray:
    """Δσ_r = σ_r,internal − σ_r,external (Pa) of one member's records, the internal one ``radial_target``."""
    if radial_target == "section_4_3":
        return np.asarray(rows["additional_radial_stress"], dtype=np.float64)
    name = RADIAL_TARGETS[radial_target]
    if name not in rows or "external_radial_stress" not in rows:
        raise ValueError(
            f"the sweep records no {name!r} (it was written before membrax recorded it): run the sweep "
            "again with this membrax, or fit the paper's §4.3 stress with radial_target='section_4_3' "
            "(`membrax fit --radial-target section_4_3`)."
        )
    internal = np.asarray(rows[name], dtype=np.float64)
    return internal - np.asarray(rows["external_radial_stress"], dtype=np.float64)


def concatenate(tables) -> FittingTable:
    """One table of several (e.g. of several sweep files), their cases renumbered to stay distinct."""
    tables = list(tables)
    if not tables:
        raise ValueError("no tables to join; give at least one sweep.")
    names = sorted({t.radial_target_name for t in tables})
    if len(names) > 1:
        raise ValueError(f"the tables count Δσ_r from different internal stresses ({names}); join like ones.")
    offsets = np.cumsum([0] + [int(t.case.max()) + 1 for t in tables[:-1]])
    return FittingTable(
        {name: np.concatenate([t.inputs[name] for t in tables]) for name in INPUTS},
        np.concatenate([t.axial_target for t in tables]),
        np.concatenate([t.radial_target for t in tables]),
        np.concatenate([t.case + offset for t, offset in zip(tables, offsets, strict=True)]),
        np.concatenate([t.initial for t in tables]),
        names[0],
    )


def save_table(table: FittingTable, path) -> None:
    """Write ``table`` to ``path`` as a compressed ``.npz`` (atomically), readable by :func:`load_table`."""
    import io

    from membrax.io.files import atomic_write_bytes

    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        **{f"input_{name}": value for name, value in table.inputs.items()},
        axial_target=table.axial_target,
        radial_target=table.radial_target,
        case=table.case,
        initial=table.initial,
        radial_target_name=np.asarray(table.radial_target_name),
    )
    atomic_write_bytes(Path(path), buffer.getvalue())


def load_table(path) -> FittingTable:
    """The :class:`FittingTable` written by :func:`save_table`."""
    with np.load(path) as content:
        inputs = {name: np.asarray(content[f"input_{name}"]) for name in INPUTS}
        return FittingTable(
            inputs,
            np.asarray(content["axial_target"]),
            np.asarray(content["radial_target"]),
            np.asarray(content["case"]),
            np.asarray(content["initial"]),
            str(content["radial_target_name"]) if "radial_target_name" in content else LEGACY_RADIAL_TARGET,
        )
