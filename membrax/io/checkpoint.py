"""Checkpoints: any JAX pytree and host data in one ``.npz``, nothing pickled, restored bit-exact.

Checkpoints. :func:`save_checkpoint` stores any JAX pytree (jax-md dataclasses, NamedTuples, dicts,
arrays, Python scalars, typed PRNG keys) and an optional ``host`` dict in one ``.npz``: the leaves of
``jax.tree_util.tree_flatten(state)`` as ``leaf_00000``, ``leaf_00001``, …; numpy/JAX array values of
``host`` as ``host__{key}``; the other ``host`` values as one JSON string ``__host__``; and a JSON string
``__meta__`` with the format name, version, and every leaf's key path, shape and dtype. Nothing is
pickled. :func:`load_checkpoint` rebuilds the state with the tree structure of a template ``like`` (a
state of the same configuration, or ``jax.eval_shape`` of one), checks the leaf count, shapes and
dtypes, and returns the leaves bit-exact: JAX array leaves of the template as JAX arrays of its dtype,
numpy leaves as numpy arrays, Python scalars as Python scalars. JSON turns tuples into lists.

Errors: :mod:`membrax.io`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from membrax.io.files import (
    atomic_write_file,
    ensure_folder,
    existing_file,
)

__all__ = ["save_checkpoint", "load_checkpoint", "read_checkpoint_host"]

#: ``format`` entry of a checkpoint's ``__meta__``, and the version written.
CHECKPOINT_FORMAT = "membrax-checkpoint"
CHECKPOINT_VERSION = 1

# ----------------------------------------------------------------------------------------------------------
# Checkpoints
# ----------------------------------------------------------------------------------------------------------


def _is_key_array(leaf) -> bool:
    dtype = getattr(leaf, "dtype", None)
    return dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)


def _leaf_signature(leaf) -> tuple[tuple[int, ...], str]:
    """(shape, dtype name) of a leaf, the same for a saved leaf and a template leaf."""
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(int(n) for n in leaf.shape), str(leaf.dtype)
    array = np.asarray(leaf)
    return tuple(array.shape), str(array.dtype)


def _leaf_to_numpy(label: str, leaf) -> tuple[np.ndarray, dict]:
    shape, dtype = _leaf_signature(leaf)
    info: dict = {"path": label, "shape": list(shape), "dtype": dtype}
    if _is_key_array(leaf):
        info["key_impl"] = str(jax.random.key_impl(leaf))
        return np.asarray(jax.random.key_data(leaf)), info
    array = np.asarray(leaf)
    if array.dtype.kind in "OV" and array.dtype.type.__module__ == "numpy":
        raise ValueError(
            f"state leaf {label} is a {type(leaf).__name__}, which is not an array or number; make it a "
            "static field of its dataclass or pass it in host."
        )
    if array.dtype.type.__module__ != "numpy":  # extension dtypes (bfloat16, ...): stored as raw bytes
        info["raw_bytes"] = True
        return np.frombuffer(np.ascontiguousarray(array).tobytes(), np.uint8), info
    return array, info


def _split_host(host) -> tuple[str, dict[str, np.ndarray], dict]:
    if host is None:
        return "null", {}, {"none": True, "order": [], "arrays": {}}
    if not isinstance(host, Mapping):
        raise ValueError(f"host must be a dict of host-side data (or None), got {type(host).__name__}.")
    plain, arrays, kinds = {}, {}, {}
    for key, value in host.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"host key {key!r} is not a non-empty string; use string keys.")
        if isinstance(value, np.ndarray | np.generic | jax.Array):
            array = np.asarray(value)
            if array.dtype.kind == "O":
                raise ValueError(f"host[{key!r}] is an object array; give numbers or JSON-able values.")
            arrays[f"host__{key}"] = array
            kinds[key] = "scalar" if isinstance(value, np.generic) else "array"
            continue
        try:
            json.dumps(value)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"host[{key!r}] of type {type(value).__name__} cannot be stored ({error}); give numpy "
                "arrays or JSON-able values (str, numbers, bools, None, lists and dicts of those)."
            ) from error
        plain[key] = value
    return json.dumps(plain), arrays, {"none": False, "order": list(host), "arrays": kinds}


def save_checkpoint(path, state, host=None) -> Path:
    """Save a JAX pytree ``state`` and a ``host`` dict to one ``.npz``, atomically (module docstring).

    Args:
      path: the checkpoint file (conventionally ``.npz``); its folder is created if missing; an existing
        file is replaced only once the new one is completely written.
      state: any pytree of arrays and numbers (jax-md dataclasses, NamedTuples, dicts, PRNG keys).
      host: optional dict of host-side data: numpy/JAX arrays (stored as ``host__{key}``) and JSON-able
        values (step counters, settings).

    Returns:
      ``path`` as a Path.

    Raises:
      ValueError: if ``path`` is a directory or its folder cannot be made, a leaf is not an array or
        number, or a host value is neither an array nor JSON-able.
    """
    path = Path(os.fspath(path))
    if path.is_dir():
        raise ValueError(f"checkpoint path '{path}' is a directory; give a file name such as 'state.npz'.")
    ensure_folder(path.parent, "the folder of the checkpoint path")
    flat, treedef = jax.tree_util.tree_flatten_with_path(state)
    arrays: dict[str, np.ndarray] = {}
    leaves = []
    for index, (key_path, leaf) in enumerate(flat):
        array, info = _leaf_to_numpy(jax.tree_util.keystr(key_path), leaf)
        arrays[f"leaf_{index:05d}"] = array
        leaves.append(info)
    host_json, host_arrays, host_meta = _split_host(host)
    arrays.update(host_arrays)
    meta = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "num_leaves": len(leaves),
        "treedef": str(treedef),
        "leaves": leaves,
        "host": host_meta,
    }
    arrays["__meta__"] = np.array(json.dumps(meta))
    arrays["__host__"] = np.array(host_json)
    atomic_write_file(path, lambda handle: np.savez(handle, **arrays))
    return path


def _read_checkpoint_entries(path: Path) -> dict[str, np.ndarray]:
    not_checkpoint = "pass a checkpoint written by membrax.io.save_checkpoint"
    try:
        loaded = np.load(path, allow_pickle=False)
    except Exception as error:
        raise ValueError(f"'{path}' is not a checkpoint .npz ({error}); {not_checkpoint}.") from error
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ValueError(f"'{path}' holds a single array, not a checkpoint .npz; {not_checkpoint}.")
    try:
        with loaded:
            if "__meta__" not in loaded.files:
                raise ValueError(
                    f"'{path}' is an .npz but not a membrax checkpoint (no __meta__ entry); {not_checkpoint}."
                )
            return {name: loaded[name] for name in loaded.files}
    except ValueError:
        raise
    except Exception as error:
        raise ValueError(
            f"checkpoint '{path}' is damaged ({type(error).__name__}: {error}); delete it and resume from an "
            "earlier checkpoint, or start a fresh run."
        ) from error


def _mismatch(path: Path, label: str, saved: str, template: str) -> ValueError:
    return ValueError(
        f"checkpoint '{path}' does not fit the template state at leaf {label}: {saved}, {template}. "
        "The checkpoint belongs to a different configuration (another particle count, mesh, batch size, "
        "neighbour capacity or precision); resume with the configuration that wrote it, or start a fresh run."
    )


def _restore_leaf(array: np.ndarray, info: dict, template):
    shape, dtype = tuple(info["shape"]), info["dtype"]
    if "key_impl" in info:
        return jax.random.wrap_key_data(jnp.asarray(array), impl=info["key_impl"])
    if info.get("raw_bytes"):
        array = np.frombuffer(array.tobytes(), jnp.dtype(dtype)).reshape(shape).copy()
    if isinstance(template, bool | int | float | complex):
        return type(template)(array.item())
    if isinstance(template, np.ndarray):
        return array
    if isinstance(template, np.generic):
        return array[()]
    return jnp.asarray(array, dtype=template.dtype)


def read_checkpoint_host(path) -> dict:
    """The JSON part of a checkpoint's host data, without its state (e.g. to size a template first)."""
    path = Path(os.fspath(path))
    entries = _read_checkpoint_entries(path)
    try:
        return json.loads(str(entries["__host__"][()]))
    except (KeyError, json.JSONDecodeError) as error:
        message = f"checkpoint '{path}' is damaged or not a membrax checkpoint ({error!r})."
        raise ValueError(message) from error


def load_checkpoint(path, like):
    """Load a checkpoint written by :func:`save_checkpoint` into the tree structure of ``like``.

    Args:
      path: the checkpoint file.
      like: a template state with the same structure, shapes and dtypes (e.g. the freshly initialised
        state of the same configuration, or ``jax.eval_shape`` of it).

    Returns:
      ``(state, host)``: the state, bit-exact (JAX leaves of ``like`` as JAX arrays of its dtypes, numpy
      leaves as numpy arrays, Python scalars as Python scalars), and the host dict (None if none was
      saved), its arrays as numpy arrays.

    Raises:
      FileNotFoundError: if ``path`` does not exist.
      ValueError: if ``path`` is not a checkpoint or is damaged, or its leaf count, a shape or a dtype
        differs from ``like`` (naming the first mismatching leaf by its key path).
    """
    path = existing_file(
        path, "checkpoint", "check the path, or start a fresh run without resuming", "the checkpoint file"
    )
    entries = _read_checkpoint_entries(path)
    damaged = f"checkpoint '{path}' is damaged"
    fix = "delete it and resume from an earlier checkpoint, or start a fresh run"
    try:
        meta = json.loads(str(entries["__meta__"][()]))
        host_plain = json.loads(str(entries["__host__"][()]))
        leaves_info = meta["leaves"]
        host_meta = meta["host"]
        if meta.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"format {meta.get('format')!r}")
        saved = [entries[f"leaf_{index:05d}"] for index in range(meta["num_leaves"])]
        host_arrays = {key: entries[f"host__{key}"] for key in host_meta["arrays"]}
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as error:
        raise ValueError(f"{damaged} or not a membrax checkpoint ({error!r}); {fix}.") from error
    if meta.get("version", 0) > CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint '{path}' has format version {meta['version']}, newer than this membrax "
            f"({CHECKPOINT_VERSION}); load it with the membrax version that wrote it."
        )
    like_flat, treedef = jax.tree_util.tree_flatten_with_path(like)
    counts = f"({len(saved)} leaves)", f"({len(like_flat)} leaves)"
    for index in range(max(len(saved), len(like_flat))):
        if index >= len(like_flat):
            label = leaves_info[index]["path"]
            raise _mismatch(path, label, f"in the checkpoint {counts[0]}", f"not in the template {counts[1]}")
        label = jax.tree_util.keystr(like_flat[index][0])
        if index >= len(saved):
            raise _mismatch(path, label, f"not in the checkpoint {counts[0]}", f"in the template {counts[1]}")
        like_shape, like_dtype = _leaf_signature(like_flat[index][1])
        info = leaves_info[index]
        if tuple(info["shape"]) != like_shape or info["dtype"] != like_dtype:
            raise _mismatch(
                path,
                label,
                f"shape {tuple(info['shape'])} dtype {info['dtype']} in the checkpoint "
                f"(saved as {info['path']})",
                f"shape {like_shape} dtype {like_dtype} in the template",
            )
    leaves = [
        _restore_leaf(array, info, template)
        for array, info, (_, template) in zip(saved, leaves_info, like_flat, strict=True)
    ]
    state = jax.tree_util.tree_unflatten(treedef, leaves)
    if host_meta.get("none"):
        return state, None
    host = {}
    for key in host_meta["order"]:
        if key in host_arrays:
            host[key] = host_arrays[key][()] if host_meta["arrays"][key] == "scalar" else host_arrays[key]
        else:
            host[key] = host_plain[key]
    return state, host
