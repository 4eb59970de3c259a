"""The public API of ``import membrax`` (optax's ``optax_test.py`` is the model): the names, where they
come from, and that importing the package starts no JAX backend."""

import subprocess
import sys

import membrax

EXPECTED = {
    "__version__",
    # configuration
    "ConfigError",
    "DEMO_CONFIG",
    "SMOKE_CONFIG",
    "TriaxialConfig",
    "load_config",
    # runs and results
    "run_test",
    "RunError",
    "RunResult",
    "run_sweep",
    "sensitivity",
    "member_records",
    "split_cpu_devices",
    "read_results",
    # factories
    "fcc_specimen",
    "random_packing",
    "Grading",
    "build_specimen",
    "rigid_wall_test",
    "membrane_test",
    "sphere_dem",
    "membrane_dem",
    "prism_mesh",
    # errors
    "ErrorCode",
    "SimulationError",
    # modules
    "analysis",
    "paper",
    "plots",
    "theory",
    "validation",
}


def test_the_api_is_exactly_the_curated_names():
    assert set(membrax.__all__) == EXPECTED
    assert len(membrax.__all__) == len(EXPECTED)  # no duplicates


def test_every_name_resolves_to_its_defining_module():
    from membrax import assemble, config, devices, errors, io, run, sensitivities, sweep
    from membrax.membrane import coupled, mesh
    from membrax.spheres import compaction, fcc, grading, integrate
    from membrax.triaxial import membrane_cell, rigid

    homes = {
        "TriaxialConfig": config,
        "load_config": config,
        "run_test": run,
        "run_sweep": sweep,
        "sensitivity": sensitivities,
        "member_records": sweep,
        "split_cpu_devices": devices,
        "read_results": io,
        "fcc_specimen": fcc,
        "random_packing": compaction,
        "Grading": grading,
        "build_specimen": assemble,
        "rigid_wall_test": rigid,
        "membrane_test": membrane_cell,
        "sphere_dem": integrate,
        "membrane_dem": coupled,
        "prism_mesh": mesh,
        "ErrorCode": errors,
        "SimulationError": errors,
        "RunError": errors,
        "ConfigError": errors,
    }
    for name, module in homes.items():
        assert getattr(membrax, name) is getattr(module, name), name
    assert membrax.paper.__name__ == "membrax.paper" and membrax.theory.__name__ == "membrax.theory"
    assert membrax.analysis.__name__ == "membrax.triaxial.analysis"
    assert membrax.DEMO_CONFIG["particles_across"] == 6
    assert set(dir(membrax)) >= EXPECTED


def test_an_unknown_name_is_an_attribute_error():
    try:
        membrax.run_tests  # noqa: B018
    except AttributeError as error:
        assert "run_tests" in str(error)
    else:
        raise AssertionError("membrax.run_tests resolved")


def test_importing_membrax_imports_no_jax():
    """So split_cpu_devices() can still set the device count after ``import membrax``."""
    code = "import sys, membrax; print(membrax.__version__); print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == [membrax.__version__, "False"]
