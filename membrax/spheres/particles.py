"""The mass properties of a solid sphere, and the density membrax assumes.

Contract: :func:`particle_mass` and :func:`moment_of_inertia` are pure ``jax.numpy`` in SI units (m, kg/m³,
kg, kg·m²), and work under ``jax.jit``, ``jax.vmap`` and ``jax.grad``; integer input becomes JAX's default
float dtype, float input keeps its dtype. Invalid values (non-positive, NaN) raise ``ValueError`` naming
the argument (:mod:`membrax.validation`; skipped for tracers).
"""

from __future__ import annotations

import math

from membrax.validation import as_float, check_range

__all__ = ["GRANITE_DENSITY", "moment_of_inertia", "particle_mass"]

#: Particle density in kg/m³. The paper gives no density; 2650 kg/m³ is granite (assumed).
GRANITE_DENSITY = 2650.0


def particle_mass(radius, density):
    """Mass of a solid sphere, m = (4/3) π R³ ρ.

    Args:
      radius: R in m, > 0 (scalar or array; broadcasts with ``density``).
      density: ρ in kg/m³, > 0 (e.g. :data:`GRANITE_DENSITY`).

    Returns:
      m in kg, in the float dtype of the inputs.
    """
    check_range("radius", radius, lower=0.0, lower_open=True, hint="Metres.")
    check_range("density", density, lower=0.0, lower_open=True, hint="kg/m³, e.g. 2650 for granite.")
    radius = as_float(radius)
    return (4.0 / 3.0 * math.pi) * as_float(density) * radius**3


def moment_of_inertia(mass, radius):
    """Moment of inertia of a solid sphere about any axis through its centre, I = (2/5) m R².

    Args:
      mass: m in kg, > 0.
      radius: R in m, > 0.

    Returns:
      I in kg·m², in the float dtype of the inputs.
    """
    check_range("mass", mass, lower=0.0, lower_open=True, hint="kg.")
    check_range("radius", radius, lower=0.0, lower_open=True, hint="Metres.")
    radius = as_float(radius)
    return 0.4 * as_float(mass) * radius**2
