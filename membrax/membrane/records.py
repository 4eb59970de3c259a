"""The records of a membrane triaxial test: the paper's external and internal stresses of a coupled state.

Contract. :func:`measure_coupled` takes a :class:`membrax.membrane.coupled.CoupledState` (one specimen),
its parameters, the time step and the reference height, volume and platen area, and returns its
:class:`MembraneMeasurements` (each field (1,)); it is pure ``jnp``, jittable and vmappable. The parts it
is made of (:func:`right_cylinder_stresses`, :func:`membrane_radial_force`,
:func:`membrane_love_weber_stress`, :func:`radial_projected_area`, :func:`radial_components`) are pure
functions of forces and positions; :func:`right_cylinder_stresses` also takes numpy arrays, so that the
records can be re-referenced after a run. SI units: m, N, Pa; strains as fractions, compression positive.

Volume and strains. The volume is the one enclosed by the membrane's inner face, V = V_mid − ½ t_m A_band
(V_mid enclosed by the mid-surface and the platens, :func:`membrax.membrane.mesh.enclosed_volume`); the
radial strain follows from volume and height, ε_r = 1 − √((V/H)/(V₀/H₀))
(:func:`membrax.theory.radial_strain`). The stresses follow the paper's §4.3, with the platen area updated
assuming right-cylinder deformation, A = A₀ (1 − ε_v)/(1 − ε_a):

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
- received radial (``received_radial_stress``): the same radial load, spheres and clamps, over the radially
  projected area of the membrane's mid-surface, A_r = Σ_nodes (∂V_mid/∂x_i)·r̂_i = ∮ n·r̂ dA
  (:func:`radial_projected_area`), the area on which the cell pressure's radial resultant is exactly σc A_r
  (the nodal pressure forces are −σc ∂V_mid/∂x). A membrane that keeps none of the pressure passes σc A_r to
  the spheres and clamps, so this stress is σc exactly, whatever the shape of the indented surface; the
  §4.3 one is then σc R̄/R_A (R̄ the mean radius of the loaded surface, R_A = √(A/π) the right cylinder's),
  a few per cent off with no membrane stiffness at all (docs/model.md, "Which internal stress").
- Love–Weber, with the membrane's node contacts as boundary contacts (force of the sphere on the node,
  arm b = x_node − x_sphere), over the inner-face volume V. In equilibrium its radial part is the
  boundary sum Σ_c f_r,c r_c / (2V) with r_c the nodes' radii (the mid-surface), so against the §4.3 σ3 it
  carries the factor r̄_c R_A / R_V² (R_V² = V/(πH)): moments taken at the mid-surface over the volume
  inside the inner face; over the mid-surface's volume V_mid the same sum gives σc exactly for a membrane
  that keeps no load (divergence theorem).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from membrax import pytree, theory
from membrax.membrane.coupled import contact_forces
from membrax.membrane.measure import hoop_strain
from membrax.membrane.mesh import enclosed_volume, inner_volume
from membrax.spheres.integrate import Particles, compute_forces
from membrax.spheres.measure import (
    coordination_number,
    kinetic_energy,
    love_weber_stress,
    principal_axisymmetric,
    unbalanced_force_ratio,
)
from membrax.spheres.walls import BOTTOM, TOP, platen_separation

__all__ = [
    "MembraneMeasurements",
    "measure_coupled",
    "membrane_love_weber_stress",
    "membrane_radial_force",
    "radial_components",
    "radial_projected_area",
    "right_cylinder_stresses",
]


@pytree.dataclass
class MembraneMeasurements:
    """Records of a coupled DEM + membrane state, each (1,) (one specimen); module docstring for the terms.

    Stresses in Pa (compression positive), strains as fractions (compression positive), forces in N.
    ``membrane_platen_force`` is the axial force of the membrane on the top platen minus that on the
    bottom one, halved: negative when the membrane pulls the platens together (axial tension).
    ``radial_projected_area`` (m²) and ``received_radial_stress`` need no reference state: the area is the
    deformed mid-surface's own.
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
    radial_projected_area: jnp.ndarray
    received_radial_stress: jnp.ndarray


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
    """All measurements of a :class:`membrax.membrane.coupled.CoupledState` (module docstring).

    Args:
      state: the coupled state.
      particles: sphere properties.
      mesh: the membrane mesh.
      params: :class:`membrax.membrane.coupled.CoupledParams`.
      dt: time step, s.
      initial_height: H₀, m.
      initial_volume: V₀ (inner face), m³.
      platen_area: m².
      wall_friction: as in :func:`membrax.spheres.integrate.compute_forces`.
    """
    spheres, nodes = state.dem, state.membrane
    mp = params.membrane
    forces = compute_forces(spheres, particles, params.dem, dt, wall_friction)
    contact = contact_forces(state, particles, params, dt, mesh)
    pair_member = jnp.zeros(spheres.neighbors.idx.shape[1], dtype=jnp.int32)
    walls = spheres.walls
    height = platen_separation(walls)
    volume = jnp.reshape(inner_volume(nodes.position, mesh, mp.contact_thickness), (1,))
    stress = membrane_love_weber_stress(
        forces, contact.slot_force, contact.branch, particles, pair_member, volume
    )
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
    projected_area = jnp.reshape(
        radial_projected_area(nodes.position, mesh, nodes.clamp_position[0]), (1,)
    ).astype(height.dtype)
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
    return MembraneMeasurements(
        hoop_strain=jnp.reshape(hoop_strain(nodes.position, mesh), (1,)),
        step=jnp.reshape(spheres.step, (1,)),
        axial_strain=axial_strain,
        volumetric_strain=volumetric_strain,
        radial_strain=theory.radial_strain(axial_strain, volumetric_strain),
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
        radial_projected_area=projected_area,
        received_radial_stress=(radial_force + clamp_force) / projected_area,
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


def membrane_love_weber_stress(forces, slot_force, branch, particles, pair_member, volume):
    """Love–Weber stress (1, 3, 3) of a membrane cell's spheres, Pa, compression positive (reference §9).

        σ_ij = (1/V) [Σ_pairs f_i l_j + Σ_platen contacts f_i b_j + Σ_node contacts f_i b_j], symmetrised,

    f the force of a sphere on the other body (pair: of i on j, l = x_j − x_i; platen and node contacts:
    of the sphere on the platen or node, b from the sphere's centre to the contact point, for a node the
    node itself, on the membrane's mid-surface).

    Args:
      forces: the spheres' contact forces (:func:`membrax.spheres.integrate.compute_forces`).
      slot_force: (n_nodes, K, 3) force of each candidate sphere on the node, N.
      branch: (n_nodes, K, 3) x_node − x_sphere per slot, m.
      particles: sphere properties (one specimen).
      pair_member: (C,) member of each pair slot.
      volume: (1,) the volume the stress is averaged over, m³.
    """
    membrane_dyad = jnp.sum(slot_force[:, :, :, None] * branch[:, :, None, :], axis=(0, 1))
    stress = (
        love_weber_stress(forces, particles, pair_member, volume)
        + membrane_dyad[None] / volume[:, None, None]
    )
    return 0.5 * (stress + jnp.swapaxes(stress, 1, 2))


def radial_projected_area(node_position, mesh, ring_position):
    """The mid-surface's radially projected area A_r = Σ_i (∂V_mid/∂x_i)·r̂_i, m² (module docstring).

    V_mid is :func:`membrax.membrane.mesh.enclosed_volume` (band and flat caps); the cell pressure's nodal
    forces are −σc ∂V_mid/∂x (:func:`membrax.membrane.energies.pressure_energy`), so their inward radial
    resultant is σc A_r exactly. For a smooth surface of revolution r = R(z) between the platens, A_r =
    ∮ n·r̂ dA = ∫∫ R dθ dz (divergence theorem, ∇·r̂ = 1/r): 2π R H for a right cylinder, 2π R̄ H for an
    indented one, R̄ the mean radius of the surface (not the radius of its volume).

    Args:
      node_position: (n_nodes, 3), m.
      mesh: the membrane mesh.
      ring_position: (n, 3) a clamped ring's nodes; their centroid is on the axis.
    """
    gradient = jax.grad(enclosed_volume)(node_position, mesh)
    return jnp.sum(radial_components(gradient, node_position, ring_position))


def radial_components(force, position, ring_position):
    """Per-row radial component F · r̂ (outward positive) about the axis through the ring's centroid, N.

    r̂ is the horizontal unit vector from the axis to the row's position (zero on the axis itself).
    """
    axis = jnp.mean(ring_position[:, :2], axis=0)
    offset = position[:, :2] - axis[None, :]
    distance = jnp.sqrt(jnp.sum(offset * offset, axis=1))
    safe = jnp.where(distance > 0.0, distance, 1.0)
    return jnp.where(distance > 0.0, jnp.sum(force[:, :2] * offset, axis=1) / safe, 0.0)
