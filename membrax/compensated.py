"""Compensated summation: positions that keep motions below their float's resolution.

Contract. :func:`compensated_add` is pure ``jax.numpy`` (jit, vmap, grad) on arrays of any shape and float
dtype; a state that moves by it carries its ``compensation`` beside its ``value`` (positions of spheres,
nodes and walls), and value + compensation is the position.
"""

from __future__ import annotations

__all__ = ["compensated_add"]


def compensated_add(value, compensation, increment):
    """(value + increment) by compensated (Kahan–Babuška/Fast2Sum) summation.

    Explicit DEM moves a body by ~1e-9 m per step, below float32 resolution at coordinates of 0.1 m
    (ulp 7e-9 m): a plain sum loses the motion. The rounding error of each sum is carried in
    ``compensation`` and fed back into the next increment, so value + compensation tracks the exact sum.

    Returns:
      (new value, new compensation).
    """
    corrected = increment + compensation
    total = value + corrected
    return total, corrected - (total - value)
