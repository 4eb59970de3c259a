"""Folders, stems and atomic writes shared by the writers of :mod:`membrax.io`.

Atomic writes. Every file written here (``.nc``, ``.csv``, ``.vtu`` of a series, ``.pvd``, checkpoint)
goes to a temporary file ``.{name}.*.tmp`` in the destination folder, is flushed and fsynced, and then
moved over the destination with ``os.replace``: a crash mid-write leaves the previous file intact (or
no file), never a half-written one, and the temporary file is removed when the write fails.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from collections.abc import Callable
from pathlib import Path

__all__ = [
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_file",
    "check_stem",
    "ensure_folder",
    "existing_file",
]

# ----------------------------------------------------------------------------------------------------------
# Shared helpers: folders, stems, atomic writes
# ----------------------------------------------------------------------------------------------------------

#: Names of stems and record variables: a letter or _, then letters, digits and _.@+-.
NAME_PATTERN = re.compile(r"^[A-Za-z_][A-Za-z0-9_.@+-]*$")


def ensure_folder(folder, argument: str = "folder") -> Path:
    """``folder`` as a Path, created (with parents) if missing; ValueError if it is not a directory."""
    path = Path(os.fspath(folder))
    if path.exists() and not path.is_dir():
        raise ValueError(
            f"{argument} = '{path}' exists and is not a directory; pass a directory (it is created if "
            "missing) or move that file out of the way."
        )
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(
            f"{argument} = '{path}' cannot be created ({error}); pass a directory path whose parents are "
            "directories you can write to."
        ) from error
    return path


def check_stem(stem) -> str:
    """``stem`` if it is a plain file-name stem, else ValueError saying how to fix it."""
    if not isinstance(stem, str) or not stem or stem.startswith(".") or "/" in stem or os.sep in stem:
        raise ValueError(
            f"stem = {stem!r} is not a plain file-name stem; give a non-empty name without '/' that does not "
            "start with '.', e.g. 'results'."
        )
    return stem


def temporary_path(path: Path, suffix: str = ".tmp") -> Path:
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"


def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every platform can open a directory)."""
    with contextlib.suppress(OSError):
        descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def atomic_write(path: Path, write: Callable[[Path], None], suffix: str = ".tmp") -> None:
    """Write ``path`` by ``write(temporary)`` in the same folder, fsync, then ``os.replace``.

    On any failure (including in ``os.replace``) the temporary file is removed and ``path`` is untouched.
    """
    temporary = temporary_path(path, suffix)
    try:
        write(temporary)
        with open(temporary, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    fsync_folder(path.parent)


def atomic_write_file(path: Path, write_handle: Callable) -> None:
    """:func:`atomic_write` through an open binary handle (created with the process umask)."""

    def write(temporary: Path) -> None:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(descriptor, "wb") as handle:
            write_handle(handle)

    atomic_write(path, write)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (module docstring)."""
    atomic_write_file(path, lambda handle: handle.write(data))


def existing_file(path, what: str, missing_hint: str, inside: str) -> Path:
    """``path`` as a Path, or FileNotFoundError (missing) / ValueError (a directory) naming ``what``."""
    path = Path(os.fspath(path))
    if not path.exists():
        raise FileNotFoundError(f"{what} '{path}' does not exist; {missing_hint}.")
    if path.is_dir():
        raise ValueError(f"{what} path '{path}' is a directory; pass {inside} inside it.")
    return path
