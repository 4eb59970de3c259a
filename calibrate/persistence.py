"""Fitted corrections saved and loaded as JSON, with provenance.

Contract. :func:`save_corrections` writes one JSON object:

- ``model``: the model's name (:data:`calibrate.models.MODELS`);
- ``params`` and ``std``: the fitted parameters and their standard errors (:class:`calibrate.fit.FitResult`);
- ``covariance`` with ``names`` (its order), ``rms`` and ``evaluations`` of the fit;
- ``input_ranges``: for each input column the model reads and each of :data:`RANGE_INPUTS`, [min, max]
  over the rows of the table, so a user's record can be checked against the fitted range;
- ``provenance``: the membrax version, the SHA-256 of the sweep's base configuration and grid (the
  ``base_config`` and ``grid`` attributes of ``sweep.nc``, canonical JSON), and the number of cases and rows;
- ``packing_family``: what the specimens were (:func:`calibrate.datasets.packing_family`: FCC or random,
  compaction states, gradings, the random members' solid-fraction range), which ``membrax correct`` checks
  a laboratory specimen against. Files written before it existed load with an empty family;
- ``input_ranges["aspect_ratio"]`` (when known): the specimens' height over diameter H/D_s
  (:func:`calibrate.datasets.aspect_ratios`), which no model reads but ``membrax correct
  --specimen-height-mm`` checks a record against;
- ``abstention``: the rule of when the correction abstains (:func:`calibrate.abstention.fit_rule`), fitted
  on the cross-validated predictions. Files written before it existed load with none (never abstain);
- ``radial_target``: the internal radial stress the correction reproduces (a key of
  :data:`calibrate.datasets.RADIAL_TARGETS`). Files written before it existed reproduce the paper's §4.3
  (``"section_4_3"``);
- ``alternate`` (optional): the same fit on the same sweeps with the other radial target, a whole
  correction object of this format without its own ``alternate``, which ``membrax correct`` reports
  beside the chosen one.

:func:`amend_corrections` adds an aspect-ratio range or a rule to a file already written, the rest kept as
it is (how the shipped correction got them without being refitted).

:func:`load_corrections` reads it back into a :class:`Corrections` (the model looked up by name), refusing a
file that is not JSON, names an unknown model, or lacks a field, with a message naming the field and the
fix. The write is atomic (a temporary file then ``os.replace``).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from calibrate.datasets import LEGACY_RADIAL_TARGET, RADIAL_TARGETS
from calibrate.models import MODELS

__all__ = [
    "Corrections",
    "amend_corrections",
    "corrections_content",
    "load_corrections",
    "save_corrections",
    "sweep_hash",
]

FORMAT = "membrax-corrections"
#: Inputs whose fitted range is saved besides the model's own: the dimensionless groups and strains a
#: laboratory record is checked against (:mod:`calibrate.correct`).
RANGE_INPUTS = (
    "axial_strain",
    "thickness_ratio",
    "stiffness_ratio",
    "size_ratio",
    "indentation_ratio",
    "hoop_ratio",
    "strain_ratio_change",
)
#: The key of the specimens' H/D_s range in ``input_ranges`` (not a column of the fitting table).
ASPECT_RATIO = "aspect_ratio"
FIELDS = ("format", "model", "params", "std", "names", "covariance", "rms", "input_ranges", "provenance")


class Corrections(NamedTuple):
    """A loaded correction: the model and what was fitted (module docstring)."""

    model: object
    params: dict
    std: dict
    covariance: np.ndarray
    names: tuple
    rms: float
    input_ranges: dict
    provenance: dict
    packing_family: dict | None = None
    abstention: dict | None = None
    radial_target: str = LEGACY_RADIAL_TARGET
    alternate: Corrections | None = None


def sweep_hash(dataset) -> str:
    """SHA-256 of a sweep's ``base_config`` and ``grid`` attributes (canonical JSON), hex."""
    parts = {}
    for name in ("base_config", "grid"):
        value = dataset.attrs.get(name)
        parts[name] = json.loads(value) if isinstance(value, str) else value
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def save_corrections(path, model, result, table, provenance=None, alternate=None, **details) -> Path:
    """Write a fitted correction to ``path`` (module docstring).

    Args:
      path: the JSON file to write.
      model: the model fitted (:func:`corrections_content`).
      result: its fit.
      table: the table it was fitted on.
      provenance: further provenance.
      alternate: :func:`corrections_content` of the fit with the other radial target (None: none).
      **details: ``packing_family``, ``aspect_ratio``, ``abstention`` of :func:`corrections_content`.
    """
    content = corrections_content(model, result, table, provenance, **details)
    if alternate is not None:
        if alternate.get("radial_target") == content["radial_target"] or "alternate" in alternate:
            raise ValueError("the alternate correction must have the other radial target and no alternate.")
        content["alternate"] = alternate
    return _write(path, content)


def corrections_content(
    model,
    result,
    table,
    provenance: dict | None = None,
    packing_family: dict | None = None,
    aspect_ratio=None,
    abstention: dict | None = None,
) -> dict:
    """The JSON object :func:`save_corrections` writes, without ``alternate``.

    Args:
      model: the :class:`calibrate.models.CorrectionModel` fitted.
      result: its :class:`calibrate.fit.FitResult`.
      table: the :class:`calibrate.datasets.FittingTable` it was fitted on (for the input ranges and the
        radial target).
      provenance: further provenance (e.g. ``{"sweep_sha256": sweep_hash(dataset)}``).
      packing_family: :func:`calibrate.datasets.packing_family` of the sweeps (None: not recorded).
      aspect_ratio: (lowest, highest) H/D_s of the specimens (None: not known).
      abstention: :func:`calibrate.abstention.fit_rule`'s rule (None: not fitted, never abstain).
    """
    from membrax import __version__

    ranges = {}
    for name in sorted(set(model.inputs) | set(RANGE_INPUTS)):
        values = np.asarray(table.inputs[name], dtype=np.float64)
        values = values[np.isfinite(values)]
        ranges[name] = [float(values.min()), float(values.max())] if values.size else [None, None]
    if aspect_ratio is not None:
        ranges[ASPECT_RATIO] = [float(aspect_ratio[0]), float(aspect_ratio[1])]
    content = {
        "format": FORMAT,
        "model": model.name,
        "params": dict(result.params),
        "std": dict(result.std),
        "names": list(result.names),
        "covariance": np.asarray(result.covariance).tolist(),
        "rms": float(result.rms),
        "evaluations": dict(result.evaluations),
        "input_ranges": ranges,
        "provenance": {
            "membrax_version": __version__,
            "cases": int(table.num_cases),
            "rows": int(table.num_rows),
            **(provenance or {}),
        },
        "packing_family": packing_family or {},
        "radial_target": table.radial_target_name,
    }
    if abstention is not None:
        content["abstention"] = abstention
    return content


def _write(path, content: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.tmp")
    partial.write_text(json.dumps(content, indent=2, sort_keys=True) + "\n")
    os.replace(partial, path)
    return path


def amend_corrections(path, aspect_ratio=None, abstention: dict | None = None) -> Path:
    """Add an H/D_s range and/or an abstention rule to a corrections file, leaving the rest as written.

    Args:
      path: a file written by :func:`save_corrections` (checked by :func:`load_corrections` first).
      aspect_ratio: (lowest, highest) H/D_s of the specimens it was fitted on, or None to leave it.
      abstention: :func:`calibrate.abstention.fit_rule`'s rule, or None to leave it.
    """
    load_corrections(path)
    content = json.loads(Path(path).read_text())
    if aspect_ratio is not None:
        content["input_ranges"][ASPECT_RATIO] = [float(aspect_ratio[0]), float(aspect_ratio[1])]
    if abstention is not None:
        content["abstention"] = abstention
    return _write(path, content)


def load_corrections(path) -> Corrections:
    """Read a correction written by :func:`save_corrections`.

    Raises:
      FileNotFoundError: no such file. ValueError: not JSON, not a corrections file, an unknown model or a
      missing field (named, with the fix).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no corrections file at '{path}'; write one with `membrax fit`.")
    try:
        content = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(
            f"'{path}' is not JSON (line {error.lineno}, column {error.colno}: {error.msg}); give a file "
            "written by `membrax fit`."
        ) from error
    return _corrections_of(content, f"'{path}'")


def _corrections_of(content: dict, where: str) -> Corrections:
    """The :class:`Corrections` of a JSON object; ``where`` names it in errors (a file, or its alternate)."""
    missing = [name for name in FIELDS if name not in content]
    if missing:
        raise ValueError(f"{where} lacks {missing}: it was not written by `membrax fit`; fit again.")
    if content["format"] != FORMAT:
        raise ValueError(f"{where} has format {content['format']!r}, not {FORMAT!r}.")
    if content["model"] not in MODELS:
        raise ValueError(f"{where} names model {content['model']!r}; known models: {sorted(MODELS)}.")
    radial_target = content.get("radial_target", LEGACY_RADIAL_TARGET)
    if radial_target not in RADIAL_TARGETS:
        raise ValueError(
            f"{where} names radial_target {radial_target!r}; known targets: {sorted(RADIAL_TARGETS)}."
        )
    alternate = content.get("alternate")
    if alternate is not None:
        alternate = _corrections_of(alternate, f"{where}'s alternate")
        if alternate.radial_target == radial_target or alternate.alternate is not None:
            raise ValueError(f"{where}'s alternate must have the other radial target and no alternate.")
    return Corrections(
        MODELS[content["model"]],
        {name: float(value) for name, value in content["params"].items()},
        {name: float(value) for name, value in content["std"].items()},
        np.asarray(content["covariance"], dtype=np.float64),
        tuple(content["names"]),
        float(content["rms"]),
        {name: tuple(value) for name, value in content["input_ranges"].items()},
        dict(content["provenance"]),
        dict(content.get("packing_family") or {}),
        content.get("abstention") or None,
        radial_target,
        alternate,
    )
