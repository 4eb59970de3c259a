"""Frozen dataclasses that are JAX pytrees: the containers of every state and parameter set of membrax.

Contract. :func:`dataclass` makes a frozen :mod:`dataclasses` class and registers it with
``jax.tree_util.register_dataclass``, so its instances pass through ``jit``, ``vmap``, ``grad`` and
``lax.scan`` like tuples of arrays; ``instance.set(name=value)`` returns a copy with fields replaced (the
jax-md idiom the step functions use). Fields made with :func:`static_field` are not leaves: they are part of
the tree's structure (compile-time constants such as a member count), so changing one recompiles.

This is the few lines of ``jax_md.dataclasses`` that membrax uses, kept here so that only the neighbour
lists (:mod:`membrax.spheres.neighbors`) import jax-md, whose import runs array code.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax

__all__ = ["dataclass", "fields", "is_dataclass", "replace", "static_field"]

fields = dataclasses.fields
is_dataclass = dataclasses.is_dataclass
replace = dataclasses.replace


def _set(self, **changes):
    """A copy with the named fields replaced (``dataclasses.replace``)."""
    return dataclasses.replace(self, **changes)


def dataclass(cls=None, **dataclass_kwargs: Any):
    """Decorate ``cls`` as a frozen dataclass registered as a pytree, with a ``set`` method.

    Args:
      cls: the class (or None, to be used as ``@dataclass(...)``).
      **dataclass_kwargs: further arguments of :func:`dataclasses.dataclass` (``frozen`` is always True).
    """

    def decorate(target):
        registered = jax.tree_util.register_dataclass(
            dataclasses.dataclass(frozen=True, **dataclass_kwargs)(target)
        )
        registered.set = _set
        return registered

    return decorate if cls is None else decorate(cls)


def static_field(**field_kwargs: Any):
    """A field that is part of the tree's structure, not a leaf (``register_dataclass``'s meta field)."""
    metadata = {**field_kwargs.pop("metadata", {}), "static": True}
    return dataclasses.field(metadata=metadata, **field_kwargs)
