"""The house's map: imports run one way along the data flow, and the DEM never imports the membrane.

Data flow (README, Architecture): config → specimen + membrane → laws → step → driver → measurements →
protocol → results → runs → commands. The configuration is the user's edge: it converts laboratory units to
SI and validates; its fields are read where it becomes a test (``assemble``) and by the one test's entry
point (``run``), the other runs and the commands pass it on; the simulator below it takes SI and shares its
defaults through ``membrax.defaults``. Every module of ``membrax`` sits on one layer below; a module may
import its own layer and those before it, never one after (every import counts, also those inside
functions). The sphere code (DEM) and the membrane code are two columns of the same layers: the membrane
builds on the DEM, the DEM knows nothing of the membrane, so the rigid-wall test runs without it.
"""

import ast
import dataclasses
import re
from pathlib import Path

import pytest

import membrax
from membrax.config import TriaxialConfig

PACKAGE = Path(membrax.__file__).parent

LAYERS = (
    # foundations: no simulation state, import nothing above
    (
        "validation",
        "vector",
        "compensated",
        "fusion",
        "native",
        "errors",
        "batch",
        "devices",
        "theory._ranges",
        "theory.measures",
        "theory.strength",
        "theory.penetration",
        "theory.corrections",
        "theory",
        "pytree",
    ),
    ("defaults",),
    # specimen + membrane: geometry
    (
        "spheres.particles",
        "spheres.fcc",
        "spheres.grading",
        "spheres.neighbors",
        "membrane.mesh",
        "membrane.candidates",
    ),
    # laws: contacts, walls and platens
    (
        "spheres.contact",
        "spheres._kernels",
        "spheres.walls",
        "spheres.periodic",
        "membrane.energies",
        "membrane._kernels",
        "membrane.contact",
        "membrane.face_contact",
    ),
    ("membrane.stability",),
    # step
    ("spheres.integrate", "membrane.node_update", "membrane.coupled", "membrane.indentation"),
    ("spheres.stability",),
    ("driver",),
    # measurements
    ("spheres.measure", "membrane.measure", "membrane.records"),
    # specimens made by a DEM run: the compaction of a random packing
    ("spheres.mould",),
    ("spheres.fire",),
    ("spheres.compaction",),
    # protocol: consolidation and shearing
    ("triaxial.protocol",),
    ("triaxial.rigid", "triaxial.periodic", "triaxial.membrane_cell"),
    # results
    (
        "triaxial.analysis",
        "io.files",
        "io.vtk",
        "io.results",
        "io.checkpoint",
        "io",
        "plots",
        "paper.published",
        "paper.tables",
        "paper.fig9",
        "paper",
    ),
    # one cell's stages checkpointed as they go (io.checkpoint): a random packing made in the periodic cell
    ("triaxial.stage_checkpoint",),
    ("triaxial.periodic_packing",),
    # the configuration: laboratory units in, SI out; its fields read by assemble and run only
    ("config",),
    # runs: a configuration becomes a test, members become a batch, the stage loop every run and sweep
    # shares, then one test, a grid, the paper
    ("assemble",),
    ("planning",),
    ("executor",),
    ("run_records",),
    ("runner",),
    ("run", "sensitivities", "gradients"),
    ("campaign", "sweep"),
    ("reproduce",),
    # commands: the calibrate half (fit, correct, serve), then the command nothing imports
    ("cli_calibrate",),
    ("cli",),
)
#: Subpackages that are namespaces only: their __init__ imports nothing, so importing them is free.
NAMESPACES = ("spheres", "membrane", "triaxial")
DEM = {name for names in LAYERS for name in names if name.startswith("spheres.")} | {
    "triaxial.rigid",
    "triaxial.periodic",
    "triaxial.periodic_packing",
}
MEMBRANE = {name for names in LAYERS for name in names if name.startswith("membrane.")} | {
    "triaxial.membrane_cell"
}
LAYER = {name: level for level, names in enumerate(LAYERS) for name in names}


def _membrax_imports(path: Path) -> set[str]:
    """The membrax modules that ``path`` imports, as dotted names below ``membrax`` (``from membrax import
    x``, ``from membrax.x import y``, ``from membrax.pkg import module``, ``import membrax.x``), anywhere in
    the file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module:
            parts = node.module.split(".")
            if parts[0] != "membrax":
                continue
            below = ".".join(parts[1:])
            if below and below not in NAMESPACES:
                found.add(below)
            else:
                prefix = f"{below}." if below else ""
                found.update(
                    f"{prefix}{alias.name}" for alias in node.names if f"{prefix}{alias.name}" in LAYER
                )
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "membrax" and len(parts) > 1:
                    found.add(".".join(parts[1:]))
    return found


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


FILES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py")) if p != PACKAGE / "__init__.py"}
MODULES = sorted(name for name in FILES if name not in NAMESPACES)


def test_every_module_has_a_layer_and_namespaces_import_nothing():
    assert set(MODULES) == set(LAYER), set(MODULES) ^ set(LAYER)
    for namespace in NAMESPACES:
        assert _membrax_imports(FILES[namespace]) == set(), namespace


@pytest.mark.parametrize("module", MODULES)
def test_imports_run_along_the_data_flow(module):
    imports = _membrax_imports(FILES[module]) - {module}
    unknown = sorted(imports - set(LAYER))
    assert not unknown, f"membrax.{module} imports {unknown}, which are not modules of a layer"
    above = sorted(name for name in imports if LAYER[name] > LAYER[module])
    assert not above, f"membrax.{module} (layer {LAYER[module]}) imports {above}, which come after it"
    if module in DEM:
        assert not imports & MEMBRANE, f"the DEM module membrax.{module} imports {sorted(imports & MEMBRANE)}"


#: The simulator: every layer from the specimen to the results. It takes SI and never reads the configuration.
SIMULATOR = {name for name, level in LAYER.items() if LAYER["spheres.fcc"] <= level < LAYER["config"]}


def test_no_module_below_the_configuration_imports_it():
    """Units are converted and validated once, in the configuration; the simulator (specimen to results)
    takes SI arguments, so none of its modules imports :mod:`membrax.config` (defaults it shares with the
    configuration come from :mod:`membrax.defaults`)."""
    readers = sorted(name for name in SIMULATOR if "config" in _membrax_imports(FILES[name]))
    assert not readers, f"{readers} import membrax.config"
    assert {"triaxial.membrane_cell", "membrane.coupled", "triaxial.protocol", "paper"} <= SIMULATOR


def test_the_checker_sees_every_kind_of_import(tmp_path):
    """The reader itself, on a file with each form (a checker that sees nothing would pass everything)."""
    sample = tmp_path / "sample.py"
    sample.write_text(
        "from membrax import io as io_lib, theory\n"
        "import membrax.sweep\n"
        "from membrax.spheres import integrate, fcc as specimen\n"
        "from membrax.membrane.coupled import membrane_dem\n"
        "def f():\n"
        "    from membrax.run import run_test\n"
        "    from membrax import __version__\n"
    )
    assert _membrax_imports(sample) == {
        "io",
        "theory",
        "sweep",
        "run",
        "spheres.integrate",
        "spheres.fcc",
        "membrane.coupled",
    }


def test_membrax_never_imports_calibrate_except_the_command_line():
    """calibrate sits after every layer of membrax but the commands (README: … → runs → calibrate →
    commands): only ``cli``, the leaf nothing imports, and its calibrate half ``cli_calibrate`` reach it
    (``membrax fit``, ``correct``, ``serve``)."""
    for name, path in FILES.items():
        if name in ("cli", "cli_calibrate"):
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            modules = []
            if isinstance(node, ast.ImportFrom) and node.module:
                modules = [node.module]
            elif isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            assert not any(m.split(".")[0] == "calibrate" for m in modules), (
                f"membrax.{name} imports calibrate"
            )


#: Where a loop over time steps may be written (``lax.fori_loop``, ``lax.scan``, ``lax.while_loop`` for a
#: traced step count): the driver's one chunk body (:func:`membrax.driver.advance`,
#: :func:`membrax.driver.record_blocks`).
LOOP_HOMES = {"fori_loop": {"driver"}, "scan": {"driver"}, "while_loop": {"driver"}}


def _loop_calls(path: Path) -> set[str]:
    """The ``lax`` loop primitives a file calls (``jax.lax.scan(...)``, ``lax.fori_loop(...)``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in LOOP_HOMES
        ):
            owner = node.func.value
            if (isinstance(owner, ast.Attribute) and owner.attr == "lax") or (
                isinstance(owner, ast.Name) and owner.id == "lax"
            ):
                found.add(node.func.attr)
    return found


def test_one_chunk_body_the_time_loops_live_in_the_driver():
    calls = {name: _loop_calls(path) for name, path in FILES.items()}
    for primitive, homes in LOOP_HOMES.items():
        where = {name for name, found in calls.items() if primitive in found}
        assert where == homes, f"lax.{primitive} is called in {sorted(where)}; only in {sorted(homes)}"


def test_the_loop_reader_sees_both_spellings(tmp_path):
    sample = tmp_path / "loops.py"
    sample.write_text(
        "import jax\nfrom jax import lax\n"
        "def f(s):\n"
        "    s = jax.lax.fori_loop(0, 3, g, s)\n"
        "    return lax.scan(h, s, None, length=2)\n"
        "def q(x):\n    return x.scan(1)\n"
    )
    assert _loop_calls(sample) == {"fori_loop", "scan"}


#: Loops outside the driver that may read error bits, and why.
HOST_LOOP_EXCEPTIONS = {
    # Allocates one table at given positions, growing it until nothing overflows: the table growth that
    # driver.grow_tables calls, not a loop over time steps.
    "spheres.neighbors": "allocate_shared",
}
_CHUNK_NAME = re.compile(r"(^|_)chunk$")


def _loop_body_nodes(loop):
    """The nodes a loop runs on each pass: its body, not the bodies of functions defined in it (callbacks
    handed to the driver run there, not here)."""
    pending = list(loop.body) + list(getattr(loop, "orelse", []))
    while pending:
        node = pending.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            pending.extend(ast.iter_child_nodes(node))


def _host_loops(path: Path) -> list[str]:
    """Loops in ``path`` that launch a compiled chunk (a callable named ``chunk``, ``_chunk``, ``…_chunk``;
    hooks ``on_chunk``/``after_chunk`` aside) or read a state's error bits (``.error``,
    ``.did_buffer_overflow``): each a host loop of its own beside :func:`membrax.driver.drive`."""
    found = []
    tree = ast.parse(path.read_text(), filename=str(path))
    functions = {
        id(node): parent.name
        for parent in ast.walk(tree)
        if isinstance(parent, (ast.FunctionDef, ast.AsyncFunctionDef))
        for node in ast.walk(parent)
    }
    for loop in ast.walk(tree):
        if not isinstance(loop, (ast.For, ast.While, ast.AsyncFor)):
            continue
        for node in _loop_body_nodes(loop):
            if isinstance(node, ast.Call):
                name = getattr(node.func, "id", getattr(node.func, "attr", ""))
                if _CHUNK_NAME.search(name) and not name.startswith(("on_", "after_")):
                    found.append(f"{functions.get(id(loop), '<module>')}:{loop.lineno} calls {name}")
            elif isinstance(node, ast.Attribute) and node.attr in ("error", "did_buffer_overflow"):
                found.append(f"{functions.get(id(loop), '<module>')}:{loop.lineno} reads .{node.attr}")
    return sorted(found)


def test_driver_drive_is_the_one_host_loop():
    """Compaction, FIRE, the continuation differences and the gradient rollouts run their chunks through
    driver.drive: no other loop launches a chunk or reads error bits (HOST_LOOP_EXCEPTIONS: stated)."""
    offenders = {}
    for name, path in FILES.items():
        if name == "driver":
            continue
        loops = _host_loops(path)
        allowed = HOST_LOOP_EXCEPTIONS.get(name)
        loops = [loop for loop in loops if allowed is None or not loop.startswith(f"{allowed}:")]
        if loops:
            offenders[name] = loops
    assert offenders == {}


def test_the_host_loop_reader_sees_chunks_and_error_bits_but_not_callbacks(tmp_path):
    sample = tmp_path / "loops.py"
    sample.write_text(
        "def relax(state, chunk, drive):\n"
        "    while True:\n"
        "        state = chunk(state)\n"  # a loop launching a chunk
        "    for k in range(3):\n"
        "        def step(s):\n"
        "            return s._chunk(s.error)\n"  # a callback: runs in the driver
        "        drive(step, on_chunk=print)\n"
        "    for k in range(2):\n"
        "        if state.dem.error:\n"  # reads error bits
        "            break\n"
        "        state = relax_chunk(state)\n"
    )
    assert _host_loops(sample) == ["relax:2 calls chunk", "relax:8 calls relax_chunk", "relax:8 reads .error"]


def test_no_module_renames_a_membrax_module_on_import():
    """``from membrax.membrane import mesh as membrane`` made one module answer to three names; a module
    is imported under its own name, or its names are imported directly."""
    renamed = []
    for name, path in FILES.items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("membrax"):
                for alias in node.names:
                    module = f"{node.module}.{alias.name}".removeprefix("membrax.")
                    if alias.asname and alias.asname != alias.name and module in LAYER:
                        renamed.append(f"membrax.{name}: {module} as {alias.asname}")
    assert not renamed, renamed


def test_every_runaway_of_a_host_loop_is_a_simulation_error():
    """No module raises FloatingPointError: a loop that cannot go on raises membrax.errors.SimulationError,
    which names the state, and the CLI reports it in one line (RuntimeError is left to the build of the
    kernels, a missing compiler, not a simulation)."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None:
                call = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                name = getattr(call, "id", getattr(call, "attr", ""))
                if name == "FloatingPointError":
                    offenders.append(f"{path.relative_to(PACKAGE)}:{node.lineno} raises {name}")
    assert offenders == []


#: Where a configuration's fields are read: the configuration itself, the assembly
#: module that turns it into a test and into the plain values below it (:class:`membrax.assemble.RunSettings`,
#: :func:`membrax.assemble.report_values`), and :mod:`membrax.run`, the one test's entry point (folder,
#: precision, VTK cadence, summary). Everything else takes plain values: the executor and the runner, and
#: the sweep, the reproduction and the commands, which build, validate and pass configurations on.
CONFIG_READERS = {"config", "assemble", "run"}
#: What a configuration answers to: its fields, properties and methods (``TriaxialConfig``'s public names).
CONFIG_ATTRIBUTES = {name for name in dir(TriaxialConfig) if not name.startswith("_")} | {
    field.name for field in dataclasses.fields(TriaxialConfig)
}
#: Calls that return a configuration, and the names a configuration goes by in membrax by convention.
CONFIG_MAKERS = {"TriaxialConfig", "with_overrides", "load_config", "config_from_dict"}
CONFIG_NAMES = {"config", "configs"}


def _holds_config(node, held: set[str]) -> bool:
    """Whether ``node`` evaluates to a configuration (or a list of them)."""
    if isinstance(node, ast.Name):
        return node.id in held
    if isinstance(node, ast.Attribute):  # batch.configs, self.config
        return node.attr in CONFIG_NAMES
    if isinstance(node, ast.Subscript):  # configs[0], batch.configs[b]
        return _holds_config(node.value, held)
    if isinstance(node, ast.Call):  # with_overrides(base, ...)
        name = getattr(node.func, "id", getattr(node.func, "attr", ""))
        return name in CONFIG_MAKERS
    return False


def _bound_configs(target, value, held: set[str]) -> set[str]:
    """The names ``target`` binds to configurations when it takes each element of ``value`` (a loop) ."""
    if isinstance(value, ast.Call) and getattr(value.func, "id", "") in ("zip", "enumerate"):
        if not isinstance(target, ast.Tuple):
            return set()
        if value.func.id == "enumerate":
            return _bound_configs(target.elts[1], value.args[0], held) if value.args else set()
        pairs = zip(target.elts, value.args, strict=False)
        return set().union(*(_bound_configs(t, v, held) for t, v in pairs))
    if isinstance(target, ast.Name) and _holds_config(value, held):
        return {target.id}
    return set()


def _config_reads(path: Path) -> list[str]:
    """Attribute reads of a configuration in ``path`` (``config.cell_pressure_kpa``, ``c.name`` in a loop
    over ``batch.configs``, ``base.float64`` of ``base = with_overrides(...)`` or ``base: TriaxialConfig``,
    ``getattr(config, name)``). Building, validating or passing a configuration on is not a read."""
    tree = ast.parse(path.read_text(), filename=str(path))
    held = set(CONFIG_NAMES)
    for node in ast.walk(tree):
        if isinstance(node, ast.arg) and node.annotation is not None:
            if "TriaxialConfig" in ast.unparse(node.annotation):
                held.add(node.arg)
    grown = True
    while grown:  # names bound to configurations by assignments and loops, until none is new
        before = len(held)
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign):
                for target in node.targets:
                    if isinstance(target, ast.Name) and _holds_config(node.value, held):
                        held.add(target.id)
            elif isinstance(node, (ast.For, ast.comprehension)):
                held |= _bound_configs(node.target, node.iter, held)
        grown = len(held) > before
    reads = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and node.attr in CONFIG_ATTRIBUTES
            and _holds_config(node.value, held)
        ):
            reads.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
        elif isinstance(node, ast.Call) and getattr(node.func, "id", "") == "getattr" and node.args:
            if _holds_config(node.args[0], held):
                reads.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    return reads


def test_a_configuration_is_read_only_where_it_becomes_a_test():
    """Followed from :func:`membrax.run.run_test`, the configuration is read only in ``config``, ``run`` and
    ``assemble``; the executor, the runner, the sweep, the reproduction and the commands take plain values
    (a read: an attribute of a :class:`~membrax.config.TriaxialConfig`, its fields or properties, or
    ``getattr`` on one; loading, building, validating and handing one on to ``assemble`` are not reads)."""
    readers = {name: _config_reads(path) for name, path in FILES.items()}
    readers = {name: reads for name, reads in readers.items() if reads}
    outside = {name: reads for name, reads in readers.items() if name not in CONFIG_READERS}
    assert not outside, outside
    assert {"assemble", "run"} <= set(readers)


def test_the_configuration_reader_sees_every_kind_of_read(tmp_path):
    """The reader itself on a file with each form, and with the values it must not take for reads."""
    sample = tmp_path / "reads.py"
    sample.write_text(
        "import numpy as np\n"
        "def f(config, batch, tests, mine: TriaxialConfig, args):\n"
        "    a = config.cell_pressure_kpa\n"
        "    b = batch.configs[0].float64\n"
        "    for c in batch.configs:\n"
        "        c.inertial_number\n"
        "    for k, (t, d) in enumerate(zip(tests, batch.configs)):\n"
        "        t.cell_pressure, t.name, d.name\n"
        "    base = with_overrides(config, name='x')\n"
        "    first = batch.configs[0]\n"
        "    base.layers, first.chunk_steps, mine.dt_safety, getattr(config, 'layers')\n"
        "    [e.packing for e in batch.configs]\n"
        "    np.float64, args.packing, batch.settings[0].name, build_test(config), structure_key(mine)\n"
    )
    reads = [read.split(" ", 1)[1] for read in _config_reads(sample)]
    assert sorted(reads) == sorted(
        [
            "config.cell_pressure_kpa",
            "batch.configs[0].float64",
            "c.inertial_number",
            "d.name",
            "base.layers",
            "first.chunk_steps",
            "mine.dt_safety",
            "getattr(config, 'layers')",
            "e.packing",
        ]
    )
