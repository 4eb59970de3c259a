"""Spheres in an orthorhombic periodic cell: minimum-image contacts, the cell's stress and stiffness.

Contract. Pure ``jax.numpy`` functions (jit, vmap) of one cell with box lengths L = (Lx, Ly, Lz), m, and
spheres at fractional positions s ∈ [0, 1)³ (x = L ⊙ s), for :mod:`membrax.triaxial.periodic`:

- :func:`minimum_image_branch`: the branch vector of each pair slot to the nearest image,
  d = L ⊙ (Δs − round(Δs)), Δs = s_j − s_i (exact for an orthorhombic cell, where the nearest image along
  each axis is the nearest image in space);
- :func:`periodic_pair_forces`: the Cundall–Strack contacts of :mod:`membrax.spheres.contact` on those
  branches, in JAX (the compiled pair kernel, :mod:`membrax.spheres._kernels`, reads branches from
  positions without images, so the periodic cell runs this path; its cost is in
  :mod:`membrax.triaxial.periodic`);
- :func:`love_weber_stress`, :func:`cell_stiffness`, :func:`coordination_numbers` and
  :func:`unbalanced_force_ratio`: what the cell measures and what its servo reads;
- :func:`random_gas` (host side, numpy): spheres placed at random without overlap in a periodic box, the
  start of a packing.

Velocities are fluctuations u about the box's homogeneous deformation, v = u + ε̇ ⊙ (x − c), ε̇ = L̇/L
per axis (extension positive): the image of j across the boundary moves with the field too, so the
velocity of j's image relative to i is u_j − u_i + ε̇ ⊙ d for any image (the field is linear).
Stresses are compression-positive, Pa, as in :mod:`membrax.spheres.measure`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.spheres import contact
from membrax.spheres.contact import ContactParams
from membrax.spheres.grading import Grading, _mean_bin_volume, sample_diameters
from membrax.validation import check_range
from membrax.vector import safe_norm, select

__all__ = [
    "RATTLER_CONTACTS",
    "RATTLER_PASSES",
    "PeriodicForces",
    "cell_stiffness",
    "coordination_numbers",
    "love_weber_stress",
    "minimum_image_branch",
    "periodic_pair_forces",
    "random_gas",
    "sample_element",
    "unbalanced_force_ratio",
]

#: A frictionless sphere with fewer force-carrying contacts is a rattler: it needs d + 1 = 4 contacts not
#: all in one hemisphere to be in stable equilibrium (Agnolin & Roux 2007, Phys. Rev. E 76, 061302; their
#: z* drops such spheres). With friction two contacts can hold a sphere, so frictional packings use 2
#: (:func:`coordination_numbers`' ``min_contacts``).
RATTLER_CONTACTS = 4
#: Passes of the rattler removal: removing a rattler can leave a neighbour with too few contacts, so it is
#: repeated (a fixed count, unrolled under jit). In the packings of ``tests/test_periodic.py`` (checked over
#: 30 passes, 2026-11-29) the first pass removed 3 of 300 frictionless and 18 of 150 frictional spheres and
#: every later pass none.
RATTLER_PASSES = 8


@pytree.dataclass
class PeriodicForces:
    """The sphere–sphere contacts of a periodic cell at one instant.

    Attributes:
      force: (N, 3) total contact force on each sphere, N.
      torque: (N, 3) total contact torque, N·m.
      pair_spring: (C, 3) updated tangential springs (force on j).
      pair_force: (C, 3) force on j from i, N (zero on padded slots).
      pair_branch: (C, 3) minimum-image branch d = x_j' − x_i, m (zero on padded slots).
      pair_normal_force: (C,) k_n max(δ, 0), N (zero on padded slots).
    """

    force: jnp.ndarray
    torque: jnp.ndarray
    pair_spring: jnp.ndarray
    pair_force: jnp.ndarray
    pair_branch: jnp.ndarray
    pair_normal_force: jnp.ndarray


def minimum_image_branch(fraction_i, fraction_j, length):
    """D = L ⊙ (Δs − round(Δs)), Δs = s_j − s_i: the branch to j's nearest image, (3, ...), m.

    Args:
      fraction_i: (3, ...) fractional position of i (high and low parts already summed, or the differences
        formed by the caller and passed as ``fraction_j`` with ``fraction_i`` zero).
      fraction_j: (3, ...) fractional position of j.
      length: (3,) box lengths L, m.
    """
    step = fraction_j - fraction_i
    return length.reshape((3,) + (1,) * (step.ndim - 1)) * (step - jnp.round(step))


def periodic_pair_forces(
    fraction,
    fraction_compensation,
    velocity,
    angular_velocity,
    radius,
    length,
    strain_rate,
    idx,
    spring,
    law: ContactParams,
    dt,
) -> PeriodicForces:
    """Cundall–Strack contacts of every pair slot with the minimum-image branch (module docstring).

    The law is :func:`membrax.spheres.contact.pair_contact` (Cundall & Strack 1979): F_n = k_n δ n,
    δ = R_i + R_j − |d|, and the tangential spring incremented by −k_s v_t Δt and capped at μ F_n, with
    the relative velocity of j's image u_j − u_i + ε̇ ⊙ d (fluctuations plus the box's affine field).

    Args:
      fraction: (N, 3) fractional positions s (high part).
      fraction_compensation: (N, 3) their low parts (compensated summation).
      velocity: (N, 3) fluctuation velocities u, m/s.
      angular_velocity: (N, 3) rad/s.
      radius: (N,) m.
      length: (3,) box lengths L, m.
      strain_rate: (3,) ε̇ = L̇/L, 1/s.
      idx: (2, C) pair slots (i < j), padded with N.
      spring: (C, 3) carried tangential springs.
      law: the contact law (scalars: one cell; ``vmap`` for several).
      dt: time step, s.
    """
    n = radius.shape[0]
    valid = idx[0] < n
    gi, gj = jnp.where(valid, idx[0], 0), jnp.where(valid, idx[1], 0)
    # Rows of one packed array, gathered once (XLA-CPU gathers contiguous rows fastest; integrate.py).
    packed = jnp.concatenate([fraction, fraction_compensation, velocity, angular_velocity], axis=1)
    rows_i, rows_j = packed[gi].T, packed[gj].T
    # High parts subtracted first (exact for nearby spheres), then the low parts added.
    step = (rows_j[0:3] - rows_i[0:3]) + (rows_j[3:6] - rows_i[3:6])
    branch = minimum_image_branch(jnp.zeros_like(step), step, length)
    image_velocity = rows_j[6:9] + strain_rate[:, None] * branch
    pairs = contact.pair_contact(
        branch,
        rows_i[6:9],
        image_velocity,
        rows_i[9:12],
        rows_j[9:12],
        radius[gi],
        radius[gj],
        spring.T,
        dt,
        law.normal_stiffness,
        law.tangential_stiffness,
        law.friction_coefficient,
    )
    totals, pair_force = contact.pair_totals(pairs, valid, gi, gj, n)
    distance = safe_norm(branch)
    overlap = radius[gi] + radius[gj] - distance
    normal_force = jnp.where(valid & (distance > 0.0), law.normal_stiffness * jnp.maximum(overlap, 0.0), 0.0)
    return PeriodicForces(
        force=totals[:, :3],
        torque=totals[:, 3:],
        pair_spring=select(valid, pairs.spring).T,
        pair_force=pair_force.T,
        pair_branch=select(valid, branch).T,
        pair_normal_force=normal_force,
    )


def love_weber_stress(forces: PeriodicForces, length):
    """σ = (1/V) Σ_c f_c ⊗ d_c, symmetrised, (3, 3), Pa, compression positive; V = Lx Ly Lz.

    The contact (Love–Weber) stress of a periodic cell (Love 1927; Weber 1966; Christoffersen, Mehrabadi
    & Nemat-Nasser 1981): f the force on j from i, d the minimum-image branch from i to j, so every
    contact counts once and no boundary term exists. The kinetic term (1/V) Σ m u ⊗ u is left out: with
    fluctuations u ~ ε̇ d it is of order φ ρ (ε̇ d)² = φ I² σ (I = ε̇ d √(ρ/σ)), below 1e-5 σ at the
    quasi-static I ≤ 1e-3 of a triaxial test.
    """
    total = jnp.einsum("ci,cj->ij", forces.pair_force, forces.pair_branch)
    stress = total / jnp.prod(length)
    return 0.5 * (stress + stress.T)


def cell_stiffness(forces: PeriodicForces, length, normal_stiffness):
    """K_k = (1/V) Σ_closed k_n (n_k d_k)², (3,), Pa: the stress change per unit box strain on axis k.

    Derived here: an affine strain δε_k changes each branch's component d_k by d_k δε_k and so each
    overlap by −n_k d_k δε_k (n = d/|d|); the normal force changes by −k_n n_k d_k δε_k, and σ_kk =
    (1/V) Σ f_k d_k by −(1/V) Σ k_n n_k² d_k² δε_k (normal springs only: the servo's scale, not the
    tangent stiffness). For a simple cubic lattice of spacing d along k, K_k = k_n / d.
    """
    branch = forces.pair_branch
    squared = jnp.sum(branch * branch, axis=1)
    closed = forces.pair_normal_force > 0.0
    weight = jnp.where(closed, normal_stiffness / jnp.where(closed, squared, 1.0), 0.0)
    return jnp.sum(weight[:, None] * branch**4, axis=0) / jnp.prod(length)


def coordination_numbers(
    forces: PeriodicForces, idx, num_particles: int, min_contacts: int = RATTLER_CONTACTS
):
    """(z, z*, rattler fraction): 2 C/N over closed contacts, the same without rattlers, and their share.

    Rattlers (Agnolin & Roux 2007): spheres with fewer than ``min_contacts`` closed contacts (static;
    :data:`RATTLER_CONTACTS` for frictionless packings, 2 with friction),
    removed :data:`RATTLER_PASSES` times over (a removal lowers its neighbours' counts); z* = 2 C*/N* over
    the contacts between the remaining N* spheres.
    """
    n = num_particles
    closed = forces.pair_normal_force > 0.0
    i = jnp.where(closed, idx[0], n)
    j = jnp.where(closed, idx[1], n)

    def counts(keep):
        kept = jnp.concatenate([keep, jnp.zeros((1,), bool)])
        both = closed & kept[i] & kept[j]
        ones = both.astype(jnp.int32)
        return jax.ops.segment_sum(
            jnp.concatenate([ones, ones]), jnp.concatenate([i, j]), num_segments=n + 1
        )[:n]

    raw = counts(jnp.ones((n,), bool))
    keep = raw >= min_contacts
    for _ in range(RATTLER_PASSES):
        keep = keep & (counts(keep) >= min_contacts)
    kept_counts = counts(keep)
    kept = jnp.sum(keep.astype(jnp.int32))
    dtype = forces.pair_normal_force.dtype
    z = jnp.sum(raw).astype(dtype) / n
    z_star = jnp.where(kept > 0, jnp.sum(kept_counts).astype(dtype) / jnp.maximum(kept, 1).astype(dtype), 0.0)
    return z, z_star, 1.0 - kept.astype(dtype) / n


def unbalanced_force_ratio(forces: PeriodicForces):
    """Mean |ΣF| over spheres / mean normal force over closed contacts (:mod:`membrax.spheres.measure`'s)."""
    net = safe_norm(forces.force.T)
    closed = forces.pair_normal_force > 0.0
    count = jnp.sum(closed.astype(net.dtype))
    mean_contact = jnp.sum(forces.pair_normal_force) / jnp.maximum(count, 1.0)
    return jnp.where(count > 0, jnp.mean(net) / jnp.where(count > 0, mean_contact, 1.0), jnp.inf)


def sample_element(grading: Grading, count: int, seed: int = 0) -> np.ndarray:
    """``count`` sphere diameters of ``grading`` for a periodic element, m, largest first.

    :func:`membrax.spheres.grading.sample_diameters` (the mould's sampling: mass by the grading, one draw
    per quantile stratum) in the solid volume that holds ``count`` spheres: bin i, of mass fraction f_i and
    mean sphere volume v_i, holds f_i V / v_i of them in V of solid, so V = count / Σ f_i / v_i.
    """
    check_range("count", count, lower=2)
    per_volume = sum(fraction / _mean_bin_volume(a, b) for a, b, fraction in grading.bins)
    return sample_diameters(grading, count / per_volume, seed)


def random_gas(diameters, solid_fraction: float, seed: int = 0, aspect=(1.0, 1.0, 1.0)):
    """Spheres placed at random without overlap in a periodic box: (fractional positions (N, 3), L (3,)).

    Random sequential addition (largest first, each tried at up to 1,000 uniform positions against the
    minimum-image distances to those placed), in a box of the given aspect sized for ``solid_fraction``;
    keep it below ~0.3 (random sequential addition jams near 0.38).

    Args:
      diameters: (N,) sphere diameters, m (e.g. :meth:`membrax.spheres.grading.Grading`'s sample).
      solid_fraction: Σ π d³/6 / V of the gas.
      seed: the random generator's seed.
      aspect: relative box lengths.
    """
    check_range("solid_fraction", solid_fraction, lower=0.0, upper=0.35, lower_open=True)
    diameters = np.sort(np.asarray(diameters, dtype=float))[::-1]
    volume = np.sum(math.pi * diameters**3 / 6.0) / solid_fraction
    aspect = np.asarray(aspect, dtype=float)
    length = aspect * (volume / np.prod(aspect)) ** (1.0 / 3.0)
    rng = np.random.default_rng(seed)
    placed = np.zeros((0, 3))
    for diameter in diameters:
        for _ in range(1000):
            trial = rng.random(3)
            step = placed - trial[None, :]
            branch = length[None, :] * (step - np.round(step))
            # Sorted largest first, so a placed sphere's diameter is >= this one's: the sum of radii.
            if not np.any(np.sum(branch**2, axis=1) < (0.5 * (diameters[: len(placed)] + diameter)) ** 2):
                break
        else:
            raise ValueError(
                f"random_gas: no room for a sphere at solid fraction {solid_fraction}; lower it."
            )
        placed = np.vstack([placed, trial])
    return placed, length, diameters
