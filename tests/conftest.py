"""Test configuration: the whole suite runs in float64 with strict rank and dtype promotion.

Library code never enables x64 on import; the tests do it here, before any array is created.
``jax_numpy_rank_promotion="raise"`` turns silent broadcasting into errors and
``jax_numpy_dtype_promotion="strict"`` turns silent dtype promotion into errors (as in diffrax/equinox).
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")
