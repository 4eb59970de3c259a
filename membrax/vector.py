"""Small-vector algebra on component-first arrays.

Contract. A vector field is an array of shape (3, ...): its first axis holds the x, y, z components and
the rest index contacts or particles, so one formula serves a single contact (3,) and a million (3, C).
Products are written out component by component because XLA's CPU backend reduces over a size-3 axis
about 25× slower than it adds three rows (measured: 131 µs vs 5.6 µs for 11,865 vectors), and the contact
laws are made of dot products.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["cross", "dot", "safe_norm", "safe_normalize", "scale", "select"]


def scale(factor, vector):
    """Factor · vector with one factor per vector: (...) × (3, ...), without implicit rank promotion."""
    factor = jnp.asarray(factor)
    return (factor[None] if factor.ndim else factor) * vector


def select(condition, vector, other=0.0):
    """``jnp.where`` with one condition per vector: (...) and (3, ...)."""
    condition = jnp.asarray(condition)
    return jnp.where(condition[None] if condition.ndim else condition, vector, other)


def dot(a, b):
    """a·b over the first axis."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    """A × b over the first axis."""
    return jnp.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def safe_norm(a):
    """|a| with a finite gradient at a = 0 (the double ``where`` of jax-md's ``safe_mask``)."""
    squared = dot(a, a)
    is_zero = squared == 0.0
    return jnp.where(is_zero, 0.0, jnp.sqrt(jnp.where(is_zero, 1.0, squared)))


def safe_normalize(a):
    """(a/|a|, |a|), with a zero direction (and finite gradients) where a = 0."""
    length = safe_norm(a)
    positive = length > 0.0
    return select(positive, scale(1.0 / jnp.where(positive, length, 1.0), a)), length
