"""The stability limit of the sphere step: the critical time step of the linearised contact network.

Contract. :func:`critical_time_step` (host side, numpy/scipy, float64) takes a :class:`DEMState` with a
current neighbour list, the :class:`Particles` and the :class:`DEMParams`, and returns Δt_crit = 2/ω_max
in seconds, ω_max² the largest eigenvalue of M⁻¹K over the 6N translational and rotational degrees of
freedom (Lanczos on the symmetric form, a fixed start vector: the same bits every call). The explicit
central-difference (leapfrog) step of an undamped linear system is stable for Δt ≤ 2/ω_max, the
amplification matrix of its stiffest mode having unit-modulus eigenvalues up to ω Δt = 2; the default step
is ``DEFAULT_SAFETY`` × Δt_crit. Nothing here is traced.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg

from membrax.spheres.integrate import DEMParams, DEMState, Particles

__all__ = ["DEFAULT_SAFETY", "critical_time_step"]

#: Default fraction of the critical time step.
DEFAULT_SAFETY = 0.5


def critical_time_step(
    state: DEMState,
    particles: Particles,
    params: DEMParams,
    contact_tolerance: float = 1e-6,
    include_rotation: bool = True,
) -> float:
    """Critical leapfrog time step Δt_crit = 2/ω_max of the linearised contact network.

    ω_max² is the largest eigenvalue of M⁻¹K, K the stiffness of the contacts that are closed or within
    ``contact_tolerance`` (a fraction of the radius) of closing — the touching FCC packing has zero overlap —
    with k_n along each normal and k_s across it, acting on the contact-point displacement
    du_c = (u_j + θ_j × r_j) − (u_i + θ_i × r_i). Rotation adds the θ terms: with k_s = k_n/2 a single
    sphere on a wall has a tangential–rotational mode at ω² = k_s (1/m + R²/I) = 3.5 k_s/m, above the
    normal k_n/m. Found by Lanczos iteration (``scipy.sparse.linalg.eigsh``, host side, float64) on the
    symmetric form M^(-1/2) K M^(-1/2), converged to a relative tolerance of 1e-10.

    Args:
      state: a state with a current neighbour list.
      particles: sphere properties.
      params: contact parameters (scalars or per member).
      contact_tolerance: gap, as a fraction of the radius, under which a contact counts as closed.
      include_rotation: include the rotational degrees of freedom (False gives the translational estimate).

    Returns:
      Δt_crit in seconds (a Python float).
    """
    n = particles.num_particles
    position = np.asarray(state.position, dtype=float)
    radius = np.asarray(particles.radius, dtype=float)
    mass = np.asarray(particles.mass, dtype=float)
    inertia = np.asarray(particles.inertia, dtype=float)
    member = np.asarray(particles.member)
    law = params.contact

    def per_member(value, ids):
        value = np.asarray(value, dtype=float)
        return np.broadcast_to(value if value.ndim == 0 else value[ids], ids.shape)

    i, j = np.asarray(state.neighbors.idx)
    keep = i < n
    i, j = i[keep], j[keep]
    branch = position[j] - position[i]
    distance = np.linalg.norm(branch, axis=1)
    closed = distance < (radius[i] + radius[j]) * (1.0 + contact_tolerance)
    i, j, branch, distance = i[closed], j[closed], branch[closed], distance[closed]
    normal = branch / distance[:, None]
    arm_i = radius[i, None] * normal
    arm_j = -radius[j, None] * normal
    kn = per_member(law.normal_stiffness, member[i])
    ks = per_member(law.tangential_stiffness, member[i])

    walls = state.walls
    wall_normal = np.asarray(walls.normal, dtype=float)
    wall_position = np.asarray(walls.position, dtype=float)[member]  # (N, W)
    gap = wall_position - position @ wall_normal.T
    wp, ww = np.nonzero(gap < radius[:, None] * (1.0 + contact_tolerance))
    wall_e = wall_normal[ww]
    wall_arm = radius[wp, None] * wall_e
    wkn = per_member(law.wall_normal_stiffness, member[wp])
    wks = per_member(law.wall_tangential_stiffness, member[wp])

    def spring_force(du, e, k_normal, k_tangent):
        along = np.sum(du * e, axis=1, keepdims=True)
        return -(k_normal[:, None] * along * e + k_tangent[:, None] * (du - along * e))

    def apply(displacement, rotation):
        du = (displacement[j] + np.cross(rotation[j], arm_j)) - (
            displacement[i] + np.cross(rotation[i], arm_i)
        )
        f_j = spring_force(du, normal, kn, ks)
        force = np.zeros_like(displacement)
        torque = np.zeros_like(displacement)
        np.add.at(force, j, f_j)
        np.add.at(force, i, -f_j)
        np.add.at(torque, i, np.cross(arm_i, -f_j))
        np.add.at(torque, j, np.cross(arm_j, f_j))
        du_w = displacement[wp] + np.cross(rotation[wp], wall_arm)
        f_w = spring_force(du_w, wall_e, wkn, wks)
        np.add.at(force, wp, f_w)
        np.add.at(torque, wp, np.cross(wall_arm, f_w))
        return -force, -torque  # K q

    # Symmetric form M^-1/2 K M^-1/2 over (translations, rotations), as a linear operator for Lanczos.
    sqrt_mass = np.sqrt(mass)[:, None]
    sqrt_inertia = np.sqrt(inertia)[:, None]
    size = 6 * n if include_rotation else 3 * n

    def matvec(vector):
        vector = np.asarray(vector, dtype=float).reshape(-1)
        x = vector[: 3 * n].reshape(n, 3)
        w = vector[3 * n :].reshape(n, 3) if include_rotation else np.zeros((n, 3))
        kx, kw = apply(x / sqrt_mass, w / sqrt_inertia)
        out = [(kx / sqrt_mass).ravel()]
        if include_rotation:
            out.append((kw / sqrt_inertia).ravel())
        return np.concatenate(out)

    operator = scipy.sparse.linalg.LinearOperator((size, size), matvec=matvec, dtype=float)
    start = np.random.default_rng(0).standard_normal(size)
    eigenvalue = float(scipy.sparse.linalg.eigsh(operator, k=1, which="LA", tol=1e-10, v0=start)[0][0])
    return 2.0 / np.sqrt(eigenvalue)
