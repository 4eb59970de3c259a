"""membrax: a differentiable JAX simulator of triaxial tests on coarse-grained materials.

The package is built to calibrate membrane corrections for large-particle triaxial tests (railway
ballast, rockfill) at low cell pressures. Modules, one concept each:

- :mod:`membrax.theory`: closed forms (Rowe, Bolton, Molenkamp & Luger, classical membrane corrections)
  that users apply to their tests and that every simulation is checked against.
- :mod:`membrax.validation`: input checks at the user-facing edge.
- :mod:`membrax.cli`: the ``membrax`` command.

Library code never enables ``jax_enable_x64``; set ``JAX_ENABLE_X64=1`` (or
``jax.config.update("jax_enable_x64", True)``) yourself for double precision.
"""

from membrax import theory, validation

__version__ = "0.1.0"

__all__ = ["__version__", "theory", "validation"]
