"""The ``membrax fit`` workflow: sweep files in, a fitted correction (JSON) and a report out.

Contract. :func:`fit_sweeps` reads one or more ``sweep.nc`` files (:mod:`membrax.sweep`), joins their
fitting tables (:func:`calibrate.datasets.concatenate`), fits a model (:func:`calibrate.fit.fit`), scores it
by leave-one-case-out cross-validation when there are at least three cases (whose predictions also fit the
rule of when the correction abstains, :func:`calibrate.abstention.fit_rule`), and writes the correction with
its provenance (:func:`calibrate.persistence.save_corrections`: the membrax version, each sweep's
SHA-256, the specimens' packing family, :func:`calibrate.datasets.packing_family`, and their H/D_s range,
:func:`calibrate.datasets.aspect_ratios`). It returns the report that ``membrax fit`` prints.

Radial target. Δσ_r is counted from ``radial_target`` (:data:`calibrate.datasets.RADIAL_TARGETS`; the
received stress by default). When the sweeps record the other one too, the same model is fitted on it the
same way and saved beside as the correction's ``alternate`` (:mod:`calibrate.persistence`), which
``membrax correct`` reports next to the chosen one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibrate import abstention, datasets, fit, models, persistence

__all__ = ["fit_sweeps"]


def fit_sweeps(
    paths,
    out,
    model: str = "rich",
    cross_validation: bool = True,
    table_out=None,
    radial_target: str = datasets.DEFAULT_RADIAL_TARGET,
) -> tuple[str, Path]:
    """Fit ``model`` on the sweeps at ``paths`` and write it to ``out`` (module docstring).

    Args:
      paths: the ``sweep.nc`` files.
      out: the JSON to write.
      model: a name of :data:`calibrate.models.MODELS`.
      cross_validation: score by leave-one-case-out (at least three cases).
      table_out: also write the joined fitting table there (``.npz``, :func:`calibrate.datasets.save_table`).
      radial_target: the internal radial stress Δσ_r counts from (:data:`calibrate.datasets.RADIAL_TARGETS`).

    Returns:
      (the report text, the path written).

    Raises:
      FileNotFoundError: a missing sweep file. ValueError: an unknown model, or a file that is not a
        sweep's (named).
    """
    from membrax.io import read_results

    if model not in models.MODELS:
        raise ValueError(f"model = {model!r}; choose one of {sorted(models.MODELS)}.")
    if radial_target not in datasets.RADIAL_TARGETS:
        raise ValueError(
            f"radial_target = {radial_target!r}; choose one of {sorted(datasets.RADIAL_TARGETS)}."
        )
    chosen = models.MODELS[model]
    tables, hashes, sweeps = [], [], []
    for path in paths:
        dataset = read_results(path)
        sweeps.append(dataset)
        try:
            tables.append(datasets.fitting_table(dataset, radial_target))
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from error
        hashes.append(persistence.sweep_hash(dataset))
    table = datasets.concatenate(tables)
    provenance = {"sweeps": [str(p) for p in paths], "sweep_sha256": hashes}
    lines = [
        f"model {chosen.name}: {table.num_cases} cases, {table.num_rows} records from {len(tables)} sweep(s)"
    ]
    result, rule, fit_lines = _fit_table(chosen, table, cross_validation, provenance)
    lines += fit_lines
    # The other radial target, where every sweep records it: fitted the same way, saved beside.
    other = next(name for name in datasets.RADIAL_TARGETS if name != radial_target)
    try:
        other_table = datasets.concatenate([datasets.fitting_table(d, other) for d in sweeps])
    except ValueError:
        other_table = None
        lines.append(f"the sweeps do not record the {other!r} radial stress: no alternate correction")
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
    alternate = None
    if other_table is not None:
        lines.append(f"alternate correction, Δσ_r from the {other!r} radial stress:")
        other_provenance = dict(provenance)
        other_result, other_rule, other_lines = _fit_table(
            chosen, other_table, cross_validation, other_provenance
        )
        lines += [f"  {line}" for line in other_lines]
        alternate = persistence.corrections_content(
            chosen, other_result, other_table, other_provenance, family, aspect, other_rule
        )
    written = persistence.save_corrections(
        out,
        chosen,
        result,
        table,
        provenance,
        packing_family=family,
        aspect_ratio=aspect,
        abstention=rule,
        alternate=alternate,
    )
    lines.append(f"written to {written}")
    if table_out is not None:
        datasets.save_table(table, table_out)
        lines.append(f"fitting table written to {table_out}")
    return "\n".join(lines), written


def _fit_table(chosen, table, cross_validation: bool, provenance: dict):
    """Fit ``chosen`` on ``table``, cross-validate and fit the abstention rule (at least three cases).

    Adds the cross-validation scores to ``provenance``. Returns (the fit, the rule or None, report lines).
    """
    result = fit.fit(chosen, table)
    lines = [
        f"Δσ_r from the {table.radial_target_name!r} radial stress",
        "parameter  value  standard error",
        *(f"{name:9s} {result.params[name]: .5g}  {result.std[name]:.2g}" for name in result.names),
        f"RMS residual {result.rms:.3g} σc; optax: {result.evaluations['adam']} Adam steps, "
        f"{result.evaluations['lbfgs']} L-BFGS loss evaluations",
    ]
    if not result.converged:
        lines.append(
            "warning: L-BFGS stopped before the gradient tolerance; the parameters may move in their last "
            "digits with the round-off of another machine (calibrate.fit.fit's lbfgs_steps)"
        )
    rule = None
    if cross_validation and table.num_cases >= 3:
        predictions = fit.cross_validated_predictions(chosen, table, progress=True)
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
    return result, rule, lines
