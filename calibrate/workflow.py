"""The ``membrax fit`` workflow: sweep files in, a fitted correction (JSON) and a report out.

Contract. :func:`fit_sweeps` reads one or more ``sweep.nc`` files (:mod:`membrax.sweep`), joins their
fitting tables (:func:`calibrate.datasets.concatenate`), fits a model (:func:`calibrate.fit.fit`), scores it
by leave-one-case-out cross-validation when there are at least three cases (whose predictions also fit the
rule of when the correction abstains, :func:`calibrate.abstention.fit_rule`), and writes the correction with
its provenance (:func:`calibrate.persistence.save_corrections`: the membrax version, each sweep's
SHA-256, the specimens' packing family, :func:`calibrate.datasets.packing_family`, and their H/D_s range,
:func:`calibrate.datasets.aspect_ratios`). It returns the report that ``membrax fit`` prints.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibrate import abstention, datasets, fit, models, persistence

__all__ = ["fit_sweeps"]


def fit_sweeps(
    paths, out, model: str = "rich", cross_validation: bool = True, table_out=None
) -> tuple[str, Path]:
    """Fit ``model`` on the sweeps at ``paths`` and write it to ``out`` (module docstring).

    Args:
      paths: the ``sweep.nc`` files.
      out: the JSON to write.
      model: a name of :data:`calibrate.models.MODELS`.
      cross_validation: score by leave-one-case-out (at least three cases).
      table_out: also write the joined fitting table there (``.npz``, :func:`calibrate.datasets.save_table`).

    Returns:
      (the report text, the path written).

    Raises:
      FileNotFoundError: a missing sweep file. ValueError: an unknown model, or a file that is not a
        sweep's (named).
    """
    from membrax.io import read_results

    if model not in models.MODELS:
        raise ValueError(f"model = {model!r}; choose one of {sorted(models.MODELS)}.")
    chosen = models.MODELS[model]
    tables, hashes, sweeps = [], [], []
    for path in paths:
        dataset = read_results(path)
        sweeps.append(dataset)
        try:
            tables.append(datasets.fitting_table(dataset))
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from error
        hashes.append(persistence.sweep_hash(dataset))
    table = datasets.concatenate(tables)
    result = fit.fit(chosen, table)
    lines = [
        f"model {chosen.name}: {table.num_cases} cases, {table.num_rows} records from {len(tables)} sweep(s)",
        "parameter  value  standard error",
        *(f"{name:9s} {result.params[name]: .5g}  {result.std[name]:.2g}" for name in result.names),
        f"RMS residual {result.rms:.3g} σc; optax: {result.evaluations['adam']} Adam steps, "
        f"{result.evaluations['lbfgs']} L-BFGS loss evaluations",
    ]
    provenance = {"sweeps": [str(p) for p in paths], "sweep_sha256": hashes}
    rule = None
    if cross_validation and table.num_cases >= 3:
        predictions = fit.cross_validated_predictions(chosen, table)
        scores = fit.cross_validate(chosen, table, predictions)
        rule = abstention.fit_rule(table, *predictions)
        axial = np.array([s["axial"] for s in scores.values()])
        radial = np.array([s["radial"] for s in scores.values()])
        provenance["cross_validation"] = {"axial_rms": axial.tolist(), "radial_rms": radial.tolist()}
        lines.append(
            "leave-one-case-out RMS error in Δσ/σc: "
            f"axial mean {axial.mean():.3g} (worst {axial.max():.3g}), "
            f"radial mean {radial.mean():.3g} (worst {radial.max():.3g})"
        )
        lines += abstention.rule_lines(rule)
    family = datasets.packing_family(sweeps)
    lines.append(
        f"packing family: {', '.join(family['packings'])}"
        + (f" ({', '.join(family['states'])}; {'; '.join(family['gradings'])})" if family["states"] else "")
        + (
            f", solid fraction {family['solid_fraction'][0]:.3f}–{family['solid_fraction'][1]:.3f}"
            if family["solid_fraction"]
            else ""
        )
    )
    ratios = datasets.aspect_ratios(sweeps)
    aspect = (min(ratios), max(ratios)) if ratios else None
    if aspect is not None:
        lines.append(f"specimens' height / diameter H/D_s {aspect[0]:.3g}–{aspect[1]:.3g}")
    written = persistence.save_corrections(
        out, chosen, result, table, provenance, packing_family=family, aspect_ratio=aspect, abstention=rule
    )
    lines.append(f"written to {written}")
    if table_out is not None:
        datasets.save_table(table, table_out)
        lines.append(f"fitting table written to {table_out}")
    return "\n".join(lines), written
