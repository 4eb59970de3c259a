"""The DEM's compiled CPU kernel on the JAX side: flat inputs, the call and the backward rule.

Contract. Private to :mod:`membrax.spheres`. For the sphere–sphere contacts of a neighbour list summed per
sphere (``dem_pairs.cc`` in :mod:`membrax.native`), the functions that turn the law's arguments
``(spheres, idx, spring, law, dt)`` into the kernel's flat operands (:func:`pair_totals_inputs`,
:func:`pair_kernel_operands`), call the forward kernel (:func:`pair_totals_kernel`) and run the backward
kernel (:func:`pair_totals_backward`). The law itself, its JAX definition (the reference) and its
:func:`membrax.native.with_reference` binding stay in :mod:`membrax.spheres.integrate`, which imports these.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from membrax import native
from membrax.spheres.contact import ContactParams, PairSpheres, slot_law, slot_spheres


def pair_totals_inputs(spheres: PairSpheres, idx, spring, law: ContactParams, dt):
    """The kernels' differentiable inputs, flat, in their order (all but ``idx``): k_n, k_t, μ per slot."""
    dtype = spheres.position.dtype
    slots = spring.shape[0]
    _, gi, _ = slot_spheres(spheres, idx)

    def per_slot(value):
        return jnp.broadcast_to(jnp.asarray(value, dtype), (slots,))

    rows = (spheres.position, spheres.position_compensation, spheres.velocity, spheres.angular_velocity)
    return (
        *native.in_dtype(dtype, *rows, spheres.radius, spring),
        *(per_slot(value) for value in slot_law(law, spheres.member[gi])),
        native.stack_scalars(dtype, dt),
    )


def pair_kernel_operands(args):
    """The flat inputs, and the operands both kernels begin with (the int32 ``idx`` before the springs)."""
    flat = pair_totals_inputs(*args)
    return flat, (*flat[:5], args[1].astype(jnp.int32), *flat[5:])  # idx between the radii and the springs


def pair_totals_kernel(*args):
    """:func:`membrax.spheres.integrate._pair_totals_reference` by the compiled kernel (``dem_pairs.cc``)."""
    flat, operands = pair_kernel_operands(args)
    radius, spring = flat[4], flat[5]
    dtype = radius.dtype
    n, slots = radius.shape[0], spring.shape[0]
    return native.call(
        "dem_pairs",
        dtype,
        (
            jax.ShapeDtypeStruct((n, 6), dtype),
            jax.ShapeDtypeStruct((slots, 3), dtype),
            jax.ShapeDtypeStruct((slots, 3), dtype),
        ),
        *operands,
    )


def pair_totals_backward(args, perturbed, cotangents):
    """The compiled reverse-mode rule (``dem_pairs_backward``: the law of each touching slot backwards)."""
    del perturbed  # it covers every differentiable argument
    flat, operands = pair_kernel_operands(args)
    dtype = flat[4].dtype
    position, velocity, angular, radius_bar, spring_bar, kn_bar, kt_bar, mu_bar, dt_bar = native.call(
        "dem_pairs_backward",
        dtype,
        tuple(jax.ShapeDtypeStruct(array.shape, dtype) for array in flat[:1] + flat[2:]),
        *operands,
        *(jnp.asarray(c, dtype) for c in cotangents),
    )
    # b = (x_j − x_i) + (c_j − c_i): the position and its compensation share a cotangent.
    flat_cotangents = (position, position, velocity, angular, radius_bar, spring_bar)
    flat_cotangents += (kn_bar, kt_bar, mu_bar, dt_bar)
    return native.pack_cotangents(pair_totals_inputs, args, flat_cotangents)
