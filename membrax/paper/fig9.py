"""The numbers of the paper's Fig. 9 (its §5.2), for membrax's cases and from the paper's Table 3.

Contract. :func:`fig9_data` takes ``results`` as :mod:`membrax.paper.tables` does (checked the same way);
:func:`paper_fig9_data` takes none. Both give, per membrane thickness, float64 arrays over the cases:
the Molenkamp & Luger indentation ratio and the negative of the relative initial axial stress ratio
(below); :func:`membrax.plots.plot_fig9` draws them. Everything runs on the host in numpy float64.

The primary axis is α/D from the paper's Eq. 2 with C = 0.275,
:func:`membrax.theory.molenkamp_luger_indentation_ratio` with the paper's parameters as ``membrax theory``
uses them (FCC void ratio, 25 mm spheres, E_m = 1400 kPa, the case's membrane thickness and cell
pressure). The secondary axis is "the negative of the relative initial axial stress ratio", read here as

    −(σ1,int/σ1,ext − 1) = −Δσ1/σ1,ext        (initial stresses, first record; Table 3 for the paper)

Reading. The paper's Fig. 7 calls σ1,int/σ1,ext the "axial stress ratio (internal to external)" and the
caption of Fig. 9 speaks of the "internal/external stress ratio"; "initial" is the state of Table 3;
"relative" takes the ratio relative to 1, i.e. the additional axial stress relative to the external one,
the quantity of the sentence just before Fig. 9 ("their significance relative to the externally applied
stresses decreases"). With the paper's Table 3 this gives 0.364, 0.271, 0.221 at 10, 40, 100 kPa for
5 mm and 0.274, 0.275, 0.364 at 10 kPa for 2.5, 3.33, 5 mm, as its Fig. 9 bullets say (greatest at low
pressure; thickest membrane the greatest influence), and its negative increases with pressure like
α/D ∝ σ'^(1/3) ("plotted as a negative to show the correlation"). The plain ratio σ1,int/σ1,ext would
only shift the curves by 1; normalising Δσ1 by σ3 instead is not what "axial stress ratio" means in the
paper. This reading is an interpretation [U]: the figure itself is not in the text available.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from membrax import theory
from membrax.paper.published import MEMBRANE_MODULUS_KPA, PAPER_TABLE_3, PARTICLE_DIAMETER_MM
from membrax.paper.tables import checked_cases
from membrax.triaxial import analysis

__all__ = ["fig9_data", "paper_fig9_data"]


def _paper_parameters() -> tuple[float, float, float]:
    """The paper's void ratio, sphere diameter (mm) and membrane modulus (kPa)."""
    return theory.FCC_VOID_RATIO, PARTICLE_DIAMETER_MM, MEMBRANE_MODULUS_KPA


def _negative_relative_ratio(sigma1_internal: float, sigma1_external: float) -> float:
    """−(σ1,int/σ1,ext − 1), NaN when σ1,ext is zero or either stress is not finite."""
    if not (math.isfinite(sigma1_internal) and math.isfinite(sigma1_external)) or sigma1_external == 0.0:
        return math.nan
    return -(sigma1_internal / sigma1_external - 1.0)


def _fig9_series(
    stresses: Mapping, c: float, diameter_mm: float | None = None, modulus_kpa: float | None = None
) -> dict[float, dict[str, np.ndarray]]:
    """Fig. 9 numbers from ``{(pressure, thickness): initial stresses}``, grouped by thickness."""
    void_ratio, paper_diameter_mm, paper_modulus_kpa = _paper_parameters()
    diameter_mm = paper_diameter_mm if diameter_mm is None else diameter_mm
    modulus_kpa = paper_modulus_kpa if modulus_kpa is None else modulus_kpa
    data = {}
    for thickness in sorted({key[1] for key in stresses}):
        pressures = np.array(sorted(key[0] for key in stresses if key[1] == thickness), dtype=np.float64)
        args = (void_ratio, diameter_mm, thickness, pressures, modulus_kpa, c)
        data[thickness] = {
            "cell_pressure_kpa": pressures,
            "indentation_ratio": np.asarray(
                theory.molenkamp_luger_indentation_ratio(*args), dtype=np.float64
            ),
            "indentation_ratio_valid": np.asarray(theory.molenkamp_luger_validity(*args).valid, dtype=bool),
            "negative_relative_axial_stress_ratio": np.array(
                [
                    _negative_relative_ratio(
                        stresses[p, thickness]["sigma1_internal_kpa"],
                        stresses[p, thickness]["sigma1_external_kpa"],
                    )
                    for p in pressures.tolist()
                ],
                dtype=np.float64,
            ),
        }
    return data


def fig9_data(
    results,
    c: float = 0.275,
    *,
    particle_diameter_mm: float | None = None,
    membrane_modulus_kpa: float | None = None,
) -> dict[float, dict[str, np.ndarray]]:
    """The numbers of the paper's Fig. 9 for our cases, per membrane thickness.

    Args:
      results: ``{(cell_pressure_kpa, membrane_thickness_mm): shear records}`` (:mod:`membrax.paper`).
      c: Molenkamp & Luger's constant C (0.15–0.4; the paper uses the mean, 0.275).
      particle_diameter_mm: D of Eq. 2, mm; default the paper's 25 mm (give yours if the runs used another).
      membrane_modulus_kpa: E_m of Eq. 2, kPa; default the paper's 1400 kPa.

    Returns:
      ``{thickness_mm: {...}}`` in increasing thickness, each with float64 arrays over the cases of that
      thickness in increasing pressure: ``cell_pressure_kpa``; ``indentation_ratio`` α/D (the paper's
      Eq. 2 with the case's t_m and σc, D, E_m and the FCC void ratio);
      ``indentation_ratio_valid`` (bool: inside Molenkamp & Luger's stated range,
      :func:`membrax.theory.molenkamp_luger_validity`); ``negative_relative_axial_stress_ratio``
      −(σ1,int/σ1,ext − 1) at the first record (see the module docstring; NaN when σ1,ext is 0).

    Raises:
      ValueError: for bad ``results`` (:mod:`membrax.paper`, Checks), or ``c``, D or E_m not positive.
    """
    stresses = {key: analysis.initial_state(records) for key, records in checked_cases(results)}
    return _fig9_series(stresses, c, particle_diameter_mm, membrane_modulus_kpa)


def paper_fig9_data(c: float = 0.275) -> dict[float, dict[str, np.ndarray]]:
    """The numbers of the paper's Fig. 9 from its Table 3, computed as :func:`fig9_data` computes ours.

    Args:
      c: Molenkamp & Luger's constant C (the paper: 0.275).

    Returns:
      The structure of :func:`fig9_data` over the paper's grid (thicknesses 2.5, 3.33, 5.0 mm; pressures
      10, 40, 100 kPa), the stress ratio from :data:`PAPER_TABLE_3` (e.g. −(14.6/10.7 − 1) at 10 kPa,
      5 mm). α/D of the middle membrane is for 3.33 mm, as ``membrax theory`` prints it.
    """
    return _fig9_series(PAPER_TABLE_3, c)
