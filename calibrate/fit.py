"""Fitting correction models with optax: weighted least squares, Gauss–Newton uncertainty, cross-validation.

Contract. :func:`fit` minimises the weighted least-squares loss

    L(θ) = Σ_i w_i [(a(θ, x_i) − Δσ_a,i/σc)² + (r(θ, x_i) − Δσ_r,i/σc)²] / Σ_i w_i

of a :class:`calibrate.models.CorrectionModel` over the rows of a
:class:`calibrate.datasets.FittingTable` (rows with a non-finite input or target get weight 0), in float64:
Adam (``optax.adam``) to get near, then L-BFGS (``optax.lbfgs`` with its zoom line search) to converge.
It returns a :class:`FitResult` with the parameters, their covariance from the Gauss–Newton Hessian at the
optimum, C = s² (JᵀWJ)⁻¹ with s² = RSS_w / (n − p) (n the weighted residuals, 2 per row, p the parameters;
J = ∂residuals/∂θ by ``jax.jacfwd``), and the number of loss evaluations each stage took.

:func:`cross_validated_predictions` refits with each case (member) left out and predicts the left-out
case; :func:`cross_validate` scores each case by the RMS of those predictions' residuals in Δσ/σc (and
:mod:`calibrate.abstention` turns them into the rule of when the correction abstains).
:func:`nelder_mead_baseline` minimises the same loss with scipy's gradient-free Nelder–Mead, for the
evaluation count it needs.

Precision: the fit runs inside ``jax.enable_x64(True)`` and standard dtype promotion (both thread-local),
so the process's settings are left alone.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

__all__ = [
    "FitResult",
    "cross_validate",
    "cross_validated_predictions",
    "fit",
    "nelder_mead_baseline",
    "predict",
]


class FitResult(NamedTuple):
    """A fitted model (module docstring).

    Attributes:
      params: dict of fitted parameters (floats).
      std: dict of their standard errors, √diag C.
      covariance: (p, p) C, in the order of ``names``.
      names: parameter names, in the order of ``covariance``.
      loss: L at the optimum.
      rms: √(RSS_w / (2 Σw)), the RMS residual of one target, in Δσ/σc.
      evaluations: {"adam": loss-and-gradient evaluations, "lbfgs": loss evaluations with the line search}.
      converged: whether L-BFGS reached the gradient tolerance within its iterations. A fit stopped short
        of it depends on the round-off of its path (the lab table's fit stopped at 100 iterations moved
        its parameters by up to 0.06 standard errors when the table became an argument of the compiled
        loss instead of a constant in it); converged, the two agree to 2e-9.
    """

    params: dict
    std: dict
    covariance: np.ndarray
    names: tuple
    loss: float
    rms: float
    evaluations: dict
    converged: bool


def _arrays(model, table, weights=None):
    inputs = {name: np.asarray(table.inputs[name], dtype=np.float64) for name in model.inputs}
    targets = np.stack([table.axial_target, table.radial_target]).astype(np.float64)
    finite = np.all(np.isfinite(targets), axis=0)
    for value in inputs.values():
        finite &= np.isfinite(value)
    weight = np.ones(table.num_rows) if weights is None else np.asarray(weights, dtype=np.float64)
    weight = np.where(finite, weight, 0.0)
    # Zeros where the weight is 0, so that no NaN reaches a gradient (0 · NaN is NaN).
    inputs = {name: jnp.asarray(np.where(finite, value, 0.0)) for name, value in inputs.items()}
    return inputs, jnp.asarray(np.where(finite, targets, 0.0)), jnp.asarray(weight)


def _weighted_residuals(predict, unravel, flat, inputs, targets, weight):
    """√w_i (a(θ, x_i) − Δσ_a,i/σc) then √w_i (r(θ, x_i) − Δσ_r,i/σc), θ = unravel(flat) (2n,)."""
    root = jnp.sqrt(weight)
    axial, radial = predict(unravel(flat), inputs)
    return jnp.concatenate([root * (axial - targets[0]), root * (radial - targets[1])])


def _residual_fn(model, inputs, targets, weight, unravel):
    return lambda flat: _weighted_residuals(model.predict, unravel, flat, inputs, targets, weight)


def strong_types(tree):
    """``tree`` with its weak-typed leaves made strong, same dtypes.

    optax's initial L-BFGS state holds weak-typed scalars that its updates return strong; a jitted step
    called first with the initial state and then with its own output would trace and compile twice.
    """
    return jax.tree.map(lambda leaf: jax.lax.convert_element_type(leaf, leaf.dtype), tree)


def _template(params: dict) -> tuple:
    """(name, shape) of each parameter, sorted: what the compiled steps of a model depend on."""
    return tuple((name, tuple(np.shape(params[name]))) for name in sorted(params))


class _Steps(NamedTuple):
    adam_init: Callable
    adam_step: Callable
    lbfgs_init: Callable
    lbfgs_step: Callable


@functools.lru_cache(maxsize=16)
def _optimiser_steps(predict: Callable, template: tuple, learning_rate: float) -> _Steps:
    """The jitted Adam and L-BFGS steps of a model, compiled once per model and table size.

    The table (inputs, targets, weights and Σw) is an argument of the steps, not a constant in them, so
    that the refits of a cross-validation, which differ only in their weights, run the same programs.
    """
    _, unravel = ravel_pytree({name: jnp.zeros(shape, jnp.float64) for name, shape in template})

    def loss(x, data):
        inputs, targets, weight, total = data
        r = _weighted_residuals(predict, unravel, x, inputs, targets, weight)
        return jnp.sum(r * r) / total

    adam = optax.adam(learning_rate)
    lbfgs = optax.lbfgs()

    @jax.jit
    def adam_step(x, state, data):
        value, grad = jax.value_and_grad(loss)(x, data)
        updates, state = adam.update(grad, state, x)
        return optax.apply_updates(x, updates), state, value

    @jax.jit
    def lbfgs_step(x, state, data):
        def value_fn(y):
            return loss(y, data)

        value, grad = optax.value_and_grad_from_state(value_fn)(x, state=state)
        updates, state = lbfgs.update(grad, state, x, value=value, grad=grad, value_fn=value_fn)
        return optax.apply_updates(x, updates), state, grad

    return _Steps(adam.init, adam_step, lbfgs.init, lbfgs_step)


def fit(
    model,
    table,
    weights=None,
    adam_steps: int = 300,
    learning_rate: float = 0.05,
    lbfgs_steps: int = 1000,
    tolerance: float = 1e-12,
) -> FitResult:
    """Fit ``model`` to ``table`` (module docstring).

    Args:
      model: a :class:`calibrate.models.CorrectionModel`.
      table: a :class:`calibrate.datasets.FittingTable`.
      weights: per-row weights (default 1); rows with non-finite data get 0.
      adam_steps: Adam iterations before L-BFGS.
      learning_rate: Adam's step size.
      lbfgs_steps: most L-BFGS iterations.
      tolerance: stop L-BFGS when the gradient's norm is below this.

    Raises:
      ValueError: fewer usable rows than parameters.
    """
    # optax mixes Python floats and int32 step counts, which strict dtype promotion refuses.
    with jax.enable_x64(True), jax.numpy_dtype_promotion("standard"):
        inputs, targets, weight = _arrays(model, table, weights)
        start = jax.tree_util.tree_map(lambda v: jnp.asarray(v, jnp.float64), model.initial_params)
        flat, unravel = ravel_pytree(start)
        num_params = int(flat.shape[0])
        rows = int(np.sum(np.asarray(weight) > 0.0))
        if 2 * rows <= num_params:
            raise ValueError(
                f"{rows} usable rows for {num_params} parameters: give more records (rows with a NaN input "
                "or target are left out)."
            )
        residuals = _residual_fn(model, inputs, targets, weight, unravel)
        total = jnp.sum(weight)
        data = (inputs, targets, weight, total)
        steps = _optimiser_steps(model.predict, _template(start), learning_rate)
        state = steps.adam_init(flat)
        for _ in range(adam_steps):
            flat, state, _ = steps.adam_step(flat, state, data)
        state = strong_types(steps.lbfgs_init(flat))
        evaluations = 0
        converged = False
        for _ in range(lbfgs_steps):
            flat, state, grad = steps.lbfgs_step(flat, state, data)
            evaluations += 1 + int(optax.tree_utils.tree_get(state, "num_linesearch_steps"))
            if float(jnp.linalg.norm(grad)) < tolerance:
                converged = True
                break
        r = residuals(flat)
        rss = float(jnp.sum(r * r))
        jacobian = jax.jacfwd(residuals)(flat)
        dof = max(2 * rows - num_params, 1)
        normal = np.asarray(jacobian.T @ jacobian)
        if np.linalg.matrix_rank(normal) < num_params:
            raise ValueError(
                f"the {num_params} parameters of model {model.name!r} are not all identifiable from these "
                f"records (JᵀJ has rank {np.linalg.matrix_rank(normal)}): give cases that differ in "
                f"{', '.join(model.inputs)}, or choose a model with fewer terms."
            )
        covariance = rss / dof * np.linalg.inv(normal)
        names = tuple(sorted(start))
        # ravel_pytree flattens a dict in sorted-key order, as ``names``.
        params = {name: float(value) for name, value in zip(names, np.asarray(flat), strict=True)}
        std = {name: float(np.sqrt(covariance[i, i])) for i, name in enumerate(names)}
        return FitResult(
            params,
            std,
            covariance,
            names,
            rss / float(total),  # L at the optimum, from the residuals already computed
            float(np.sqrt(rss / (2.0 * float(total)))),
            {"adam": adam_steps, "lbfgs": evaluations},
            converged,
        )


def predict(model, params: dict, table):
    """(Δσ_a/σc, Δσ_r/σc) of ``model`` with ``params`` over the rows of ``table`` (NaN where inputs are)."""
    with jax.enable_x64(True):
        inputs = {name: jnp.asarray(table.inputs[name], jnp.float64) for name in model.inputs}
        axial, radial = model.predict({k: jnp.asarray(v, jnp.float64) for k, v in params.items()}, inputs)
        return np.asarray(axial), np.asarray(radial)


def cross_validated_predictions(model, table, groups=None, held_out=None, progress=False, **fit_options):
    """(Δσ_a/σc, Δσ_r/σc) of every row, each predicted by a fit that left the row's group out.

    Args:
      model: a :class:`calibrate.models.CorrectionModel`.
      table: a :class:`calibrate.datasets.FittingTable`.
      groups: the label of each row's group (default ``table.case``: leave-one-case-out).
      held_out: the groups to leave out and predict, one refit each (default: every group); the rows of
        the others stay NaN.
      progress: a tqdm bar over the refits, on a terminal.
      **fit_options: passed to :func:`fit`.

    Returns:
      two float64 arrays over the rows (NaN where a row's inputs are).
    """
    from tqdm.auto import tqdm

    groups = table.case if groups is None else np.asarray(groups)
    axial = np.full(table.num_rows, np.nan)
    radial = np.full(table.num_rows, np.nan)
    weights = fit_options.pop("weights", None)
    weights = np.ones(table.num_rows) if weights is None else np.asarray(weights, dtype=np.float64)
    chosen = np.unique(groups) if held_out is None else np.asarray(held_out)
    for group in tqdm(chosen, desc="leave-one-case-out", unit="refit", disable=None if progress else True):
        held = groups == group
        # The group's rows weigh 0 rather than leave the table: the same loss, and every refit runs the
        # programs the first compiled (the table keeps its size).
        result = fit(model, table, weights=np.where(held, 0.0, weights), **fit_options)
        axial[held], radial[held] = predict(model, result.params, table.select(held))
    return axial, radial


def cross_validate(model, table, predictions=None, **fit_options) -> dict:
    """Leave-one-case-out: for each case, the RMS error in Δσ/σc (axial and radial) of a fit without it.

    Args:
      model: a :class:`calibrate.models.CorrectionModel`.
      table: a :class:`calibrate.datasets.FittingTable`.
      predictions: :func:`cross_validated_predictions` of ``model`` on ``table`` when already computed.
      **fit_options: passed to :func:`fit`.

    Returns:
      {case: {"axial": rms, "radial": rms}}.
    """
    if predictions is None:
        predictions = cross_validated_predictions(model, table, **fit_options)
    axial, radial = predictions
    scores = {}
    for case in np.unique(table.case):
        held = table.case == case
        axial_error = axial[held] - table.axial_target[held]
        radial_error = radial[held] - table.radial_target[held]
        scores[int(case)] = {
            "axial": float(np.sqrt(np.nanmean(axial_error**2))),
            "radial": float(np.sqrt(np.nanmean(radial_error**2))),
        }
    return scores


def nelder_mead_baseline(model, table, weights=None, max_evaluations: int = 20000) -> dict:
    """The same loss minimised by scipy's Nelder–Mead (gradient-free), from the model's starting point.

    Returns:
      {"params": dict, "loss": float, "evaluations": int, "converged": bool}.
    """
    import scipy.optimize

    with jax.enable_x64(True):
        inputs, targets, weight = _arrays(model, table, weights)
        start = jax.tree_util.tree_map(lambda v: jnp.asarray(v, jnp.float64), model.initial_params)
        flat, unravel = ravel_pytree(start)
        residuals = _residual_fn(model, inputs, targets, weight, unravel)
        total = float(jnp.sum(weight))
        loss = jax.jit(lambda x: jnp.sum(residuals(x) ** 2) / total)
        found = scipy.optimize.minimize(
            lambda x: float(loss(jnp.asarray(x))),
            np.asarray(flat),
            method="Nelder-Mead",
            options={"maxfev": max_evaluations, "xatol": 1e-10, "fatol": 1e-14, "adaptive": True},
        )
        names = tuple(sorted(start))
        return {
            "params": {name: float(v) for name, v in zip(names, found.x, strict=True)},
            "loss": float(found.fun),
            "evaluations": int(found.nfev),
            "converged": bool(found.success),
        }
