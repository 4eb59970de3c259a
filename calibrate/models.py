"""Correction models: the membrane's extra stresses Δσ_a/σc, Δσ_r/σc as pure JAX functions of parameters.

Each model maps (parameters, inputs) to predictions.

Contract. A model is a :class:`CorrectionModel`: ``predict(params, inputs) -> (axial, radial)``, each an
array over the rows of ``inputs`` (a dict of arrays, :data:`membrax`-free: the columns of
:class:`calibrate.datasets.FittingTable`), and ``initial_params`` (a dict of float arrays, the point the
fit starts from). Both functions work under ``jax.jit``, ``jax.vmap`` and ``jax.grad``.

- :data:`PAPER` — the paper's correlations (§5.2, Figs 7–9) made physical:

      Δσ_r/σc = k_r · 2 E_m t_m (−ε_r)/(D_s σc) + r₀ + r₁ · α/D,
      Δσ_a/σc = k_a · dε_r/dε_a + a₀ + a₁ · α/D,

  Henkel & Gilbert's hoop stress with the right cylinder's hoop strain −ε_r (what every laboratory record
  gives, from ε_v) scaled by k_r (1 for a thin hoop), the strain-ratio correlation of
  Fig. 7, and initial offsets linear in Molenkamp & Luger's indentation ratio (Fig. 9). Six parameters.
- :data:`RICH` — the same terms plus the size ratio D/D_s in the offsets, the hoop term's growth with
  axial strain and a quadratic strain-ratio term. Ten parameters. The shipped default
  (``calibrate/data/default_corrections.json``, fitted on :data:`calibrate.designs.LAB_CALIBRATION`): on
  the random calibration grid (:data:`calibrate.designs.RANDOM_CALIBRATION`), where the two were compared,
  its leave-one-case-out error is below :data:`PAPER`'s in both targets (axial 0.0603 against 0.0626 σc,
  radial 0.0157 against 0.0196 σc), at the price of correlated, individually poorly determined terms.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp

__all__ = ["MODELS", "PAPER", "RICH", "CorrectionModel"]


class CorrectionModel(NamedTuple):
    """A correction model (module docstring)."""

    name: str
    predict: Callable
    initial_params: dict
    inputs: tuple


def _paper(params, inputs):
    indentation = inputs["indentation_ratio"]
    radial = params["k_r"] * inputs["hoop_ratio"] + params["r0"] + params["r1"] * indentation
    axial = params["k_a"] * inputs["strain_ratio_change"] + params["a0"] + params["a1"] * indentation
    return axial, radial


def _rich(params, inputs):
    axial, radial = _paper(params, inputs)
    size = inputs["size_ratio"]
    ratio = inputs["strain_ratio_change"]
    radial = radial + params["r2"] * size + params["k_r2"] * inputs["hoop_ratio"] * inputs["axial_strain"]
    axial = axial + params["a2"] * size + params["k_a2"] * ratio * ratio
    return axial, radial


_PAPER_START = {"k_r": 1.0, "r0": 0.0, "r1": 0.0, "k_a": 0.0, "a0": 0.0, "a1": 0.0}

#: The paper's correlations, physically scaled (module docstring).
PAPER = CorrectionModel(
    "paper",
    _paper,
    {name: jnp.asarray(value) for name, value in _PAPER_START.items()},
    ("hoop_ratio", "strain_ratio_change", "indentation_ratio"),
)
#: The richer comparison model (module docstring).
RICH = CorrectionModel(
    "rich",
    _rich,
    {
        name: jnp.asarray(value)
        for name, value in {**_PAPER_START, "r2": 0.0, "k_r2": 0.0, "a2": 0.0, "k_a2": 0.0}.items()
    },
    ("hoop_ratio", "strain_ratio_change", "indentation_ratio", "size_ratio", "axial_strain"),
)
#: Models by name.
MODELS = {model.name: model for model in (PAPER, RICH)}
