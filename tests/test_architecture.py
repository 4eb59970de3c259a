"""The house's map: imports run one way along the data flow, and the DEM never imports the membrane.

Data flow (README, Architecture): config → specimen + membrane → laws → step → driver → measurements →
protocol → results → runs → commands. Every module of ``membrax`` sits on one layer below; a module may
import its own layer and those before it, never one after (every import counts, also those inside
functions). The sphere code (DEM) and the membrane code are two columns of the same layers: the membrane
builds on the DEM, the DEM knows nothing of the membrane, so the rigid-wall test runs without it.
"""

import ast
from pathlib import Path

import pytest

import membrax

PACKAGE = Path(membrax.__file__).parent

LAYERS = (
    # foundations: no simulation state, import nothing above
    ("validation", "vector", "fusion", "native", "errors", "batch", "devices", "theory", "pytree"),
    ("config",),
    # specimen + membrane: geometry
    ("packing", "neighbors", "membrane"),
    # laws: contacts, walls and platens
    ("contact", "walls", "membrane_contact"),
    # step
    ("integrate", "membrane_dem", "indentation"),
    ("driver",),
    # measurements
    ("measure", "membrane_measure"),
    # protocol: consolidation and shearing
    ("triaxial", "membrane_triaxial"),
    # results
    ("analysis", "io", "plots", "paper"),
    # runs: the stage loop every run and sweep shares, then one test, a grid, the paper
    ("stages",),
    ("run",),
    ("sweep",),
    ("reproduce",),
    # commands: nothing imports them
    ("cli",),
)
DEM = {"packing", "neighbors", "contact", "walls", "integrate", "measure", "triaxial"}
MEMBRANE = {
    "membrane",
    "membrane_contact",
    "membrane_dem",
    "membrane_measure",
    "membrane_triaxial",
    "indentation",
}
LAYER = {name: level for level, names in enumerate(LAYERS) for name in names}


def _membrax_imports(path: Path) -> set[str]:
    """The membrax modules that ``path`` imports (``from membrax import x``, ``from membrax.x import y``,
    ``import membrax.x``), anywhere in the file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module:
            parts = node.module.split(".")
            if parts[0] != "membrax":
                continue
            if len(parts) > 1:
                found.add(parts[1])
            else:
                found.update(alias.name for alias in node.names if alias.name in LAYER)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "membrax" and len(parts) > 1:
                    found.add(parts[1])
    return found


MODULES = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__")


def test_every_module_has_a_layer():
    assert set(MODULES) == set(LAYER), set(MODULES) ^ set(LAYER)


@pytest.mark.parametrize("module", MODULES)
def test_imports_run_along_the_data_flow(module):
    imports = _membrax_imports(PACKAGE / f"{module}.py") - {module}
    above = sorted(name for name in imports if LAYER[name] > LAYER[module])
    assert not above, f"membrax.{module} (layer {LAYER[module]}) imports {above}, which come after it"
    if module in DEM:
        assert not imports & MEMBRANE, f"the DEM module membrax.{module} imports {sorted(imports & MEMBRANE)}"


def test_the_checker_sees_every_kind_of_import(tmp_path):
    """The reader itself, on a file with each form (a checker that sees nothing would pass everything)."""
    sample = tmp_path / "sample.py"
    sample.write_text(
        "from membrax import io as io_lib, theory\n"
        "import membrax.sweep\n"
        "def f():\n"
        "    from membrax.run import run_test\n"
        "    from membrax import __version__\n"
    )
    assert _membrax_imports(sample) == {"io", "theory", "sweep", "run"}
