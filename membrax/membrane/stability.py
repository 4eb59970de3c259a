"""The membrane's explicit step: its critical time step, and the Gent law's checks near the lock.

Contract. :func:`membrane_critical_time_step` gives the critical steps of the membrane's explicit
integration (mesh, contact, combined) from its rest stiffness (host side, once per test);
:func:`membrane_tangent_limit` the largest tangent-stiffness ratio k_t/k_0 a chosen step tolerates;
:func:`gent_bits` (:func:`locked_bit` | :func:`stiffened_bit`, jittable) the error bits a Gent membrane
sets when a triangle passes the lock's fraction (``ErrorCode.MEMBRANE_LOCKED``) or stiffens past what the
step tolerates (``ErrorCode.MEMBRANE_STIFFENED``), which the coupled step
(:func:`membrax.membrane.coupled.membrane_dem`) checks every ``LOCK_CHECK_EVERY`` steps. It mirrors
:mod:`membrax.spheres.stability` for the spheres.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg

from membrax.defaults import GENT_LOCK_FRACTION, LATEX_DENSITY
from membrax.errors import ErrorCode
from membrax.membrane import energies
from membrax.membrane.mesh import MembraneMesh, free_node_mask

__all__ = [
    "gent_bits",
    "locked_bit",
    "membrane_critical_time_step",
    "membrane_tangent_limit",
    "stiffened_bit",
]


def stiffened_bit(ratio, locking_jm, tangent_limit):
    """``ErrorCode.MEMBRANE_STIFFENED`` if Gent's tangent ratio at ``ratio`` exceeds the limit (jittable).

    Else 0. ``ratio`` is the closest approach to the lock, ``tangent_limit`` the step's r_max.

    The rule: Δt stays stable while k_t(s)/k_0 ≤ r_max (:func:`membrane_tangent_limit`), k_t/k_0 the
    equibiaxial tangent ratio at the largest s = (I₁ − 3)/J_m over the triangles
    (:func:`membrax.membrane.energies.gent_tangent_ratio`, which bounds the other tension states' there);
    i.e. while s ≤ s_stable (:func:`membrax.membrane.energies.stable_locking_ratio`). Compared as ratios so
    that J_m stays a traced parameter.

    Args:
      ratio: s at the closest approach (:func:`membrax.membrane.energies.locking_ratio`).
      locking_jm: J_m.
      tangent_limit: r_max (a float; ``inf``: never set).
    """
    if math.isinf(tangent_limit):
        return jnp.int32(0)
    tangent = energies.gent_tangent_ratio(ratio, locking_jm)
    return jnp.where(tangent > tangent_limit, ErrorCode.MEMBRANE_STIFFENED, 0).astype(jnp.int32)


def gent_bits(position, mesh: MembraneMesh, locking_jm, tangent_limit=math.inf):
    """:func:`locked_bit` | :func:`stiffened_bit` of one pass over the triangles (jittable)."""
    ratio = jax.lax.stop_gradient(energies.locking_ratio(position, mesh, locking_jm))
    locked = jnp.where(ratio > GENT_LOCK_FRACTION, ErrorCode.MEMBRANE_LOCKED, 0).astype(jnp.int32)
    return locked | stiffened_bit(ratio, jax.lax.stop_gradient(locking_jm), tangent_limit)


def membrane_tangent_limit(dt, critical) -> float:
    """r_max: the largest membrane tangent ratio k_t/k_0 the step ``dt`` tolerates (host).

    The explicit step is stable while ω² ≤ (2/Δt)², ω² = ω²_mesh + ω²_contact (the bound of
    :func:`membrane_critical_time_step` for the coupled node). Stiffening by k_t/k_0 multiplies ω²_mesh,
    the mesh's rest stiffness with the rest masses, by at most that ratio
    (:func:`membrax.membrane.energies.gent_tangent_ratio`), so

        k_t/k_0 ≤ r_max = (Δt_crit,mesh/Δt)² − (Δt_crit,mesh/Δt_crit,contact)²,

    ≥ 1 whenever Δt ≤ Δt_crit,combined. Chosen over a step taken from the tangent at the lock: that would
    divide every Gent run's Δt by √32.7 = 5.7 (J_m = 97.2, s = 0.9) to cover stretches few runs reach;
    the check costs one evaluation of the closed form every
    :data:`membrax.membrane.coupled.LOCK_CHECK_EVERY` steps, on the pass the lock check makes anyway.

    Args:
      dt: Δt, s.
      critical: :func:`membrane_critical_time_step`'s dict (``mesh`` and ``contact`` steps, s).
    """
    mesh_step, contact_step = float(critical["mesh"]), float(critical["contact"])
    return (mesh_step / float(dt)) ** 2 - (mesh_step / contact_step) ** 2


def locked_bit(position, mesh: MembraneMesh, locking_jm):
    """``ErrorCode.MEMBRANE_LOCKED`` if a triangle is past the Gent lock's fraction, else 0 (jittable).

    The Gent energy is continued past (I₁ − 3)/J_m = :data:`membrax.defaults.GENT_LOCK_FRACTION`
    (:func:`membrax.membrane.energies.stretching_energy`): the forces there are finite but no longer Gent's.
    """
    ratio = jax.lax.stop_gradient(energies.locking_ratio(position, mesh, locking_jm))
    return jnp.where(ratio > GENT_LOCK_FRACTION, ErrorCode.MEMBRANE_LOCKED, 0).astype(jnp.int32)


@functools.partial(jax.jit, static_argnames="model")
def _stiffness_product(
    vector, position, mesh, modulus, thickness, cell_pressure, bending_factor, locking_jm, model
):
    """K v, K = ∇²(W_stretch + W_bend + p V) at ``position``, by reverse over reverse mode.

    Jitted once per mesh size, not once per mesh: the mesh and parameters are arguments, not constants.
    """

    def energy(x):
        return energies.total_energy(
            x,
            mesh,
            modulus,
            thickness,
            cell_pressure,
            model=model,
            bending_factor=bending_factor,
            locking_jm=locking_jm,
        )

    return jax.grad(lambda x: jnp.vdot(jax.grad(energy)(x), vector))(position)


def membrane_critical_time_step(
    mesh: MembraneMesh,
    params,
    latex_density: float = LATEX_DENSITY,
    contacts_per_node: int = 2,
    stretching_model: str = "neo_hookean",
) -> dict:
    """Critical time steps of the membrane's explicit integration, s.

    ω²_mesh = λ_max(M⁻¹ K) of the membrane's stiffness K = ∇²(W_stretch + W_bend + p V) at the rest shape
    (Lanczos on Hessian–vector products, reverse over reverse mode), and the contact bound
    ω²_contact = c k_n / m_min for a node pressed by c spheres at once. Δt_crit = 2/ω for each and for the
    sum ω² = ω²_mesh + ω²_contact (a Gershgorin-style bound for the coupled node).

    Args:
      mesh: the membrane's mesh (its rest geometry).
      params: its :class:`membrax.membrane.coupled.MembraneParams` (modulus, thickness, cell pressure,
        bending factor, J_m, contact law).
      latex_density: kg/m³.
      contacts_per_node: spheres pressing one node at once, c.
      stretching_model: the membrane law (static).

    Returns:
      dict with ``mesh``, ``contact`` and ``combined`` critical steps, s.
    """
    position = mesh.reference_position
    mass = np.asarray(energies.lumped_mass(mesh, params.thickness, latex_density), dtype=float)
    free = free_node_mask(mesh)

    scale = np.repeat(1.0 / np.sqrt(mass), 3) * np.repeat(free, 3)  # M^-1/2, clamped rows removed
    stiffness = (
        params.modulus,
        params.thickness,
        params.cell_pressure,
        params.bending_factor,
        params.locking_jm,
    )

    def matvec(vector):
        vector = jnp.asarray((np.asarray(vector).ravel() * scale).reshape(-1, 3), dtype=position.dtype)
        product = _stiffness_product(vector, position, mesh, *stiffness, model=stretching_model)
        return np.asarray(product).ravel() * scale

    size = 3 * mesh.num_nodes
    operator = scipy.sparse.linalg.LinearOperator((size, size), matvec=matvec, dtype=float)
    # A fixed start vector: ARPACK's default is random, which made Δt differ between runs of one configuration
    # in its 7th digit (measured on the demo's mesh: 1.6434583e-4 and 1.6434544e-4 s).
    start = np.random.default_rng(0).standard_normal(size) * np.repeat(free, 3)
    omega_sq_mesh = float(scipy.sparse.linalg.eigsh(operator, k=1, which="LA", tol=1e-3, v0=start)[0][0])
    omega_sq_contact = contacts_per_node * float(params.contact.normal_stiffness) / float(mass[free].min())
    return {
        "mesh": 2.0 / math.sqrt(omega_sq_mesh),
        "contact": 2.0 / math.sqrt(omega_sq_contact) if omega_sq_contact > 0.0 else math.inf,
        "combined": 2.0 / math.sqrt(omega_sq_mesh + omega_sq_contact),
    }
