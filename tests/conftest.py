"""Test configuration: the whole suite runs in float64 with strict rank and dtype promotion.

Library code never enables x64 on import; the tests do it here, before any array is created.
``jax_numpy_rank_promotion="raise"`` turns silent broadcasting into errors and
``jax_numpy_dtype_promotion="strict"`` turns silent dtype promotion into errors (as in diffrax/equinox).

jax-md fights strict promotion: importing it runs array code that mixes float32 and int64, and its cell
list mixes dtypes and ranks when it builds. So jax-md is imported here before the strict settings, and
membrax's neighbour-list wrapper (membrax.spheres.neighbors) calls jax-md under local standard promotion. All
of membrax's own code runs strict.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # scipy's L-BFGS-B threads only contend on 2 cores
# One persistent compilation cache for the session, which the notebooks' kernels inherit (nbmake starts
# them from this process): a program compiled twice (the same specimen's step in a test and a notebook)
# is read back the second time. Set before jax is imported, which reads these at import.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    import tempfile

    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="membrax_jax_cache_")
# Every program, however small: building a specimen compiles ~400 small ones (jax-md's import ~130, the mesh
# and contact tables the rest; ~10 s on 2 cores), which each xdist worker, notebook kernel and CLI subprocess
# would compile again (a second process built the 4 × 4 × 5 specimen and ran 2,000 steps in 6.5 s from the
# cache, 14 s without).
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import jax

jax.config.update("jax_enable_x64", True)
import jax_md  # noqa: E402,F401  (imported before strict promotion, see above)

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")


import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(params=["float64", "float32"])
def precision(request):
    """Runs a test in float64 and in float32, what users run by default (``TriaxialConfig.float64 =
    False``): inside, JAX's default float is that dtype (``jax.enable_x64``, thread-local). Tolerances come
    from ``helpers.tolerance(precision)``."""
    with jax.enable_x64(request.param == "float64"):
        yield np.dtype(request.param)
