"""Input checks at the user-facing edge.

Contract: ``check_range(name, value, ...)`` raises ``ValueError`` naming the argument, the accepted range
and the offending value when a *concrete* input is NaN or out of range, and returns ``None`` otherwise.

Inside ``jax.jit``, ``jax.vmap`` or ``jax.grad`` the inputs are tracers whose values are unknown, so the
check is skipped there: a traced program carries no host-side checks (they would force a device sync and
cannot raise anyway). Users who call the public functions eagerly, with numbers or arrays, get the check.
``as_float`` turns the checked input into an array of a float dtype, as the laws compute in it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["as_float", "check_range", "is_traced"]


def is_traced(value) -> bool:
    """True when ``value`` (or any leaf of it) is a JAX tracer, i.e. we are inside a transformation."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(value))


def _fmt_bound(bound: float) -> str:
    return f"{bound:g}"


def check_range(
    name: str,
    value,
    *,
    lower: float | None = None,
    upper: float | None = None,
    lower_open: bool = False,
    upper_open: bool = False,
    hint: str = "",
) -> None:
    """Raise ``ValueError`` if a concrete ``value`` is NaN or outside the given interval.

    Args:
      name: the argument's name as the user typed it (e.g. ``"membrane_thickness"``).
      value: a scalar or array; tracers are not checked (see the module docstring).
      lower: lower bound of the accepted interval; ``None`` means unbounded.
      upper: upper bound; ``None`` means unbounded.
      lower_open: exclude the lower bound itself (``lower=0, lower_open=True`` means "> 0").
      upper_open: exclude the upper bound itself.
      hint: an extra sentence on how to fix the input (units, typical values).

    Raises:
      ValueError: naming ``name``, the accepted range and the worst offending value.
    """
    if value is None or is_traced(value):
        return
    array = np.asarray(value, dtype=float)
    left = "(" if lower_open else "["
    right = ")" if upper_open else "]"
    lo = "-inf" if lower is None else _fmt_bound(lower)
    hi = "inf" if upper is None else _fmt_bound(upper)
    accepted = f"{left}{lo}, {hi}{right}"
    suffix = f" {hint}" if hint else ""
    if np.isnan(array).any():
        raise ValueError(f"{name} is NaN; accepted range is {accepted}.{suffix}")
    bad = np.zeros(array.shape, dtype=bool)
    if lower is not None:
        bad |= (array <= lower) if lower_open else (array < lower)
    if upper is not None:
        bad |= (array >= upper) if upper_open else (array > upper)
    if bad.any():
        offending = array[bad].ravel()[0]
        shown = f"{offending:g}" if math.isfinite(offending) else str(offending)
        raise ValueError(f"{name} = {shown} is outside the accepted range {accepted}.{suffix}")


def as_float(x):
    """``jnp.asarray`` that turns integer input into JAX's default float dtype (float dtypes are kept)."""
    array = jnp.asarray(x)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        array = array.astype(jnp.result_type(float))
    return array
