"""Contact laws: linear Cundall–Strack sphere–sphere and sphere–plane contacts with tangential history.

Contract. A contact law is a pure function of the contacts' kinematics and their carried tangential
springs that returns the forces and torques on the bodies and the updated springs. Conservative parts
(the normal spring) are ``-jax.grad`` of their energy; the non-conservative part (the tangential spring
with Coulomb slip) is an explicit force function, as in jax-md (``quantity.force`` /
``canonicalize_force``).

The law (Cundall & Strack 1979, Géotechnique 29(1), 47–65; the linear model of the paper's §4.2):

- normal: overlap δ = R_i + R_j − |x_j − x_i|; energy U_n = ½ k_n δ² for δ > 0; the force on j is
  F_n = −∂U_n/∂x_j = k_n δ n, n = (x_j − x_i)/|x_j − x_i| (from i to j);
- tangential: an incremental spring s carried per contact. Each step it is first rotated into the current
  tangent plane (its normal component removed and its length kept), then incremented by
  −k_s v_t Δt, v_t the tangential velocity of j's contact point relative to i's (rotation included), and
  finally capped by Coulomb, |s| <= μ |F_n|, μ = tan φ_μ (sliding). It is cleared when the contact opens;
- torques: each sphere's contact point is at its centre plus (R − δ/2) times the normal towards the
  other body; torque = arm × force; the normal force gives none.

Layout: vectors are component-first, shape (3, ...) (see :mod:`membrax.vector`), so each law is written
once and applies to one contact, (3,), or to all contacts at once, (3, C), without ``vmap``; scalars
(radii, stiffnesses) are () or (C,).

Neighbour lists: :class:`PairSpheres` holds the spheres as the sphere–sphere contacts of a neighbour
list read them; :func:`slot_spheres` says which pair slots are pairs and which spheres they join, and
:func:`slot_law` gives each slot the law of its batch member (:func:`for_members`: a parameter is a scalar
or one value per member).

Sign conventions: forces and torques in N and N·m on the bodies named; ``spring`` is the tangential force
on body j (for walls, on the sphere).

Gradient safety: the distance uses a guarded norm (double ``where``), so coincident centres (one FCC
sphere sits exactly on the axis, and padded pair slots point at a phantom particle) give finite gradients.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from membrax import pytree
from membrax.fusion import materialize
from membrax.vector import cross, dot, safe_norm, safe_normalize, scale, select

__all__ = [
    "pair_totals",
    "ContactParams",
    "PairContact",
    "PairSpheres",
    "WallContact",
    "for_members",
    "normal_energy",
    "pair_contact",
    "slot_law",
    "slot_spheres",
    "tangential_spring_update",
    "wall_contact",
]


@pytree.dataclass
class ContactParams:
    """Parameters of the linear contact law (SI). Each field is a scalar or an array over batch members.

    Attributes:
      normal_stiffness: k_n sphere–sphere (N/m); paper 1e7.
      tangential_stiffness: k_s sphere–sphere (N/m); paper 5e6.
      friction_coefficient: μ = tan φ_μ sphere–sphere; paper tan 25°.
      wall_normal_stiffness: k_n sphere–plane (N/m); paper 1e7.
      wall_tangential_stiffness: k_s sphere–plane (N/m); paper 5e6.
      wall_friction_coefficient: μ sphere–plane; paper 0 (platen friction angle 0°).
    """

    normal_stiffness: jnp.ndarray
    tangential_stiffness: jnp.ndarray
    friction_coefficient: jnp.ndarray
    wall_normal_stiffness: jnp.ndarray
    wall_tangential_stiffness: jnp.ndarray
    wall_friction_coefficient: jnp.ndarray

    @staticmethod
    def paper(
        friction_angle_deg: float = 25.0,
        wall_friction_angle_deg: float = 0.0,
        normal_stiffness: float = 1e7,
        tangential_stiffness: float = 5e6,
    ) -> ContactParams:
        """The paper's §5.1 values: k_n = 1e7 N/m, k_s = 5e6 N/m, φ_μ = 25°, platen friction 0°."""
        return ContactParams(
            normal_stiffness=jnp.asarray(normal_stiffness),
            tangential_stiffness=jnp.asarray(tangential_stiffness),
            friction_coefficient=jnp.asarray(math.tan(math.radians(friction_angle_deg))),
            wall_normal_stiffness=jnp.asarray(normal_stiffness),
            wall_tangential_stiffness=jnp.asarray(tangential_stiffness),
            wall_friction_coefficient=jnp.asarray(math.tan(math.radians(wall_friction_angle_deg))),
        )


def normal_energy(overlap, normal_stiffness):
    """Linear normal spring energy U_n = ½ k_n max(δ, 0)² (J)."""
    positive = jnp.maximum(overlap, 0.0)
    return 0.5 * normal_stiffness * positive * positive


def tangential_spring_update(
    spring,
    normal,
    tangential_velocity,
    dt,
    tangential_stiffness,
    friction_coefficient,
    normal_force,
    active,
    stored: bool = False,
):
    """Advance a Cundall–Strack tangential spring by one step.

    s' = Π_t(s) |s|/max(|Π_t(s)|, |s|/2) − k_s v_t Δt, then s'' = s' min(1, μ F_n / |s'|); s'' = 0 if not
    in contact.
    Π_t removes the normal component, so the spring follows the rotating contact plane.

    Args:
      spring: the carried spring (3, ...), force on body j.
      normal: current unit normal (3, ...) from i to j.
      tangential_velocity: velocity of j's contact point relative to i's, tangential part (3, ...).
      dt: time step (s).
      tangential_stiffness: k_s (N/m).
      friction_coefficient: μ.
      normal_force: |F_n| (N), >= 0.
      active: whether the bodies overlap.
      stored: store the per-contact intermediates once (:func:`membrax.fusion.materialize`; the same
        bits). XLA-CPU otherwise fuses the whole update into each vector component of the result and
        evaluates every norm three times: worth it for a wide, mostly padded table
        (:mod:`membrax.membrane.face_contact`).

    Returns:
      The new spring (3, ...).
    """
    store = materialize if stored else lambda *arrays: arrays if len(arrays) > 1 else arrays[0]
    length = safe_norm(spring)
    projected = spring - scale(dot(spring, normal), normal)
    length, projected = store(length, projected)
    # |s| Π_t(s)/|Π_t(s)|, the rescaling capped at 2. A physical spring turns by a tiny angle per step
    # (factor ≈ 1); one more than 60° out of the plane is round-off (1e-18 N along an FCC contact's normal,
    # measured), where the uncapped factor's derivative, ~|s|/|Π_t(s)|, reached 1e16 and blew up reverse
    # mode through a rollout. The cap changes only such round-off springs.
    # (Rounded as |s| · (Π_t(s) · 1/|Π_t(s)|), as before the cap: float32 springs summed over 20,000 steps
    # keep their earlier round-off.)
    denominator_squared = jnp.maximum(dot(projected, projected), 0.25 * length * length)
    positive = denominator_squared > 0.0
    denominator = jnp.where(positive, jnp.sqrt(jnp.where(positive, denominator_squared, 1.0)), 0.0)
    direction = select(positive, scale(1.0 / jnp.where(positive, denominator, 1.0), projected))
    trial = store(scale(length, direction) - scale(tangential_stiffness * dt, tangential_velocity))
    trial_length = safe_norm(trial)
    limit = friction_coefficient * normal_force
    slip_scale = jnp.where(
        trial_length > limit, limit / jnp.where(trial_length > 0.0, trial_length, 1.0), 1.0
    )
    slip_scale = store(slip_scale)
    return select(active, scale(slip_scale, trial))


@pytree.dataclass
class PairContact:
    """Result of one sphere–sphere contact: forces/torques on j (on i: −force, own torque)."""

    force_on_j: jnp.ndarray
    torque_on_i: jnp.ndarray
    torque_on_j: jnp.ndarray
    spring: jnp.ndarray
    normal_force: jnp.ndarray
    overlap: jnp.ndarray
    branch: jnp.ndarray


def pair_contact(
    branch,
    velocity_i,
    velocity_j,
    angular_velocity_i,
    angular_velocity_j,
    radius_i,
    radius_j,
    spring,
    dt,
    normal_stiffness,
    tangential_stiffness,
    friction_coefficient,
) -> PairContact:
    """Sphere–sphere Cundall–Strack contacts (see the module docstring for the law).

    Args:
      branch: x_j − x_i (3, ...), m (computed by the caller, with the position compensation).
      velocity_i: velocity of sphere i (3, ...), m/s.
      velocity_j: velocity of sphere j (3, ...), m/s.
      angular_velocity_i: angular velocity of i (3, ...), rad/s.
      angular_velocity_j: angular velocity of j (3, ...), rad/s.
      radius_i: radius of i, () or (...), m.
      radius_j: radius of j, () or (...), m.
      spring: carried tangential spring (3, ...), N.
      dt: time step, s.
      normal_stiffness: k_n, N/m.
      tangential_stiffness: k_s, N/m.
      friction_coefficient: μ.

    Returns:
      A :class:`PairContact`; ``branch`` is x_j − x_i (for the Love–Weber stress).
    """

    def energy(separation):
        # A sum of independent per-contact energies: its gradient is each contact's own force.
        return jnp.sum(normal_energy(radius_i + radius_j - safe_norm(separation), normal_stiffness))

    # The gradient taken per component: XLA-CPU forms it without padding each one into a (3, ...) array.
    normal_force_vector = -jnp.stack(jax.grad(energy)(tuple(branch)))  # on j
    normal, distance = safe_normalize(branch)
    overlap = radius_i + radius_j - distance
    active = overlap > 0.0
    normal_force = dot(normal_force_vector, normal)
    arm_i = scale(radius_i - 0.5 * overlap, normal)
    arm_j = scale(-(radius_j - 0.5 * overlap), normal)
    contact_velocity = (velocity_j + cross(angular_velocity_j, arm_j)) - (
        velocity_i + cross(angular_velocity_i, arm_i)
    )
    tangential_velocity = contact_velocity - scale(dot(contact_velocity, normal), normal)
    # Stored once each: XLA-CPU would otherwise re-evaluate the law per component and per output.
    normal_force_vector, normal, tangential_velocity, normal_force, active, arm_i, arm_j = materialize(
        normal_force_vector, normal, tangential_velocity, normal_force, active, arm_i, arm_j
    )
    new_spring = tangential_spring_update(
        spring,
        normal,
        tangential_velocity,
        dt,
        tangential_stiffness,
        friction_coefficient,
        normal_force,
        active,
    )
    force_on_j, new_spring = materialize(normal_force_vector + new_spring, new_spring)
    return PairContact(
        force_on_j=force_on_j,
        torque_on_i=cross(arm_i, -force_on_j),
        torque_on_j=cross(arm_j, force_on_j),
        spring=new_spring,
        normal_force=normal_force,
        overlap=overlap,
        branch=branch,
    )


def pair_totals(pairs: PairContact, valid, i, j, num_particles: int):
    """Each sphere's force and torque from its pair slots' contacts: ((N, 6) totals, (3, C) forces on j).

    Sphere j of a slot receives (F, T_j) and sphere i (−F, T_i), F = ``pairs.force_on_j``; padded slots
    (``valid`` False) carry zeros into a dropped segment N. One row scatter (``segment_sum`` of (2C, 6)
    rows; about 10× faster on XLA-CPU than scattering the (3, C) columns one by one).
    """
    pair_force = select(valid, pairs.force_on_j)
    stacked = jnp.concatenate(
        [
            jnp.concatenate([pair_force, select(valid, pairs.torque_on_j)], axis=0),
            jnp.concatenate([-pair_force, select(valid, pairs.torque_on_i)], axis=0),
        ],
        axis=1,
    ).T
    segments = jnp.concatenate([jnp.where(valid, j, num_particles), jnp.where(valid, i, num_particles)])
    totals = jax.ops.segment_sum(stacked, segments, num_segments=num_particles + 1)[:num_particles]
    return totals, pair_force


# The sphere–sphere contacts of a neighbour list: its pair slots (i, j), padded with i = N, read as the
# spheres and the law of each slot.


def for_members(value, member):
    """A law's parameter that is a scalar or one value per batch member, spread over particles or pairs."""
    value = jnp.asarray(value)
    return value if value.ndim == 0 else value[member]


@pytree.dataclass
class PairSpheres:
    """The spheres as the sphere–sphere contacts read them (rows, SI).

    Attributes:
      position: (N, 3) centres x, m.
      position_compensation: (N, 3) low-order part of x, m (the branches add it, see
        :class:`membrax.spheres.integrate.DEMState`).
      velocity: (N, 3) m/s.
      angular_velocity: (N, 3) rad/s.
      radius: (N,) m.
      member: (N,) int32 batch member of each sphere: a slot takes the contact law of its sphere i's member.
    """

    position: jnp.ndarray
    position_compensation: jnp.ndarray
    velocity: jnp.ndarray
    angular_velocity: jnp.ndarray
    radius: jnp.ndarray
    member: jnp.ndarray


def slot_spheres(spheres: PairSpheres, idx):
    """Which slots are pairs (i < N), and their spheres i and j with the padding (i = N) sent to sphere 0."""
    n = spheres.radius.shape[0]
    i, j = idx[0], idx[1]
    valid = i < n
    return valid, jnp.where(valid, i, 0), jnp.where(valid, j, 0)


def slot_law(law: ContactParams, member):
    """(k_n, k_t, μ) of the sphere–sphere law for slots of batch members ``member`` (scalars stay scalars)."""
    return (
        for_members(law.normal_stiffness, member),
        for_members(law.tangential_stiffness, member),
        for_members(law.friction_coefficient, member),
    )


@pytree.dataclass
class WallContact:
    """Result of one sphere–plane contact: force and torque on the sphere."""

    force: jnp.ndarray
    torque: jnp.ndarray
    spring: jnp.ndarray
    normal_force: jnp.ndarray
    overlap: jnp.ndarray
    arm: jnp.ndarray


def wall_contact(
    gap,
    velocity,
    angular_velocity,
    radius,
    wall_normal,
    wall_velocity,
    spring,
    dt,
    normal_stiffness,
    tangential_stiffness,
    friction_coefficient,
) -> WallContact:
    """Sphere–plane contacts. The plane is {x : x·e = h}, e its unit normal pointing *away* from the spheres.

    Gap d = h − x·e, overlap δ = R − d, energy U(d) = ½ k_n max(R − d, 0)², force on the sphere
    −∂U/∂x = (dU/dd) e = −k_n δ e. The wall moves along e at ``wall_velocity`` (it has no tangential
    velocity); the tangential spring works as for pairs.

    Args:
      gap: d = h − x·e, (...), m (computed by the caller, with the position compensation).
      velocity: the sphere's velocity (3, ...), m/s.
      angular_velocity: the sphere's angular velocity (3, ...), rad/s.
      radius: the sphere's radius.
      wall_normal: e (3, ...), unit, outward from the specimen.
      wall_velocity: dh/dt, m/s.
      spring: carried tangential spring (3,) on the sphere.
      dt: time step.
      normal_stiffness: the wall's k_n, N/m.
      tangential_stiffness: the wall's k_s, N/m.
      friction_coefficient: the wall's μ.
    """

    def energy(gap_):
        return jnp.sum(normal_energy(radius - gap_, normal_stiffness))

    normal_force_vector = scale(jax.grad(energy)(gap), wall_normal)
    overlap = radius - gap
    active = overlap > 0.0
    normal_force = -dot(normal_force_vector, wall_normal)
    arm = scale(radius - 0.5 * overlap, wall_normal)
    contact_velocity = velocity + cross(angular_velocity, arm) - scale(wall_velocity, wall_normal)
    tangential_velocity = contact_velocity - scale(dot(contact_velocity, wall_normal), wall_normal)
    # The spring is the force on the sphere; the sphere is body "j" relative to the wall.
    new_spring = tangential_spring_update(
        spring=spring,
        normal=-wall_normal,
        tangential_velocity=tangential_velocity,
        dt=dt,
        tangential_stiffness=tangential_stiffness,
        friction_coefficient=friction_coefficient,
        normal_force=normal_force,
        active=active,
    )
    force = normal_force_vector + new_spring
    return WallContact(
        force=force,
        torque=cross(arm, force),
        spring=new_spring,
        normal_force=normal_force,
        overlap=overlap,
        arm=arm,
    )
