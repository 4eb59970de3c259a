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

With a membrane (:func:`measure_coupled`, one specimen): the volume is the one enclosed by the membrane's
inner face, V = V_mid − ½ t_m A_band (V_mid enclosed by the mid-surface and the platens,
:func:`membrax.membrane.enclosed_volume`); the radial strain follows from volume and height,
ε_r = 1 − √((V/H)/(V₀/H₀)). The stresses follow the paper's §4.3, with the platen area updated assuming
right-cylinder deformation, A = A₀ (1 − ε_v)/(1 − ε_a):

- external axial: the ram force over A. The ram holds each platen against the spheres and the membrane,
  F_ram = F_spheres + F_ring + F_membrane per platen (compression positive along the platen's outward
  normal; :func:`right_cylinder_stresses`), averaged over the two platens; external radial: the cell
  pressure;
- internal axial: the force the spheres receive from the platens over A, F_spheres + F_ring (mean of
  both platens): F_spheres their push on the platen faces and F_ring their push on the clamped ring
  nodes, which the clamp passes to the platen (the paper: "including forces from the membrane that are
  transmitted through the membrane contact with the platen"). F_membrane, the membrane's own load on the
  platen (negative in axial tension), is the rest of the ram's. The three are recorded per platen
  (``platen_ram_force`` = ``platen_received_force`` + ``platen_membrane_force``);
- internal radial: the inward radial force the membrane exerts on the specimen, over the lateral area
  of the right cylinder of cross-section A, 2 √(π A) H: on the boundary spheres, F_r = −Σ_i F_i · r̂_i
  (``membrane_radial_force``; r̂_i the horizontal unit vector from the specimen axis to sphere i, the
  axis the centroid of the clamped bottom ring), plus what the clamped rings take (``clamp_radial_force``,
  −Σ F·r̂ over the ring nodes' total forces: the strip between a clamp and the first sphere row passes
  its share to the platens, 5–11 % of the whole on the paper's and the demo's specimens). The lateral
  area spans the whole height H, clamp strips included, so the numerator counts their load too: the
  spheres' load over the spheres' share of the area would give the same σ3. (For a regular octagon under
  uniform pressure the cylinder of equal area has a lateral area within 0.11 % of ∮ n·r̂ ds H, so the
  octagonal specimen needs no shape factor.)
- Love–Weber, with the membrane's node contacts as boundary contacts (force of the sphere on the node,
  arm b = x_node − x_sphere).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax_md import dataclasses

from membrax import membrane as membrane_lib
from membrax import theory
from membrax.integrate import DEMParams, DEMState, Forces, Particles, compute_forces
from membrax.membrane_dem import contact_forces
from membrax.walls import BOTTOM, TOP, cross_section, platen_separation, wall_areas

__all__ = [
    "Measurements",
    "MembraneMeasurements",
    "hoop_strain",
    "membrane_radial_force",
    "radial_components",
    "measure_coupled",
    "coordination_number",
    "kinetic_energy",
    "love_weber_stress",
    "measure",
    "principal_axisymmetric",
    "right_cylinder_stresses",
    "unbalanced_force_ratio",
]


def _per_member(values, member, num_members):
    return jax.ops.segment_sum(values, member, num_segments=num_members)


def love_weber_stress(forces: Forces, particles: Particles, pair_member, volume):
    """Love–Weber stress tensor (B, 3, 3), compression positive.

    Args:
      forces: contact forces from :func:`membrax.integrate.compute_forces`.
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


@dataclasses.dataclass
class Measurements:
    """Per-member (B,) records of one state (stresses in Pa, strains as fractions, angles in degrees).

    ``wall_force`` and ``wall_position`` are (B, W): the normal force of the particles on every wall (N)
    and every wall's plane position h (m), in the wall order of :mod:`membrax.walls`.
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
      wall_friction: as in :func:`membrax.integrate.compute_forces`.
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


@dataclasses.dataclass
class MembraneMeasurements:
    """Records of a coupled DEM + membrane state, each (1,) (one specimen); module docstring for the terms.

    Stresses in Pa (compression positive), strains as fractions (compression positive), forces in N.
    ``membrane_platen_force`` is the axial force of the membrane on the top platen minus that on the
    bottom one, halved: negative when the membrane pulls the platens together (axial tension).
    """

    step: jnp.ndarray
    axial_strain: jnp.ndarray
    volumetric_strain: jnp.ndarray
    radial_strain: jnp.ndarray
    height: jnp.ndarray
    volume: jnp.ndarray
    platen_axial_stress: jnp.ndarray
    love_weber_axial_stress: jnp.ndarray
    love_weber_radial_stress: jnp.ndarray
    love_weber_friction_angle: jnp.ndarray
    unbalanced_force_ratio: jnp.ndarray
    coordination_number: jnp.ndarray
    kinetic_energy: jnp.ndarray
    membrane_platen_force: jnp.ndarray
    membrane_contacts: jnp.ndarray
    wall_force: jnp.ndarray
    wall_position: jnp.ndarray
    time: jnp.ndarray
    platen_area: jnp.ndarray
    ram_force: jnp.ndarray
    received_axial_force: jnp.ndarray
    platen_ram_force: jnp.ndarray
    platen_received_force: jnp.ndarray
    platen_membrane_force: jnp.ndarray
    membrane_radial_force: jnp.ndarray
    clamp_radial_force: jnp.ndarray
    hoop_strain: jnp.ndarray
    external_axial_stress: jnp.ndarray
    external_radial_stress: jnp.ndarray
    internal_axial_stress: jnp.ndarray
    internal_radial_stress: jnp.ndarray


def measure_coupled(
    state,
    particles: Particles,
    mesh,
    params,
    dt,
    initial_height,
    initial_volume,
    platen_area,
    wall_friction: bool = False,
) -> MembraneMeasurements:
    """All measurements of a :class:`membrax.membrane_dem.CoupledState` (module docstring).

    Args:
      state: the coupled state.
      particles: sphere properties.
      mesh: the membrane mesh.
      params: :class:`membrax.membrane_dem.CoupledParams`.
      dt: time step, s.
      initial_height: H₀, m.
      initial_volume: V₀ (inner face), m³.
      platen_area: m².
      wall_friction: as in :func:`membrax.integrate.compute_forces`.
    """
    spheres, nodes = state.dem, state.membrane
    mp = params.membrane
    forces = compute_forces(spheres, particles, params.dem, dt, wall_friction)
    contact = contact_forces(state, particles, params, dt)
    pair_member = jnp.zeros(spheres.neighbors.idx.shape[1], dtype=jnp.int32)
    walls = spheres.walls
    height = platen_separation(walls)
    volume = jnp.reshape(membrane_lib.inner_volume(nodes.position, mesh, mp.contact_thickness), (1,))
    membrane_dyad = jnp.sum(contact.slot_force[:, :, :, None] * contact.branch[:, :, None, :], axis=(0, 1))
    stress = (
        love_weber_stress(forces, particles, pair_member, volume)
        + membrane_dyad[None] / volume[:, None, None]
    )
    stress = 0.5 * (stress + jnp.swapaxes(stress, 1, 2))
    lw_axial, lw_radial = principal_axisymmetric(stress)
    platen_stress = 0.5 * (forces.wall_total_force[:, TOP] + forces.wall_total_force[:, BOTTOM]) / platen_area
    major = jnp.maximum(lw_axial, lw_radial)
    minor = jnp.minimum(lw_axial, lw_radial)
    positive = minor > 0.0
    angle = jnp.where(
        positive,
        theory.mobilised_friction_angle_deg(jnp.where(positive, major, 2.0), jnp.where(positive, minor, 1.0)),
        jnp.nan,
    )
    net_force = forces.force + contact.sphere_force
    reaction = nodes.platen_reaction
    outward = jnp.asarray([-1.0, 1.0], dtype=height.dtype)  # platen normals along z: bottom −, top +
    sphere_platen = forces.wall_total_force[0, :2]
    ring_contact = outward * nodes.ring_contact_force[:, 2]
    membrane_load = outward * reaction[:, 2] - ring_contact
    # Per platen (bottom, top), compression positive: the ram holds the spheres' push on the platen face,
    # their push on the clamped ring and the membrane's own load (negative when it pulls the platens
    # together); the spheres receive the first two.
    ram = sphere_platen + ring_contact + membrane_load
    received = sphere_platen + ring_contact
    radial_force = jnp.reshape(
        membrane_radial_force(contact.sphere_force, spheres.position, nodes.clamp_position[0]), (1,)
    )
    rings = jnp.concatenate([mesh.bottom_ring, mesh.top_ring])
    # The membrane's radial load that the clamped rings pass to the platens: the strip between a ring and
    # the first sphere row, carried by the specimen's ends (module docstring).
    clamp_force = jnp.reshape(
        -jnp.sum(radial_components(nodes.node_force[rings], nodes.position[rings], nodes.clamp_position[0])),
        (1,),
    )
    area, external_axial, internal_axial, internal_radial = right_cylinder_stresses(
        jnp.mean(ram)[None],
        jnp.mean(received)[None],
        radial_force + clamp_force,
        height,
        volume,
        initial_height,
        initial_volume,
        platen_area,
    )
    axial_strain = (initial_height - height) / initial_height
    volumetric_strain = (initial_volume - volume) / initial_volume
    ratio = (volume / height) / (initial_volume / initial_height)
    return MembraneMeasurements(
        hoop_strain=jnp.reshape(hoop_strain(nodes.position, mesh), (1,)),
        step=jnp.reshape(spheres.step, (1,)),
        axial_strain=axial_strain,
        volumetric_strain=volumetric_strain,
        radial_strain=1.0 - jnp.sqrt(ratio),
        height=height,
        volume=volume,
        platen_axial_stress=platen_stress,
        love_weber_axial_stress=lw_axial,
        love_weber_radial_stress=lw_radial,
        love_weber_friction_angle=angle,
        unbalanced_force_ratio=unbalanced_force_ratio(net_force, forces, particles, pair_member),
        coordination_number=coordination_number(forces, particles, pair_member),
        kinetic_energy=kinetic_energy(spheres, particles),
        membrane_platen_force=jnp.reshape(jnp.mean(membrane_load), (1,)),
        membrane_contacts=jnp.reshape(jnp.sum(contact.overlap > 0.0), (1,)),
        wall_force=forces.wall_total_force,
        wall_position=walls.position + walls.position_compensation,
        time=jnp.reshape(spheres.step.astype(height.dtype) * jnp.asarray(dt, height.dtype), (1,)),
        platen_area=area,
        ram_force=jnp.mean(ram)[None],
        received_axial_force=jnp.mean(received)[None],
        platen_ram_force=ram[None],
        platen_received_force=received[None],
        platen_membrane_force=membrane_load[None],
        membrane_radial_force=radial_force,
        clamp_radial_force=clamp_force,
        external_axial_stress=external_axial,
        external_radial_stress=jnp.reshape(mp.cell_pressure, (1,)).astype(height.dtype),
        internal_axial_stress=internal_axial,
        internal_radial_stress=internal_radial,
    )


def right_cylinder_stresses(
    ram_force,
    received_axial_force,
    radial_force,
    height,
    volume,
    reference_height,
    reference_volume,
    platen_area,
):
    """The paper's §4.3 stresses on a right cylinder: (area, external σ1, internal σ1, internal σ3), Pa.

    The area follows right-cylinder deformation from a reference state (height H₀, volume V₀, platen area
    A₀): A = A₀ (1 − ε_v)/(1 − ε_a) with ε_a = (H₀ − H)/H₀ and ε_v = (V₀ − V)/V₀ (the paper's §4.3, ASTM
    D7181's area correction). External σ1 = F_ram / A; internal σ1 = F_received / A; internal σ3 = F_r /
    (2 √(π A) H), the lateral area of the right cylinder of cross-section A. Works on JAX and numpy arrays
    alike, so the records can be re-referenced after the run (the start of shearing, :mod:`membrax.run`).

    Args:
      ram_force: the ram's force, N (mean of the two platens).
      received_axial_force: the force the spheres receive from the platens and clamped rings, N.
      radial_force: the membrane's inward radial force on the specimen, N.
      height: H now, m.
      volume: V now, m³.
      reference_height: H₀ of the reference state, m.
      reference_volume: V₀ of the reference state, m³.
      platen_area: A₀, m².
    """
    axial_strain = (reference_height - height) / reference_height
    volumetric_strain = (reference_volume - volume) / reference_volume
    area = platen_area * (1.0 - volumetric_strain) / (1.0 - axial_strain)
    lateral_area = 2.0 * (area * math.pi) ** 0.5 * height
    return area, ram_force / area, received_axial_force / area, radial_force / lateral_area


def hoop_strain(node_position, mesh):
    """The membrane's circumferential strain at mid-height, ε_θ = L/L₀ − 1 (tension positive).

    L is the length of the closed polyline through the nodes of the band's middle ring, L₀ its length in
    the rest mesh (the unstretched membrane). A laboratory measures the same with a circumference tape
    where the membrane bridges the voids. Hoop theory (Henkel & Gilbert 1952) turns it into the
    membrane's radial stress, Δσ_r = 2 E_m t_m ε_θ / D₀ (:func:`membrax.theory.hoop_tension_correction`).
    """
    around = mesh.bottom_ring.shape[0]
    rings = (mesh.top_ring[0] - mesh.bottom_ring[0]) // around + 1
    middle = mesh.bottom_ring + around * (rings // 2)

    def length(position):
        ring = position[middle]
        step = jnp.roll(ring, -1, axis=0) - ring
        return jnp.sum(jnp.sqrt(jnp.sum(step * step, axis=1)))

    return length(node_position) / length(mesh.reference_position.astype(node_position.dtype)) - 1.0


def membrane_radial_force(sphere_force, sphere_position, ring_position):
    """Inward radial force of the membrane on the spheres, F_r = −Σ_i F_i · r̂_i, N (module docstring).

    Args:
      sphere_force: (N, 3) the membrane's force on each sphere, N.
      sphere_position: (N, 3), m.
      ring_position: (n, 3) nodes of a clamped ring, whose centroid fixes the specimen axis.

    Returns:
      Scalar F_r (positive when the membrane presses the spheres inward).
    """
    return -jnp.sum(radial_components(sphere_force, sphere_position, ring_position))


def radial_components(force, position, ring_position):
    """Per-row radial component F · r̂ (outward positive) about the axis through the ring's centroid, N.

    r̂ is the horizontal unit vector from the axis to the row's position (zero on the axis itself).
    """
    axis = jnp.mean(ring_position[:, :2], axis=0)
    offset = position[:, :2] - axis[None, :]
    distance = jnp.sqrt(jnp.sum(offset * offset, axis=1))
    safe = jnp.where(distance > 0.0, distance, 1.0)
    return jnp.where(distance > 0.0, jnp.sum(force[:, :2] * offset, axis=1) / safe, 0.0)
