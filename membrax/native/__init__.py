"""Compiled CPU kernels for the hottest loops, built on first use, with the JAX code as reference.

Contract. :func:`available` says whether the kernels in ``membrax/native/*.cc`` are compiled and
registered with XLA as FFI targets (``jax.ffi``) for the CPU; when it is false, every caller uses its
pure-JAX path, which computes the same numbers to round-off. The kernels are built once per machine
with a C++17 compiler (``$CXX``, else ``g++``) against XLA's FFI headers, into a cache folder keyed by
the sources' hash and the host CPU (``$MEMBRAX_CACHE_DIR``, else ``~/.cache/membrax``), and loaded with
``ctypes``. ``MEMBRAX_NATIVE=0`` turns them off. A failed build warns once and falls back to JAX.

Kernels: the membrane's nodal forces (:func:`membrax.membrane.energies.nodal_forces`), its node update
(:func:`membrax.membrane.node_update.advance_nodes`), the node–sphere law
(:func:`membrax.membrane.contact.node_sphere_forces`), the face contact law
(:func:`membrax.membrane.face_contact.face_contact_forces`) and the DEM's sphere–sphere contacts summed per
sphere (:func:`membrax.spheres.integrate.compute_forces`, with the law of
:func:`membrax.spheres.contact.pair_contact`). Each caller wraps its kernel with :func:`with_reference`.

Why. XLA-CPU has no multi-output loop fusion and turns each per-element formula into several passes
over memory (see :mod:`membrax.fusion`); a membrane force is a short formula over 34,000 triangles, and
one loop that computes it once per element and adds it to its nodes does in one pass what XLA does in a
dozen. The callers keep their JAX formulas as the definition: they use them on other backends
(``lax.platform_dependent``), and the tests check kernel against JAX.

Derivatives. Each kernel is wrapped in ``jax.custom_vjp`` (:func:`with_reference`). Its backward pass on the
CPU is a second compiled kernel (``*_backward``): the membrane forces are −∇Φ, whose Jacobian is symmetric,
so their backward kernel evaluates the directional derivative J ū on dual numbers (``dual.h``); the face
contact law evaluates each touching slot's ū·(outputs) on dual numbers once per input of the slot (a few
dozen, for a few hundred touching slots); the other contact laws and the node update are run backwards by
hand. XLA's own derivatives of the JAX formulas spread over hundreds of small fusions per step and made
reverse mode through a rollout 50–60× the forward pass at paper size (``benchmarks/bench_gradients.py``).
The JAX formulas' derivatives remain the definition: the tests hold each backward kernel to ``jax.vjp`` of
the JAX code to round-off, and that derivative is used on other backends and for arguments a backward kernel
does not cover (the membrane mesh's rest geometry). Where several kernels read the same array, their
backward kernels take an addend, the cotangent so far, which ``input_output_aliases`` (:func:`call`) lets
them update in place (:func:`membrax.membrane.node_update.node_step`). XLA runs the reverse pass's kernels
one after another, so the membrane, node–sphere, face contact and pair backward kernels split their element
loops in two fixed halves, the second offered to XLA's intra-op thread pool (``parallel.h``); each half sums
its own elements in order, so the result does not depend on which thread ran it.

Threads. The forward kernels of the membrane forces, the node–sphere law and the sphere pairs are
asynchronous FFI handlers: each checks its arguments, runs its loop as a task on XLA's intra-op thread
pool (from 8,192 elements on; smaller loops run in the caller) and returns a future, so XLA goes on with
independent work meanwhile and the membrane's two kernels of a step run side by side (``parallel.h``,
``on_pool``). The sphere pairs' and the face contact law's forward kernels run their loops as two such
tasks, fixed halves of the slots (of each kind of feature), and add the spheres' sums up in slot order
after both (``halves_on_pool``): XLA launches the pairs after the node update, so both halves then have a
thread each.
Their arithmetic is the synchronous one's, bit for bit. A trace (``jax.profiler``) then shows only their
launch under the kernel's name; the loop runs in an unnamed pool task. With ``MEMBRAX_NATIVE_THREADS=1``
every kernel runs its loops in its caller, the same halves in the same order: the serial path the tests
hold the threaded one to, bit for bit.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp

__all__ = [
    "Absent",
    "available",
    "build",
    "cache_dir",
    "call",
    "compiler_options",
    "enabled_for",
    "in_dtype",
    "pack_cotangents",
    "reference_vjp",
    "runs_kernels",
    "stack_scalars",
    "with_reference",
    "zeros_for_absent",
]

_SOURCES = ("membrane_forces.cc", "membrane_nodes.cc", "node_sphere.cc", "face_contact.cc", "dem_pairs.cc")
_HEADERS = ("contact_law.h", "dual.h", "ffi_bind.h", "parallel.h")
# Kernel → exported handler symbol, less its F32/F64 suffix; XLA's target is membrax_<kernel>_f32/_f64.
_KERNELS = {
    "membrane_forces": "MembraxMembraneForces",  # membrane.nodal_forces
    "membrane_forces_backward": "MembraxMembraneForcesBackward",  # its reverse-mode rule
    "membrane_nodes": "MembraxMembraneNodes",  # node_update.advance_nodes
    "membrane_nodes_backward": "MembraxMembraneNodesBackward",
    "node_sphere_forces": "MembraxNodeSphereForces",  # membrane_contact.node_sphere_forces
    "node_sphere_backward": "MembraxNodeSphereBackward",
    "face_contact_forces": "MembraxFaceContactForces",  # face_contact.face_contact_forces
    "face_contact_backward": "MembraxFaceContactBackward",
    "dem_pairs": "MembraxDemPairs",  # integrate.compute_forces (pairs)
    "dem_pairs_backward": "MembraxDemPairsBackward",
}
_FLAGS = ("-O3", "-march=native", "-fopenmp-simd", "-fno-math-errno", "-std=c++17", "-shared", "-fPIC")


def cache_dir() -> Path:
    """The folder of the compiled library: ``$MEMBRAX_CACHE_DIR`` or ``~/.cache/membrax``."""
    return Path(os.environ.get("MEMBRAX_CACHE_DIR") or Path.home() / ".cache" / "membrax")


def _source_dir() -> Path:
    return Path(__file__).parent


def _cpu_signature() -> str:
    # -march=native: a library built on one CPU may not run on another sharing the cache folder.
    flags = ""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            flags = next((line for line in cpuinfo if line.startswith("flags")), "")
    except OSError:
        pass
    return f"{platform.machine()} {flags}"


def _library_path() -> Path:
    digest = hashlib.sha256()
    for name in _SOURCES + _HEADERS:
        digest.update((_source_dir() / name).read_bytes())
    digest.update(" ".join(_FLAGS).encode())
    digest.update(jax.ffi.include_dir().encode())
    digest.update(_cpu_signature().encode())
    return cache_dir() / f"membrax_native_{digest.hexdigest()[:16]}.so"


def build() -> Path:
    """Compile the kernels if the cache lacks them; returns the library's path.

    Raises:
      RuntimeError: no C++ compiler, or the compilation failed (its messages are included).
    """
    target = _library_path()
    if target.exists():
        return target
    compiler = os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        raise RuntimeError("no C++ compiler found (install g++ or set CXX)")
    target.parent.mkdir(parents=True, exist_ok=True)
    # Built under a temporary name and renamed, so that concurrent processes never load half a file.
    with tempfile.NamedTemporaryFile(dir=target.parent, suffix=".so", delete=False) as partial:
        partial_path = Path(partial.name)
    command = [
        compiler,
        *_FLAGS,
        f"-I{jax.ffi.include_dir()}",
        *(str(_source_dir() / name) for name in _SOURCES),
        "-o",
        str(partial_path),
    ]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        partial_path.unlink(missing_ok=True)
        errors = [line for line in result.stderr.splitlines() if "error" in line][:10]
        raise RuntimeError(f"compiling the membrax kernels failed: {' '.join(command)}: " + "; ".join(errors))
    partial_path.replace(target)
    return target


@functools.cache
def available() -> bool:
    """Whether the compiled kernels are registered for the CPU (built on the first call).

    False when ``MEMBRAX_NATIVE=0``, or when the build failed (with one warning saying why).
    """
    if os.environ.get("MEMBRAX_NATIVE", "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    try:
        library = ctypes.cdll.LoadLibrary(str(build()))
        for name, symbol in _KERNELS.items():
            for suffix in ("f32", "f64"):
                handler = jax.ffi.pycapsule(getattr(library, symbol + suffix.upper()))
                jax.ffi.register_ffi_target(f"membrax_{name}_{suffix}", handler, platform="cpu")
    except (OSError, RuntimeError, AttributeError) as error:
        if jax.default_backend() != "cpu":  # the kernels would serve only CPU side work there
            return False
        warnings.warn(
            f"membrax: compiled CPU kernels unavailable, using the JAX code ({error}). "
            "Set MEMBRAX_NATIVE=0 to silence this.",
            stacklevel=2,
        )
        return False
    return True


def enabled_for(dtype) -> bool:
    """Whether arrays of ``dtype`` go through the kernels: float32 or float64, and :func:`available`."""
    return jnp.dtype(dtype) in (jnp.float32, jnp.float64) and available()


def runs_kernels(dtype) -> bool:
    """Whether a step traced now for arrays of ``dtype`` runs the kernels: :func:`enabled_for` on the CPU.

    Elsewhere (another default backend, ``MEMBRAX_NATIVE=0``, another dtype) it runs the JAX code, and
    reverse mode is XLA's derivative of that code.
    """
    return enabled_for(dtype) and jax.default_backend() == "cpu"


def compiler_options() -> dict[str, str] | None:
    """XLA's options for compiling a long run's chunks (``jax.jit(..., compiler_options=...)``), or None.

    On the CPU backend, XLA's memory-optimised thunk scheduler in place of its default: the same
    operations and arithmetic (the same bits, ``tests/test_native.py``) in another order, in which the
    asynchronous kernels of a step overlap more. The paper-size coupled step ran at 1,320 steps/s against
    1,188 with the default (float32, 2 CPU cores; 300 steps in a jitted loop as
    ``benchmarks/bench_membrane.py`` times them, runs alternated). None elsewhere.
    """
    if jax.default_backend() != "cpu":
        return None
    return {"xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"}


def call(name: str, dtype, results, *args, input_output_aliases=None, **attributes):
    """Call the kernel ``name`` (``membrax_<name>_f32`` or ``_f64`` after ``dtype``) on ``args``.

    ``results`` is one ``jax.ShapeDtypeStruct`` or a tuple of them; ``attributes`` are the handler's static
    attributes (numpy scalars). ``input_output_aliases`` ({argument index: result index}) gives a result
    its argument's buffer, for a kernel that updates that argument in place (XLA copies the argument first
    if anything else still reads it). Under ``vmap`` the kernel runs once per batch member.
    """
    if not available():  # registers the targets on first use
        raise RuntimeError("the membrax CPU kernels are not available (see membrax.native.available)")
    suffix = "f32" if jnp.dtype(dtype) == jnp.float32 else "f64"
    function = jax.ffi.ffi_call(
        f"membrax_{name}_{suffix}",
        results,
        vmap_method="sequential",
        input_output_aliases=input_output_aliases,
    )
    return function(*args, **attributes)


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True)
class _Perturbed:
    """Which argument leaves are differentiated: static, so it rides in the residuals' tree structure."""

    flags: tuple


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True)
class Absent:
    """An argument a backward kernel does not read, left out of the residuals: only its shape and dtype."""

    shape: tuple
    dtype: object

    @classmethod
    def like(cls, array):
        """The shape and dtype of ``array``."""
        return cls(tuple(array.shape), jnp.dtype(array.dtype))


def zeros_for_absent(tree):
    """``tree`` with every :class:`Absent` replaced by zeros of its shape and dtype.

    A backward rule whose residuals left arrays out gets them back as zeros: its kernels do not read them,
    and :func:`pack_cotangents` needs only their shapes and dtypes.
    """

    def restore(leaf):
        return jnp.zeros(leaf.shape, leaf.dtype) if isinstance(leaf, Absent) else leaf

    return jax.tree.map(restore, tree, is_leaf=lambda leaf: isinstance(leaf, Absent))


def with_reference(kernel, reference, backward=None, keep=None):
    """``kernel`` on the CPU and ``reference`` on other backends, with the derivatives of ``reference``.

    Both take the same positional arguments and return the same arrays; ``reference`` is the JAX
    definition the kernel computes. Reverse mode (``jax.grad``, ``jax.vjp``, and reverse over reverse
    through the reference) is defined; forward mode is not (``jax.custom_vjp``).

    ``backward(args, perturbed, cotangents)``, when given, is the compiled reverse-mode rule on the CPU:
    ``perturbed`` is a pytree of bools like ``args`` (which leaves are being differentiated) and
    ``cotangents`` the outputs' (dense arrays); it returns the arguments' cotangents, or None where it
    does not cover a perturbed argument, and then the reference's derivative is used. The tests hold it
    to the reference's ``jax.vjp``.

    ``keep(args, outputs, perturbed)``, when given with ``backward``, says what reverse mode keeps on the
    CPU: the arguments as ``backward`` will receive them (any pytree), those it does not read replaced by
    :class:`Absent` or by an output that carries what it needs. Through a checkpointed rollout every kept
    array is stored once per step, so this is memory traffic saved. ``backward`` must then cover every
    argument (never None); where it needs the reference's rule for some ``perturbed``, ``keep`` keeps all
    the arguments for it and ``backward`` calls :func:`reference_vjp` itself.
    """

    @jax.custom_vjp
    def compiled(*args):
        return jax.lax.platform_dependent(*args, cpu=kernel, default=reference)

    def reference_backward(args, cotangents):
        return reference_vjp(reference, args, cotangents)

    if backward is None:

        def forward(*args):
            return compiled(*args), args

        compiled.defvjp(forward, reference_backward)
        return compiled

    def is_primal(leaf):
        return isinstance(leaf, jax.custom_derivatives.CustomVJPPrimal)

    def forward_marked(*primals):
        args = jax.tree.map(lambda leaf: leaf.value, primals, is_leaf=is_primal)
        perturbed = jax.tree.map(lambda leaf: leaf.perturbed, primals, is_leaf=is_primal)
        flat, structure = jax.tree.flatten(perturbed)
        outputs = compiled(*args)
        if keep is not None and jax.default_backend() == "cpu":
            args = keep(args, outputs, perturbed)
        return outputs, (args, _Perturbed((tuple(flat), structure)))

    def backward_marked(residuals, cotangents):
        args, marks = residuals
        flat, structure = marks.flags
        perturbed = jax.tree.unflatten(structure, flat)
        symbolic = jax.custom_derivatives.SymbolicZero
        cotangents = jax.tree.map(
            lambda c: jnp.zeros(c.shape, c.dtype) if isinstance(c, symbolic) else c,
            cotangents,
            is_leaf=lambda c: isinstance(c, symbolic),
        )
        result = None
        if jax.default_backend() == "cpu":
            result = backward(args, perturbed, cotangents)
            if result is None and keep is not None:
                raise RuntimeError("a backward kernel with slimmed residuals must cover every argument")
        return reference_backward(args, cotangents) if result is None else tuple(result)

    compiled.defvjp(forward_marked, backward_marked, symbolic_zeros=True)
    return compiled


def in_dtype(dtype, *arrays):
    """``arrays`` in ``dtype``, as a tuple: a kernel's floating inputs all have the dtype it is built for."""
    return tuple(jnp.asarray(array).astype(dtype) for array in arrays)


def stack_scalars(dtype, *values):
    """Scalar parameters as one (k,) array of ``dtype``, in the order a kernel reads them."""
    return jnp.stack([jnp.asarray(value, dtype) for value in values])


def reference_vjp(reference, args, cotangents):
    """The cotangents of ``args`` from those of ``reference(*args)``'s outputs, by ``jax.vjp``."""
    _, pullback = jax.vjp(reference, *args)
    return pullback(cotangents)


def pack_cotangents(pack, args, flat_cotangents):
    """The cotangents of ``args`` from those of ``pack(*args)``, a kernel's flat inputs (by ``jax.vjp``).

    ``pack`` maps the caller's arguments to the arrays a kernel takes (stacked scalars, casts); a backward
    kernel returns cotangents of those arrays, and this carries them back through the packing.
    """
    packed, pullback = jax.vjp(pack, *args)
    flat_cotangents = tuple(
        jnp.asarray(c, p.dtype).reshape(p.shape) for p, c in zip(packed, flat_cotangents, strict=True)
    )
    return pullback(flat_cotangents)
