"""Measurements of a DEM state: stresses, strains, energies and equilibrium indicators.

Contract. Every function here is pure, works under ``jit`` and ``vmap``, and returns one value per batch
member (leading axis B). :func:`measure` bundles them into a :class:`Measurements` pytree that the driver
records every few steps. Stresses are compression-positive, in Pa.

Definitions (reference §9):

- Love–Weber (contact) stress, σ_ij = (1/V) Σ_c f_i l_j, with f the force exerted by body A on body B and
  l = x_B − x_A the branch vector. For a particle–boundary contact A is the particle, B the wall, and
  l runs from the particle centre to the contact point. Symmetrised. V is the specimen volume.
- Wall stresses: normal force on a wall / its current area (rigid cell: polygon × platen separation).
- Axial stress from the platens: the mean of the top and bottom platen forces over the platen area.
- Unbalanced-force ratio: mean |ΣF| over particles / mean contact normal force over closed contacts.
- Coordination number: 2 × (closed particle–particle contacts) / N (wall contacts not counted).
- Strains from the walls: ε_a = (H0 − H)/H0 and ε_v = (V0 − V)/V0, V = A H.

The measurements of a DEM specimen inside a membrane (the paper's §4.3 external and internal stresses)
are :func:`membrax.membrane.records.measure_coupled`'s.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from membrax import pytree, theory
from membrax.spheres.integrate import DEMParams, DEMState, Forces, Particles, compute_forces
from membrax.spheres.walls import BOTTOM, TOP, cross_section, platen_separation, wall_areas

__all__ = [
    "Measurements",
    "coordination_number",
    "kinetic_energy",
    "love_weber_stress",
    "measure",
    "principal_axisymmetric",
    "unbalanced_force_ratio",
]


def _per_member(values, member, num_members):
    return jax.ops.segment_sum(values, member, num_segments=num_members)


def love_weber_stress(forces: Forces, particles: Particles, pair_member, volume):
    """Love–Weber stress tensor (B, 3, 3), compression positive.

    Args:
      forces: contact forces from :func:`membrax.spheres.integrate.compute_forces`.
      particles: sphere properties (for batch members).
      pair_member: (C,) member of each pair slot.
      volume: (B,) specimen volume, m³.
    """
    pair_dyad = forces.pair_force[:, :, None] * forces.pair_branch[:, None, :]
    # Boundary contacts: force of the particle on the wall (minus the wall's force on it), centre → contact.
    wall_dyad = jnp.sum(-forces.wall_force[:, :, :, None] * forces.wall_arm[:, :, None, :], axis=1)
    wall_dyad = jnp.where((forces.wall_normal_force > 0.0).any(axis=1)[:, None, None], wall_dyad, 0.0)
    total = _per_member(pair_dyad, pair_member, particles.num_members) + _per_member(
        wall_dyad, particles.member, particles.num_members
    )
    stress = total / volume[:, None, None]
    return 0.5 * (stress + jnp.swapaxes(stress, 1, 2))


def principal_axisymmetric(stress):
    """(σ_axial, σ_radial) from a (B, 3, 3) tensor: σ_zz and the mean of σ_xx and σ_yy."""
    return stress[:, 2, 2], 0.5 * (stress[:, 0, 0] + stress[:, 1, 1])


def unbalanced_force_ratio(net_force, forces: Forces, particles: Particles, pair_member):
    """Mean |net force| over particles divided by the mean normal force over closed contacts, (B,)."""
    net = jnp.sqrt(jnp.sum(net_force * net_force, axis=1))
    count = _per_member(jnp.ones_like(net), particles.member, particles.num_members)
    mean_net = _per_member(net, particles.member, particles.num_members) / count
    closed = forces.pair_normal_force > 0.0
    contact_sum = _per_member(forces.pair_normal_force, pair_member, particles.num_members) + _per_member(
        jnp.sum(forces.wall_normal_force, axis=1), particles.member, particles.num_members
    )
    contact_count = _per_member(closed.astype(net.dtype), pair_member, particles.num_members) + _per_member(
        jnp.sum(forces.wall_normal_force > 0.0, axis=1).astype(net.dtype),
        particles.member,
        particles.num_members,
    )
    mean_contact = contact_sum / jnp.maximum(contact_count, 1.0)
    return mean_net / jnp.where(mean_contact > 0.0, mean_contact, 1.0)


def coordination_number(forces: Forces, particles: Particles, pair_member):
    """2 × closed particle–particle contacts / N per member, (B,)."""
    closed = (forces.pair_normal_force > 0.0).astype(forces.force.dtype)
    contacts = _per_member(closed, pair_member, particles.num_members)
    count = _per_member(
        jnp.ones(particles.num_particles, forces.force.dtype), particles.member, particles.num_members
    )
    return 2.0 * contacts / count


def kinetic_energy(state: DEMState, particles: Particles):
    """½ m v² + ½ I ω² per member (B,), J (with the half-step velocities of the state)."""
    translational = 0.5 * particles.mass * jnp.sum(state.velocity**2, axis=1)
    rotational = 0.5 * particles.inertia * jnp.sum(state.angular_velocity**2, axis=1)
    return _per_member(translational + rotational, particles.member, particles.num_members)


@pytree.dataclass
class Measurements:
    """Per-member (B,) records of one state (stresses in Pa, strains as fractions, angles in degrees).

    ``wall_force`` and ``wall_position`` are (B, W): the normal force of the particles on every wall (N)
    and every wall's plane position h (m), in the wall order of :mod:`membrax.spheres.walls`.
    """

    step: jnp.ndarray
    axial_strain: jnp.ndarray
    volumetric_strain: jnp.ndarray
    height: jnp.ndarray
    area: jnp.ndarray
    wall_axial_stress: jnp.ndarray
    wall_radial_stress: jnp.ndarray
    love_weber_axial_stress: jnp.ndarray
    love_weber_radial_stress: jnp.ndarray
    wall_friction_angle: jnp.ndarray
    love_weber_friction_angle: jnp.ndarray
    unbalanced_force_ratio: jnp.ndarray
    coordination_number: jnp.ndarray
    kinetic_energy: jnp.ndarray
    wall_force: jnp.ndarray
    wall_position: jnp.ndarray


def measure(
    state: DEMState,
    particles: Particles,
    params: DEMParams,
    dt,
    initial_height,
    initial_volume,
    platen_area=None,
    wall_friction: bool = True,
) -> Measurements:
    """All measurements of a state (rigid-wall cell: the volume is the wall polygon × platen separation).

    The contact forces are re-evaluated at the state's positions with its springs (without advancing them).

    Args:
      state: the state.
      particles: sphere properties.
      params: contact parameters.
      dt: time step (the spring increment is computed but discarded).
      initial_height: (B,) H0, m.
      initial_volume: (B,) V0, m³.
      platen_area: required when there are no lateral walls.
      wall_friction: as in :func:`membrax.spheres.integrate.compute_forces`.
    """
    forces = compute_forces(state, particles, params, dt, wall_friction)
    n = particles.num_particles
    i = state.neighbors.idx[0]
    pair_member = particles.member[jnp.where(i < n, i, 0)]
    walls = state.walls
    height = platen_separation(walls)
    if walls.num_lateral > 0:
        area, _ = cross_section(walls)
    else:
        area = jnp.broadcast_to(jnp.asarray(platen_area, dtype=height.dtype), height.shape)
    volume = area * height
    areas = wall_areas(walls, platen_area)
    stresses = forces.wall_total_force / areas
    wall_axial = 0.5 * (stresses[:, TOP] + stresses[:, BOTTOM])
    if walls.num_lateral > 0:
        lateral_force = jnp.sum(forces.wall_total_force[:, 2:], axis=1)
        wall_radial = lateral_force / jnp.sum(areas[:, 2:], axis=1)
    else:
        wall_radial = jnp.zeros_like(wall_axial)
    stress = love_weber_stress(forces, particles, pair_member, volume)
    lw_axial, lw_radial = principal_axisymmetric(stress)

    def friction_angle(axial, radial):
        major = jnp.maximum(axial, radial)
        minor = jnp.minimum(axial, radial)
        positive = minor > 0.0
        angle = theory.mobilised_friction_angle_deg(
            jnp.where(positive, major, 2.0), jnp.where(positive, minor, 1.0)
        )
        return jnp.where(positive, angle, jnp.nan)

    return Measurements(
        step=jnp.broadcast_to(state.step, height.shape),
        axial_strain=(initial_height - height) / initial_height,
        volumetric_strain=(initial_volume - volume) / initial_volume,
        height=height,
        area=area,
        wall_axial_stress=wall_axial,
        wall_radial_stress=wall_radial,
        love_weber_axial_stress=lw_axial,
        love_weber_radial_stress=lw_radial,
        wall_friction_angle=friction_angle(wall_axial, wall_radial),
        love_weber_friction_angle=friction_angle(lw_axial, lw_radial),
        unbalanced_force_ratio=unbalanced_force_ratio(forces.force, forces, particles, pair_member),
        coordination_number=coordination_number(forces, particles, pair_member),
        kinetic_energy=kinetic_energy(state, particles),
        wall_force=forces.wall_total_force,
        wall_position=walls.position + walls.position_compensation,
    )
