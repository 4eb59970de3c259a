"""The rigid cylindrical mould a random packing is compacted in: its energy, radial load and mean stress.

Contract. Pure ``jax.numpy`` on one packing's (N, 3) centres in SI units (m, N, Pa, J), jit-, vmap- and
grad-able. The mould wall is a true cylinder on the z axis: a frictionless sphere of radius r at distance ρ
from the axis overlaps it by δ = ρ + r − R_m, energy ½ k_w max(δ, 0)² (k_w the contact law's wall
stiffness), force its gradient (:func:`mould_energy`); its platens are the DEM's walls (bottom and top).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from membrax.spheres.contact import normal_energy
from membrax.spheres.walls import BOTTOM, TOP

__all__ = ["mould_energy", "mould_mean_stress", "mould_radial_load"]


def mould_energy(position, radius, mould_radius, stiffness):
    """Σ_i ½ k_w max(ρ_i + r_i − R_m, 0)², J: the spheres' overlap with a smooth cylinder on the z axis.

    Args:
      position: (N, 3) centres, m.
      radius: (N,) radii, m.
      mould_radius: R_m, m.
      stiffness: k_w, N/m.
    """
    rho = jnp.sqrt(position[:, 0] ** 2 + position[:, 1] ** 2 + jnp.finfo(position.dtype).tiny)
    return jnp.sum(normal_energy(rho + radius - mould_radius, stiffness))


def mould_radial_load(mould_force, position):
    """The mould's radial load, N: the spheres push it outward by −Σ F_i·ρ̂_i (F_i its force on sphere i)."""
    rho = jnp.sqrt(jnp.sum(position[:, :2] ** 2, axis=1)) + jnp.finfo(position.dtype).tiny
    return -jnp.sum((mould_force[:, 0] * position[:, 0] + mould_force[:, 1] * position[:, 1]) / rho)


def mould_mean_stress(wall_force, radial_load, mould_radius, mould_height):
    """σ = (σ_a + 2σ_r)/3, Pa, of the mould and its platens.

    σ_a is the platens' mean normal force (``wall_force``: one member's (W,) wall forces) over the mould's
    area, σ_r the mould's radial load over its lateral area.
    """
    axial = 0.5 * (wall_force[BOTTOM] + wall_force[TOP]) / (math.pi * mould_radius**2)
    return (axial + 2.0 * radial_load / (2.0 * math.pi * mould_radius * mould_height)) / 3.0
