"""Fitting tables from membrax sweeps: laboratory measures as dimensionless groups, and the extra stresses.

Contract. :func:`fitting_table` takes a sweep dataset (``sweep.nc`` of :func:`membrax.sweep.run_sweep`,
opened with :func:`membrax.io.read_results` or ``xarray``) and returns a :class:`FittingTable`: one row per
shearing record of every member (NaN padding dropped), float64 numpy arrays.

Inputs, each a quantity a laboratory measures or knows (SI, compression positive):

- ``axial_strain`` ε_a, ``radial_strain`` ε_r (right cylinder, from ε_a and ε_v), both counted from the
  start of shearing; ``strain_ratio_change`` dε_r/dε_a (the paper's Fig. 7,
  :func:`membrax.triaxial.analysis.strain_ratio_change`); ``hoop_strain`` ε_θ, the mid-height
  circumferential strain from the start of shearing, extension positive (a tape measure);
- ``cell_pressure`` σc, ``membrane_thickness`` t_m, ``membrane_modulus`` E_m, ``particle_diameter`` D and
  ``specimen_diameter`` D_s (√(4A₀/π), A₀ the platen area at the start of shearing);

and the dimensionless groups the models use:

- ``thickness_ratio`` t_m/D, ``stiffness_ratio`` E_m t_m/(σc D), ``size_ratio`` D/D_s;
- ``indentation_ratio`` α/D of Molenkamp & Luger (the paper's Eq. 2, C = 0.275, FCC void ratio;
  :func:`membrax.theory.molenkamp_luger_indentation_ratio`);
- ``hoop_ratio`` 2 E_m t_m ε_θ/(D_s σc): Henkel & Gilbert's hoop stress over σc (positive when the
  membrane is stretched round the specimen).

Targets: ``axial_target`` Δσ_a/σc and ``radial_target`` Δσ_r/σc, internal − external (the paper's §4.3
stresses; Δσ > 0 when the specimen carries more than the cell and ram apply). ``case`` numbers the
members (for leave-one-case-out cross-validation) and ``initial`` marks each member's first record (the
end of consolidation: Table 3, Fig. 9).
"""

from __future__ import annotations

import json
import math
from typing import NamedTuple

import numpy as np

from membrax import theory

__all__ = ["FittingTable", "concatenate", "fitting_table"]

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
)


class FittingTable(NamedTuple):
    """Rows of (inputs, targets) for fitting; every field a float64 array of one length (module docstring)."""

    inputs: dict
    axial_target: np.ndarray
    radial_target: np.ndarray
    case: np.ndarray
    initial: np.ndarray

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
        )


def _attr(dataset, name):
    value = dataset.attrs[name]
    return json.loads(value) if isinstance(value, str) else value


def fitting_table(dataset) -> FittingTable:
    """The fitting table of a sweep dataset (module docstring).

    Args:
      dataset: an :class:`xarray.Dataset` of :func:`membrax.sweep.run_sweep` (``sweep.nc``).

    Raises:
      ValueError: a dataset that is not a sweep's (no ``base_config``/``grid_fields`` attributes or no
        records), naming what is missing.
    """
    for name in ("base_config", "grid_fields"):
        if name not in dataset.attrs:
            raise ValueError(
                f"the dataset has no {name!r} attribute: give the sweep.nc that membrax sweep wrote."
            )
    base = _attr(dataset, "base_config")
    fields = [f for f in dataset.attrs["grid_fields"].split(",") if f]
    stacked = dataset.stack(member=fields) if fields else dataset.expand_dims(member=[0])
    columns = {name: [] for name in INPUTS}
    axial, radial, cases, initial = [], [], [], []
    for case in range(stacked.sizes["member"]):
        member = stacked.isel(member=case)
        count = int(member["num_records"])
        if count == 0:
            continue
        config = dict(base)
        for field in fields:
            config[field] = float(member[field])
        rows = member.isel(record=slice(0, count))
        cell_pressure = 1e3 * config["cell_pressure_kpa"]
        thickness = 1e-3 * config["membrane_thickness_mm"]
        modulus = 1e3 * config["membrane_modulus_kpa"]
        particle = 1e-3 * config["particle_diameter_mm"]
        specimen = math.sqrt(4.0 * float(rows["platen_area"][0]) / math.pi)
        hoop = np.asarray(rows["hoop_strain"], dtype=np.float64)
        hoop = hoop - hoop[0]
        indentation = float(
            theory.molenkamp_luger_indentation_ratio(
                theory.FCC_VOID_RATIO, particle, thickness, cell_pressure, modulus
            )
        )
        values = {
            "axial_strain": np.asarray(rows["axial_strain"], dtype=np.float64),
            "radial_strain": np.asarray(rows["radial_strain"], dtype=np.float64),
            "strain_ratio_change": np.asarray(rows["strain_ratio_change"], dtype=np.float64),
            "hoop_strain": hoop,
            "cell_pressure": np.full(count, cell_pressure),
            "membrane_thickness": np.full(count, thickness),
            "membrane_modulus": np.full(count, modulus),
            "particle_diameter": np.full(count, particle),
            "specimen_diameter": np.full(count, specimen),
            "thickness_ratio": np.full(count, thickness / particle),
            "stiffness_ratio": np.full(count, modulus * thickness / (cell_pressure * particle)),
            "size_ratio": np.full(count, particle / specimen),
            "indentation_ratio": np.full(count, indentation),
            "hoop_ratio": 2.0 * modulus * thickness * hoop / (specimen * cell_pressure),
        }
        for name in INPUTS:
            columns[name].append(values[name])
        axial.append(np.asarray(rows["additional_axial_stress"], dtype=np.float64) / cell_pressure)
        radial.append(np.asarray(rows["additional_radial_stress"], dtype=np.float64) / cell_pressure)
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
    )


def concatenate(tables) -> FittingTable:
    """One table of several (e.g. of several sweep files), their cases renumbered to stay distinct."""
    tables = list(tables)
    if not tables:
        raise ValueError("no tables to join; give at least one sweep.")
    offsets = np.cumsum([0] + [int(t.case.max()) + 1 for t in tables[:-1]])
    return FittingTable(
        {name: np.concatenate([t.inputs[name] for t in tables]) for name in INPUTS},
        np.concatenate([t.axial_target for t in tables]),
        np.concatenate([t.radial_target for t in tables]),
        np.concatenate([t.case + offset for t, offset in zip(tables, offsets, strict=True)]),
        np.concatenate([t.initial for t in tables]),
    )
