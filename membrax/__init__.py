"""membrax: a differentiable JAX simulator of triaxial tests on coarse-grained materials.

The package is built to calibrate membrane corrections for large-particle triaxial tests (railway
ballast, rockfill) at low cell pressures. ``import membrax`` gives what a user needs (:data:`__all__`):

- configuration: :class:`TriaxialConfig`, :func:`load_config`, :data:`DEMO_CONFIG`, :data:`SMOKE_CONFIG`,
  :class:`ConfigError`;
- runs: :func:`run_test` (one test into a results folder), :func:`run_sweep` (a grid as one compiled
  batch), :func:`member_records`, :func:`split_cpu_devices` (one JAX device per core; call it first);
- gradients: :func:`sensitivity` (the consolidated equilibrium's derivatives by implicit differentiation,
  checked by finite differences of the simulator);
- results: :func:`read_results`;
- the factories under them: :func:`fcc_specimen`, :func:`random_packing` (a :class:`Grading` compacted
  in a mould), :func:`build_specimen` (a configuration's specimen), :func:`rigid_wall_test`,
  :func:`membrane_test`,
  the two step factories :func:`sphere_dem` (spheres alone) and :func:`membrane_dem` (spheres and
  membrane coupled),
  :func:`prism_mesh`;
- errors: :class:`ErrorCode` (a state's error bits), :class:`SimulationError`, :class:`RunError`;
- modules: :mod:`~membrax.theory` (closed forms), :mod:`~membrax.paper` (the paper's numbers and the
  comparison tables), ``analysis`` (:mod:`membrax.triaxial.analysis`), :mod:`~membrax.plots`;
  ``membrax.reproduce.reproduce`` is ``membrax reproduce``.

Every name is imported on first use (PEP 562), so ``import membrax`` starts no JAX backend and
:func:`split_cpu_devices` still works after it. The README's architecture section maps the modules.

Library code never enables ``jax_enable_x64``; set ``JAX_ENABLE_X64=1`` (or
``jax.config.update("jax_enable_x64", True)``) yourself for double precision.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# name → the module that defines it; one place, pinned by tests/test_api.py.
_API = {
    "ConfigError": "membrax.errors",
    "DEMO_CONFIG": "membrax.config",
    "SMOKE_CONFIG": "membrax.config",
    "TriaxialConfig": "membrax.config",
    "load_config": "membrax.config",
    "run_test": "membrax.run",
    "RunError": "membrax.errors",
    "RunResult": "membrax.run",
    "run_sweep": "membrax.sweep",
    "sensitivity": "membrax.sensitivities",
    "member_records": "membrax.sweep",
    "split_cpu_devices": "membrax.devices",
    "read_results": "membrax.io",
    "fcc_specimen": "membrax.spheres.fcc",
    "random_packing": "membrax.spheres.compaction",
    "Grading": "membrax.spheres.grading",
    "build_specimen": "membrax.assemble",
    "rigid_wall_test": "membrax.triaxial.rigid",
    "membrane_test": "membrax.triaxial.membrane_cell",
    "sphere_dem": "membrax.spheres.integrate",
    "membrane_dem": "membrax.membrane.coupled",
    "prism_mesh": "membrax.membrane.mesh",
    "ErrorCode": "membrax.errors",
    "SimulationError": "membrax.errors",
}
_MODULES = {
    "analysis": "membrax.triaxial.analysis",
    "paper": "membrax.paper",
    "plots": "membrax.plots",
    "theory": "membrax.theory",
    "validation": "membrax.validation",
}

__all__ = ["__version__", *_API, *_MODULES]


def __getattr__(name: str):
    if name in _API:
        value = getattr(importlib.import_module(_API[name]), name)
    elif name in _MODULES:
        value = importlib.import_module(_MODULES[name])
    else:
        raise AttributeError(f"module 'membrax' has no attribute {name!r}")
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
