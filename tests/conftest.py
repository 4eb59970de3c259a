"""Test configuration: the whole suite runs in float64 with strict rank and dtype promotion.

Library code never enables x64 on import; the tests do it here, before any array is created.
``jax_numpy_rank_promotion="raise"`` turns silent broadcasting into errors and
``jax_numpy_dtype_promotion="strict"`` turns silent dtype promotion into errors (as in diffrax/equinox).

jax-md fights strict promotion: its package import runs array code that mixes float32 and int64, and its
cell list mixes dtypes and ranks when it builds. membrax's neighbour-list wrapper (membrax.spheres.neighbors)
loads only jax-md's ``space`` and ``partition`` (not the package's import) and calls them under local
standard promotion. All of membrax's own code runs strict.
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
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")


import numpy as np  # noqa: E402
import pytest  # noqa: E402

try:  # private: see _compile_small_programs_quickly
    from jax._src import compiler
    from jax._src.lib.mlir import ir
except ImportError:  # pragma: no cover
    compiler = None


@pytest.fixture(params=["float64", "float32"])
def precision(request):
    """Runs a test in float64 and in float32, what users run by default (``TriaxialConfig.float64 =
    False``): inside, JAX's default float is that dtype (``jax.enable_x64``, thread-local). Tolerances come
    from ``helpers.tolerance(precision)``."""
    with jax.enable_x64(request.param == "float64"):
        yield np.dtype(request.param)


#: The files that take longest on 2 cores (``--durations``, 2026-11-26: the gradient notebook 214–327 s, the
#: gradient, sweep, run and loading tests 2–4 min each), handed out first. ``--dist loadfile`` gives each
#: worker the next file in the queue when it runs low, and xdist's default queue puts the files with most
#: tests first, so the one-item notebooks came last: a worker was still running the 3.5-min gradient
#: notebook while the other had finished (wall 17 min 55 s against 30 min 48 s of CPU on 2 workers; in this
#: order 15 min 48 s against 29 min 7 s).
#: xdist hands each worker one file and then a second (``LoadScopeScheduling.schedule``), so the third
#: file, the gradient notebook, queues behind the gradient tests on the first worker: it runs their rollout
#: at the same sizes (on purpose) and, run after them, reads those programs from the persistent cache
#: instead of compiling them beside them. The inverse problem is checked in the notebook alone.
LONG_FIRST = (
    "tests/test_gradients.py",
    "tests/test_sweep.py",
    "tests/test_campaign.py",
    "notebooks/04_gradients.ipynb",
    "tests/test_run.py",
    "tests/test_loading.py",
    "notebooks/02_reproduce_paper.ipynb",
    "tests/test_sensitivity.py",
    "tests/test_correct.py",
    "tests/test_membrane_dem.py",
    "tests/test_dem.py",
    "notebooks/01_quickstart.ipynb",
    "notebooks/03_parameter_study.ipynb",
    "tests/test_compaction.py",
    "notebooks/06_random_specimens.ipynb",
    "notebooks/07_random_vs_fcc.ipynb",
    "tests/test_random_run.py",
)


def pytest_configure(config):
    """Keep the collection order below for xdist's queue (its reorder by test count would undo it)."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """The files of :data:`LONG_FIRST` first, in that order; the rest after, in their own order (stable)."""
    rank = {path: k for k, path in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(LONG_FIRST)))


#: The files whose time is spent running XLA's own code (the periodic element's step, reverse mode through
#: long rollouts, compaction) or whose checks hold the shipped fit to 1e-6, which XLA's round-off at another
#: optimisation level moves (1.5e-5 measured). Every other file runs with XLA's backend at its lowest
#: optimisation (``jax_disable_most_optimizations``): their time is mostly compiling small specimens'
#: programs, whose hot loops are membrax's own compiled kernels (membrax/native), which this does not touch.
#: Measured on 2 cores, the whole suite in each mode (2026-12-07, --durations): test_native 419 → 285 s,
#: test_membrane_dem 145 → 101 s, test_sweep 193 → 153 s, notebook 07 114 → 86 s; these files the other way:
#: test_periodic 181 → 317 s, notebook 04 132 → 186 s, test_gradients 84 → 116 s, test_compaction 63 → 94 s,
#: test_stage_checkpoint 36 → 64 s; also kept at users' level, as measured slower at the lowest:
#: test_face_contact 85 → 94 s, test_indentation 13 → 16 s, notebook 08 6 → 8 s; and test_calibrate, whose
#: fits are test_correct's kind. No operation changes its meaning either way (no fast-math in either);
#: a test comparing two paths compiles both in its file's mode. ``MEMBRAX_TEST_XLA_OPTIMIZED=1``: every
#: file as users' programs compile.
XLA_OPTIMIZED = frozenset(
    {
        "tests/test_periodic.py",
        "tests/test_gradients.py",
        "notebooks/04_gradients.ipynb",
        "tests/test_compaction.py",
        "tests/test_stage_checkpoint.py",
        "tests/test_face_contact.py",
        "tests/test_indentation.py",
        "tests/test_correct.py",
        "tests/test_calibrate.py",
        "notebooks/08_boundaries.ipynb",
    }
)


_xla_optimized = [None]  # the level this process compiles at now (None: not set yet), mutable in place

#: A program of at most this many MLIR operations is one eager operation or a few (``a + b`` on arrays: 5-8;
#: a jitted chunk of steps: tens of thousands).
SMALL_PROGRAM_OPERATIONS = 100


def _is_small(module) -> bool:
    """Whether the MLIR ``module`` has at most :data:`SMALL_PROGRAM_OPERATIONS` operations."""
    count = 0

    def visit(operation):
        nonlocal count
        count += 1
        return ir.WalkResult.INTERRUPT if count > SMALL_PROGRAM_OPERATIONS else ir.WalkResult.ADVANCE

    module.operation.walk(visit)
    return count <= SMALL_PROGRAM_OPERATIONS


def _compile_small_programs_quickly(backend, computation, devices, compile_options, *args, **kwargs):
    """A small program (an eager operation) is compiled with XLA-CPU's LLVM IR emitters instead of its MLIR
    fusion emitters, at either optimisation level (:data:`XLA_OPTIMIZED`).

    Each eager operation on a new shape or dtype is a program of its own: test_native alone compiles
    ~3,800 of them, 113 s of its 390 s in one process. The older emitters compile one in 11-19 ms instead
    of 26-37 (``a + a`` on (k, 3) float64 rows). Larger programs (every jitted step, chunk and rollout)
    compile as before: with the older emitters for all programs, a batched member's bits depended on the
    batch's size (1-2 ulp in 5 of 22 stresses of test_sweep's failure isolation), which users' emitters
    keep equal. The files at users' level lost 40 s of their 440 s of backend compiling this way (the eight
    files alone, 2 workers). The option is part of the program's key in JAX's persistent cache
    (``env_option_overrides`` are hashed). JAX's private compile entry point is wrapped in pytest's own
    processes only (notebook kernels and subprocesses compile as users' programs do), and not at all with
    ``MEMBRAX_TEST_XLA_OPTIMIZED=1``; if it moves, programs compile as users' do.
    """
    if backend.platform == "cpu" and _is_small(computation):
        compile_options.env_option_overrides = [
            *compile_options.env_option_overrides,
            ("xla_cpu_use_fusion_emitters", False),
        ]
    return _compile_or_get_cached(backend, computation, devices, compile_options, *args, **kwargs)


if (
    compiler is not None
    and hasattr(compiler, "compile_or_get_cached")
    and os.environ.get("MEMBRAX_TEST_XLA_OPTIMIZED") != "1"
):
    _compile_or_get_cached = compiler.compile_or_get_cached
    compiler.compile_or_get_cached = _compile_small_programs_quickly


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """XLA's optimisation level for ``item``'s file (:data:`XLA_OPTIMIZED`), before its fixtures compile.

    The flag is read at each compilation but is not part of JAX's in-memory caches' keys, so they are
    cleared where the level changes (``--dist loadfile``: between files); the persistent cache's key holds
    the level, so a program compiled before at this level is read back from it. The environment variable
    carries the level to notebook kernels and subprocesses (the CLI tests, test_campaign's workers).
    """
    optimized = (
        os.environ.get("MEMBRAX_TEST_XLA_OPTIMIZED") == "1" or item.nodeid.split("::")[0] in XLA_OPTIMIZED
    )
    if _xla_optimized[0] is not optimized:
        if _xla_optimized[0] is not None:
            jax.clear_caches()
        jax.config.update("jax_disable_most_optimizations", not optimized)
        _xla_optimized[0] = optimized
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "0" if optimized else "1"
