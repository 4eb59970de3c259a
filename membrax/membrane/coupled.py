"""DEM + membrane: spheres, platens and a latex membrane whose end rings are clamped to the platens.

Contract. ``membrane_dem(particles, neighbor_frame, mesh, dt)`` returns ``(init_fn, step_fn)`` in the
jax-md style, composed from :func:`membrax.spheres.integrate.sphere_dem` and the membrane modules:

- ``init_fn(dem_state, params, capacity=3, skin=..., sphere_capacity=64) -> CoupledState`` (host side:
  builds the node–sphere candidate table over every sphere, through a cell list: K per node, M per
  sphere and C spheres per cell, all grown by the chunk driver on overflow; the membrane starts at rest
  at ``mesh.reference_position``, its rings clamped to the platens where they stand in ``dem_state``);
- ``step_fn(state, params) -> CoupledState`` advances one step under ``jit``; ``params``
  (:class:`CoupledParams`: the DEM's and the membrane's parameters) is traced, so it can be differentiated
  and changed without recompiling.

One step (explicit central differences, as the DEM; velocities at half steps):

1. node–sphere contacts at (y_n, x_n) with the velocities of the previous half step
   (:func:`membrax.membrane.contact.node_sphere_forces`), or with ``contact_model="faces"`` the
   contacts of the spheres with the mesh's faces, edges and nodes
   (:func:`membrax.membrane.face_contact.face_contact_forces`: the mesh cannot pass between its nodes
   through a sphere; its own CPU kernel, ``face_contact.cc``, so steps 1, 2 and 4 run as three kernels
   rather than the node law's chained node step; the node table then reaches one rest edge further,
   :func:`membrax.membrane.face_contact.longest_edge`);
2. membrane forces −∇(W_stretch + W_bend + p V) at y_n (:func:`membrax.membrane.energies.nodal_forces`);
3. the DEM step with the contacts' reactions added to the spheres (forces and torques);
4. free nodes (:mod:`membrax.membrane.node_update`): damped leapfrog with the lumped masses (area × t_m
   × ρ_latex / 3 per triangle corner) and the DEM's damping law
   (:func:`membrax.spheres.integrate.apply_damping`), in the DEM's frame: with
   ``DampingParams.frame = "affine"`` (the default) on the velocity relative to the platens' affine field
   v_ref = (0, 0, v_b + (v_t − v_b)(z − z_b)/(z_t − z_b)) while they shear the specimen
   (:func:`membrax.spheres.walls.affine_velocity`), so that the membrane's share of the drag does not load
   the platens either (absolute damping of the nodes carried 0.4–0.6 % of σc onto the ram in shearing at
   10 kPa and I = 1e-3, the affine frame 0.07–0.15 %, ``examples/damping_artefact.py``). No radial term:
   the membrane's radial motion is free, and a reference taken from it would leave its slowest mode, the
   specimen's radial breathing, undamped (the nodes' radial drag adds ~0.3–0.5 % of σc to the internal σ3).
   Clamped nodes (the two end rings, the O-rings) follow their platen rigidly:
   y = y_clamp + (z_platen − z_platen,0) e_z;
5. the candidate table is rebuilt when a node or a sphere moved more than skin/2
   (:func:`membrax.membrane.candidates.update_candidates`), and with it, under ``contact_model="faces"``,
   the feature slots, the springs carried onto them by sphere id (:func:`refresh_feature_contact`; they
   are a function of the table alone, so a state always holds its table's slots); an overflow sets
   ``ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW`` (:mod:`membrax.errors`) in the DEM state's error bitmask,
   and the chunk driver reallocates a larger table and reruns the chunk.

Platen reactions. The clamp holds the ring nodes against the forces F_k of the membrane and the spheres
on them, so the membrane loads each platen with R = Σ_ring F_k + p A n_out: the second term removes the
cell pressure on the cap, which :func:`membrax.membrane.mesh.enclosed_volume` closes over the platen face (the
cell pressure there acts on the platen, not on the membrane); A n_out = ±½ Σ_k y_k × y_{k+1} is the
ring's vector area, n_out = −e_z at the bottom and +e_z at the top. ``MembraneState.platen_reaction``
holds R for both platens (N; R_z < 0 on the top platen when the membrane pulls it down). They are
recorded separately from the sphere–platen forces. The platen servo holds the ram force: the ram
balances both, F_ram = F_spheres + R_z on the top platen (F_spheres − R_z on the bottom one), so the
membrane's normal reactions are passed to the DEM step as extra wall loads. Sphere contacts on the
clamped ring nodes reach the platen through the clamp: ``MembraneState.ring_contact_force`` keeps them
apart, so that the spheres receive F_spheres + F_ring contacts from the platens (the paper's internal
axial force "including forces from the membrane that are transmitted through the membrane contact with
the platen") and the membrane alone pulls R − F_ring contacts: the spheres receive more than the ram
when the membrane is in axial tension (the paper's internal σ1 above the external one, its Table 3).

Reverse mode. On the CPU kernels, steps 1, 2 and 4 are one reverse-mode rule,
:func:`membrax.membrane.node_update.node_step`; elsewhere the three functions run as written above.

Scope: one specimen (``particles.num_members == 1``), the platens being walls 0 and 1 and no lateral
walls; batches of specimens are the business of :mod:`membrax.sweep`. SI units: m, s, N, Pa, kg.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native, pytree
from membrax.defaults import GENT_LOCKING_JM, LATEX_DENSITY, MEMBRANE_CONTACT_MODELS, MEMBRANE_MODULUS
from membrax.errors import not_finite_bit
from membrax.membrane import energies
from membrax.membrane.candidates import (
    CandidateCapacities,
    NodeCandidates,
    build_candidates,
    candidate_errors,
    remap_node_history,
    update_candidates,
)
from membrax.membrane.contact import (
    ContactNodes,
    ContactSpheres,
    MembraneContactParams,
    node_sphere_forces,
)
from membrax.membrane.face_contact import (
    FeatureContactState,
    carry_springs,
    face_contact_forces,
    feature_slots,
    longest_edge,
    mesh_neighbours,
    widen,
    zero_springs,
)
from membrax.membrane.mesh import MembraneMesh, free_node_mask
from membrax.membrane.node_update import MembraneNodes, advance_nodes, node_step
from membrax.membrane.stability import gent_bits
from membrax.spheres.integrate import DEMParams, DEMState, Particles, sphere_dem
from membrax.spheres.neighbors import PairNeighborFn
from membrax.spheres.walls import BOTTOM, TOP, affine_velocity
from membrax.validation import check_range

#: The membrane–sphere contact models of :func:`membrane_dem` (``membrax.defaults.MEMBRANE_CONTACT_MODELS``).
CONTACT_MODELS = MEMBRANE_CONTACT_MODELS

__all__ = [
    "CONTACT_MODELS",
    "LOCK_CHECK_EVERY",
    "CoupledParams",
    "contact_forces",
    "CoupledState",
    "MembraneParams",
    "MembraneState",
    "grow_candidates",
    "membrane_dem",
    "platen_heights",
    "platen_reaction",
    "refresh_feature_contact",
]

#: Steps between the Gent lock checks of a coupled step (:func:`membrax.membrane.stability.gent_bits`): a
#: pass over the triangles in JAX, 0.8 ms at paper size (33,000 triangles, float32, 2 CPU cores) against
#: 0.25 ms for the compiled membrane forces, so every 20th step (0.04 ms a step on average). A membrane runs
#: to its lock over many more steps than that, and the continued energy keeps the forces finite meanwhile.
LOCK_CHECK_EVERY = 20


@pytree.dataclass
class MembraneParams:
    """Traced membrane parameters (SI).

    Attributes:
      modulus: E_m, Pa (paper: 1400 kPa).
      thickness: t_m, m (paper: 2.5, 3.33 and 5 mm).
      cell_pressure: p, Pa, on the membrane's outer face.
      contact: the node–sphere contact law.
      bending_factor: scale of the bending rigidity, dimensionless: 1 the plate's E t³/12(1 − ν²), 0 a pure
        membrane (:func:`membrax.membrane.energies.total_energy`).
      contact_offset_factor: where nodes touch spheres, dimensionless: at R + f t_m/2 from a sphere's
        centre (1: the membrane's inner face touches the sphere, its nodes on the mid-surface t_m/2
        off; 0: the nodes on the sphere surface, as the paper's "constrained to lie on the surface of
        the respective particle").
      locking_jm: J_m of the Gent stretching law, dimensionless
        (:func:`membrax.membrane.energies.stretching_energy`; the other laws do not read it).
    """

    modulus: jnp.ndarray
    thickness: jnp.ndarray
    cell_pressure: jnp.ndarray
    contact: MembraneContactParams
    bending_factor: jnp.ndarray
    contact_offset_factor: jnp.ndarray
    locking_jm: jnp.ndarray = GENT_LOCKING_JM

    @property
    def contact_thickness(self):
        """F t_m, m: the thickness the node–sphere contact sees (nodes touch at R + f t_m/2)."""
        return self.contact_offset_factor * self.thickness

    @staticmethod
    def create(
        *,
        thickness: float,
        cell_pressure: float,
        modulus: float = MEMBRANE_MODULUS,
        contact: MembraneContactParams | None = None,
        bending_factor: float = 0.0,
        contact_offset_factor: float = 1.0,
        locking_jm: float = GENT_LOCKING_JM,
    ) -> MembraneParams:
        """Parameters in SI, range-checked; the modulus defaults to the paper's (:mod:`membrax.defaults`).

        Args:
          thickness: t_m, m, > 0 (the paper's: 2.5e-3 to 5e-3).
          cell_pressure: σc, Pa, >= 0 (the paper's: 1e4 to 1e5).
          modulus: E_m, Pa, > 0 (the paper's latex: 1.4e6).
          contact: the node–sphere law (default :meth:`MembraneContactParams.default`).
          bending_factor: scale of the plate bending rigidity, >= 0.
          contact_offset_factor: nodes touch spheres at R + f t_m/2, f in [0, 1].
          locking_jm: the Gent law's J_m, > 0 (:data:`membrax.defaults.GENT_LOCKING_JM`).
        """
        check_range("bending_factor", bending_factor, lower=0.0, hint="1: plate bending; 0: none.")
        check_range(
            "contact_offset_factor",
            contact_offset_factor,
            lower=0.0,
            upper=1.0,
            hint="0: nodes on the sphere surface; 1: the inner face on it.",
        )
        check_range("modulus", modulus, lower=0.0, lower_open=True, hint="Pa; latex is about 1.4e6.")
        check_range("thickness", thickness, lower=0.0, lower_open=True, hint="m; paper: 2.5e-3 to 5e-3.")
        check_range("cell_pressure", cell_pressure, lower=0.0, hint="Pa; 10 kPa is 1e4.")
        check_range("locking_jm", locking_jm, lower=0.0, lower_open=True, hint="natural rubber: about 100.")
        return MembraneParams(
            modulus=jnp.asarray(modulus),
            thickness=jnp.asarray(thickness),
            cell_pressure=jnp.asarray(cell_pressure),
            contact=MembraneContactParams.default() if contact is None else contact,
            bending_factor=jnp.asarray(float(bending_factor)),
            contact_offset_factor=jnp.asarray(float(contact_offset_factor)),
            locking_jm=jnp.asarray(float(locking_jm)),
        )


@pytree.dataclass
class CoupledParams:
    """The traced parameters of a coupled step: the DEM's (contacts, damping) and the membrane's."""

    dem: DEMParams
    membrane: MembraneParams


@pytree.dataclass
class MembraneState:
    """Everything of the membrane that evolves.

    Attributes:
      position: (n, 3) node positions y_n, m.
      position_compensation: (n, 3) low-order part of y_n (compensated summation, as the spheres).
      velocity: (n, 3) node velocities at the previous half step, m/s.
      spring: (3, n, K) tangential springs of the node–sphere slots (force on the node), N.
      candidates: the node → sphere candidate table.
      clamp_position: (2, n_θ, 3) the bottom and top ring positions when the platens stood at
        ``clamp_platen_height``, m.
      clamp_platen_height: (2,) z of the bottom and top platens when clamped, m.
      node_force: (n, 3) total force on each node at the last step (membrane + spheres), N.
      sphere_force: (N, 3) force of the membrane on each sphere at the last step, N.
      platen_reaction: (2, 3) force on the bottom and top platens through the clamped rings (module
        docstring), N: the membrane's own pull plus the sphere contacts on the ring nodes.
      ring_contact_force: (2, 3) force of the spheres on the bottom and top ring nodes, N; the platens
        take it through the clamp, so it counts as force the spheres receive from the platens.
      feature_contact: with ``contact_model="faces"``, the feature contacts' slots and springs
        (:class:`~membrax.membrane.face_contact.FeatureContactState`; ``spring`` then stays zero); else None.
    """

    position: jnp.ndarray
    position_compensation: jnp.ndarray
    velocity: jnp.ndarray
    spring: jnp.ndarray
    candidates: NodeCandidates
    clamp_position: jnp.ndarray
    clamp_platen_height: jnp.ndarray
    node_force: jnp.ndarray
    sphere_force: jnp.ndarray
    platen_reaction: jnp.ndarray
    ring_contact_force: jnp.ndarray
    feature_contact: FeatureContactState | None = None


@pytree.dataclass
class CoupledState:
    """The DEM state and the membrane state; errors and the step count live in the DEM state."""

    dem: DEMState
    membrane: MembraneState

    @property
    def error(self):
        """int32 error bitmask (the bits of :class:`membrax.errors.ErrorCode`)."""
        return self.dem.error

    @property
    def step(self):
        """Number of steps taken."""
        return self.dem.step


def platen_heights(walls):
    """(z_bottom, z_top) of the platens of member 0, m (h of the bottom plane is −z, its normal −e_z)."""
    bottom = walls.position[0, BOTTOM] + walls.position_compensation[0, BOTTOM]
    top = walls.position[0, TOP] + walls.position_compensation[0, TOP]
    return jnp.stack([-bottom, top])


def _ring_vector_area(ring_position):
    """½ Σ_k y_k × y_{k+1} over a closed ring (n_θ, 3): the vector area of the polygon, m²."""
    here = ring_position.T
    after = jnp.roll(ring_position, -1, axis=0).T
    return 0.5 * jnp.stack(
        [
            jnp.sum(here[1] * after[2] - here[2] * after[1]),
            jnp.sum(here[2] * after[0] - here[0] * after[2]),
            jnp.sum(here[0] * after[1] - here[1] * after[0]),
        ]
    )


def platen_reaction(node_force, mesh: MembraneMesh, position=None, cell_pressure=0.0):
    """Forces the membrane's clamped end rings exert on the bottom and top platens, (2, 3), N.

    F_k is the force on node k from everything except its clamp (stretching, bending, the pressure load,
    which on the end rings includes the share of the cap that closes the volume over the platen face; add
    node–sphere contact forces if wanted). A clamped ring node is held by the clamp force −F_k, so it
    pushes its platen with +F_k, and (module docstring, Platen reactions)

        R_bottom = Σ_{k ∈ bottom ring} F_k − p A_b e_z,   R_top = Σ_{k ∈ top ring} F_k + p A_t e_z,

    A the ring's polygon area (½ Σ_k y_k × y_{k+1}): the second term removes the cell pressure p on the
    cap, which acts on the platen, not on the membrane (give ``position`` and ``cell_pressure``; with
    p = 0 the cap's share stays in). Sign: ``R_top[2] < 0`` pushes the top platen down, ``> 0`` pulls it
    up; likewise ``R_bottom[2] > 0`` pushes the bottom platen up. Example: a closed membrane under internal
    pressure p at its rest shape gives R_top = −R_bottom = p A e_z with p = 0 here, the thin-shell end load
    (for the faceted mesh A is the mean cross-section of the end layer, see the tests).

    Args:
      node_force: (n_nodes, 3) force on each node except the clamp, N.
      mesh: a band membrane.
      position: (n_nodes, 3) node positions, m (needed when ``cell_pressure`` is not 0).
      cell_pressure: p, Pa.

    Returns:
      (2, 3): the bottom and top platens' forces, N.
    """
    sign = (-1.0, 1.0)  # n_out = ∓e_z: A n_out = ∓ vector area
    reactions = []
    for k, ring in enumerate((mesh.bottom_ring, mesh.top_ring)):
        reaction = jnp.sum(node_force[ring], axis=0)
        if position is not None:
            reaction = reaction + sign[k] * cell_pressure * _ring_vector_area(position[ring])
        reactions.append(reaction)
    return jnp.stack(reactions)


def _contact_spheres(spheres: DEMState, particles: Particles) -> ContactSpheres:
    """The spheres of a DEM state as the node–sphere law reads them."""
    return ContactSpheres(
        position=spheres.position,
        velocity=spheres.velocity,
        angular_velocity=spheres.angular_velocity,
        radius=particles.radius,
    )


def contact_forces(state: CoupledState, particles: Particles, params: CoupledParams, dt, mesh=None):
    """The membrane–sphere contacts of a coupled state at its positions (step 1 of the module docstring).

    Returns the :class:`~membrax.membrane.contact.NodeSphereForces` (the springs advanced by one step),
    or for a state with feature contacts (``contact_model="faces"``; ``mesh`` needed) the
    :class:`~membrax.membrane.face_contact.FaceContactForces` on the slots the node table gives now, the
    carried springs moved onto them.
    """
    nodes = state.membrane
    if nodes.feature_contact is not None:
        if mesh is None:
            raise ValueError("contact_forces: a state with feature contacts needs the mesh (mesh=...).")
        slots = feature_slots(mesh, nodes.candidates.idx, particles.num_particles)
        return face_contact_forces(
            ContactNodes(position=nodes.position, velocity=nodes.velocity),
            _contact_spheres(state.dem, particles),
            mesh,
            slots,
            carry_springs(nodes.feature_contact, slots, particles.num_particles),
            dt,
            params.membrane.contact,
            params.membrane.contact_thickness,
        )
    return node_sphere_forces(
        ContactNodes(position=nodes.position, velocity=nodes.velocity),
        _contact_spheres(state.dem, particles),
        nodes.candidates.idx,
        nodes.spring,
        dt,
        params.membrane.contact,
        params.membrane.contact_thickness,
        sphere_slots=nodes.candidates.sphere_slots,
    )


def membrane_dem(
    particles: Particles,
    neighbor_frame: PairNeighborFn,
    mesh: MembraneMesh,
    dt: float,
    platen_area,
    latex_density: float = LATEX_DENSITY,
    stretching_model: str = "neo_hookean",
    wall_friction: bool = False,
    contact_model: str = "nodes",
    tangent_limit: float = math.inf,
) -> tuple[Callable, Callable]:
    """The coupled DEM + membrane simulation as ``(init_fn, step_fn)`` (see the module docstring).

    Args:
      particles: sphere properties (one specimen).
      neighbor_frame: the sphere neighbour-list factory.
      mesh: the membrane (:func:`membrax.membrane.mesh.prism_mesh` around the specimen at t_m/2).
      dt: time step, s (the smaller of the DEM's and
        :func:`membrax.membrane.stability.membrane_critical_time_step`'s, with a safety).
      platen_area: the platen area for the servo, m².
      latex_density: ρ of the membrane, kg/m³, for the lumped node masses.
      stretching_model: ``"neo_hookean"``, ``"gent"`` or ``"svk"``
        (:func:`membrax.membrane.energies.stretching_energy`). Under ``"gent"`` every
        :data:`LOCK_CHECK_EVERY`-th step also checks the closest approach to the lock
        (:func:`membrax.membrane.energies.locking_ratio`) and sets ``ErrorCode.MEMBRANE_LOCKED`` past
        :data:`membrax.defaults.GENT_LOCK_FRACTION`.
      wall_friction: the DEM's sphere–platen friction path (False: frictionless platens, the paper's).
      contact_model: ``"nodes"`` (the spheres meet the mesh's nodes) or ``"faces"`` (its faces, edges
        and nodes: :mod:`membrax.membrane.face_contact`), :data:`CONTACT_MODELS`.
      tangent_limit: r_max, the largest Gent tangent ratio k_t/k_0 that ``dt`` tolerates
        (:func:`membrax.membrane.stability.membrane_tangent_limit`; static). Under ``"gent"`` the same
        check sets ``ErrorCode.MEMBRANE_STIFFENED`` when the closest approach's ratio exceeds it
        (:func:`membrax.membrane.stability.stiffened_bit`); ``inf`` (the default) checks nothing.
    """
    if contact_model not in CONTACT_MODELS:
        raise ValueError(f"contact_model = {contact_model!r}; choose one of {CONTACT_MODELS}.")
    faces = contact_model == "faces"
    # The mesh's neighbours and interior nodes, which the feature contacts read: built once, not every step.
    neighbours = mesh_neighbours(mesh) if faces else None
    if particles.num_members != 1:
        raise ValueError(
            f"membrane_dem couples one specimen, got {particles.num_members} members; batch with vmap."
        )
    check_range("latex_density", latex_density, lower=0.0, lower_open=True, hint="kg/m³; latex ≈ 1000.")
    check_range("dt", dt, lower=0.0, lower_open=True, hint="seconds; see membrane_critical_time_step.")
    _, dem_step = sphere_dem(
        particles, neighbor_frame, dt, platen_area=platen_area, wall_friction=wall_friction
    )
    # Mass per unit thickness: lumped_mass is linear in t_m, which stays a traced parameter.
    mass_per_thickness = energies.lumped_mass(mesh, 1.0, latex_density)
    free = jnp.asarray(free_node_mask(mesh))
    # One specimen: every node reads member 0's walls.
    node_member = jnp.zeros(mesh.num_nodes, dtype=jnp.int32)
    rings = jnp.stack([mesh.bottom_ring, mesh.top_ring])  # (2, n_θ)
    # The rings are set with unique_indices (checked here unless the mesh is traced, as in a vmapped rollout).
    if not isinstance(rings, jax.core.Tracer) and np.unique(np.asarray(rings)).size != rings.size:
        raise ValueError("membrane_dem: the mesh's two rings repeat a node; build the mesh with prism_mesh.")

    def init_fn(
        dem_state: DEMState, params: CoupledParams, capacity: int = 3, skin=None, sphere_capacity: int = 64
    ) -> CoupledState:
        position = mesh.reference_position.astype(dem_state.position.dtype)
        thickness = params.membrane.contact_thickness
        if skin is None:
            skin = 0.2 * 2.0 * float(jnp.max(particles.radius))
        candidates = build_candidates(
            position,
            dem_state.position,
            particles.radius,
            thickness,
            skin,
            capacity,
            sphere_capacity,
            extra_reach=longest_edge(mesh) if faces else 0.0,
        )
        feature_contact = None
        if faces:
            slots = feature_slots(mesh, candidates.idx, particles.num_particles, neighbours)
            feature_contact = FeatureContactState(slots=slots, spring=zero_springs(slots, position.dtype))
        zeros = jnp.zeros_like(position)
        return CoupledState(
            dem=dem_state,
            membrane=MembraneState(
                position=position,
                position_compensation=zeros,
                velocity=zeros,
                spring=jnp.zeros((3, mesh.num_nodes, capacity), position.dtype),
                candidates=candidates,
                clamp_position=position[rings],
                clamp_platen_height=platen_heights(dem_state.walls),
                node_force=zeros,
                sphere_force=jnp.zeros_like(dem_state.position),
                platen_reaction=jnp.zeros((2, 3), position.dtype),
                ring_contact_force=jnp.zeros((2, 3), position.dtype),
                feature_contact=feature_contact,
            ),
        )

    def step_fn(state: CoupledState, params: CoupledParams) -> CoupledState:
        spheres, nodes = state.dem, state.membrane
        mp = params.membrane
        reference = None  # the absolute law
        if params.dem.damping.frame == "affine":  # static: the nodes damped as the spheres are
            reference = affine_velocity(nodes.position, spheres.walls, node_member)
        moving = MembraneNodes(
            position=nodes.position,
            position_compensation=nodes.position_compensation,
            velocity=nodes.velocity,
            mass=mp.thickness * mass_per_thickness,
            free=free,
            reference_velocity=reference,
        )
        feature_contact = nodes.feature_contact
        if not faces and native.enabled_for(nodes.position.dtype):  # steps 1, 2 and 4 in one rule
            (
                contact_node_force,
                sphere_force,
                sphere_torque,
                contact_spring,
                node_force,
                velocity,
                position,
                compensation,
            ) = node_step(
                moving,
                _contact_spheres(spheres, particles),
                nodes.candidates.idx,
                nodes.spring,
                dt,
                mp,
                params.dem.damping,
                mesh,
                model=stretching_model,
            )
        else:
            if faces:  # the slots of the current table, carried with their springs (see step 5)
                contact = face_contact_forces(
                    ContactNodes(position=nodes.position, velocity=nodes.velocity),
                    _contact_spheres(spheres, particles),
                    mesh,
                    feature_contact.slots,
                    feature_contact.spring,
                    dt,
                    mp.contact,
                    mp.contact_thickness,
                    neighbours,
                )
                feature_contact = FeatureContactState(slots=contact.slots, spring=contact.spring)
                contact_spring = nodes.spring  # the node slots' springs, unused
            else:
                contact = contact_forces(state, particles, params, dt, mesh)
                contact_spring = contact.spring
            contact_node_force, sphere_force = contact.node_force, contact.sphere_force
            sphere_torque = contact.sphere_torque
            internal = energies.nodal_forces(
                nodes.position,
                mesh,
                mp.modulus,
                mp.thickness,
                mp.cell_pressure,
                model=stretching_model,
                bending_factor=mp.bending_factor,
                locking_jm=mp.locking_jm,
            )
            node_force, velocity, position, compensation = advance_nodes(
                internal, contact_node_force, moving, dt, params.dem.damping
            )
        reaction = platen_reaction(node_force, mesh, nodes.position, mp.cell_pressure)
        # The ram holds the platen against the spheres and the membrane: the servo sees both.
        membrane_load = jnp.stack([-reaction[0, 2], reaction[1, 2]])[None, :]
        spheres = dem_step(spheres, params.dem, sphere_force, sphere_torque, wall_load=membrane_load)

        # Clamped rings ride on their platens (rigid vertical motion).
        platen_z = platen_heights(spheres.walls)
        shift = platen_z - nodes.clamp_platen_height  # (2,)
        clamped = (
            nodes.clamp_position
            + jnp.stack([jnp.zeros_like(shift), jnp.zeros_like(shift), shift]).T[:, None, :]
        )
        # The rings' nodes are distinct: unique_indices gives the set a plain scatter as its derivative,
        # not JAX's id-masked one for repeated indices (three full-mesh selects per step).
        position = position.at[rings].set(clamped, unique_indices=True)
        compensation = compensation.at[rings].set(0.0, unique_indices=True)
        platen_velocity = jnp.stack([-spheres.walls.velocity[0, BOTTOM], spheres.walls.velocity[0, TOP]])
        ring_velocity = jnp.broadcast_to(
            jnp.stack([jnp.zeros_like(platen_velocity), jnp.zeros_like(platen_velocity), platen_velocity]).T[
                :, None, :
            ],
            clamped.shape,
        )
        velocity = velocity.at[rings].set(ring_velocity, unique_indices=True)

        candidates, spring, rebuilt = update_candidates(
            nodes.candidates,
            contact_spring,
            position,
            spheres.position,
            particles.radius,
            mp.contact_thickness,
            with_rebuilt=True,
        )
        if faces:  # the feature slots change with the node table only: rebuilt with it, springs carried by id
            feature_contact = jax.lax.cond(
                rebuilt,
                lambda fc: refresh_feature_contact(
                    fc, mesh, candidates.idx, particles.num_particles, neighbours
                ),
                lambda fc: fc,
                feature_contact,
            )
        error = spheres.error | candidate_errors(candidates) | not_finite_bit(position, velocity)
        if stretching_model == "gent":  # static: the other laws have no lock
            check = state.dem.step % LOCK_CHECK_EVERY == 0
            error = error | jax.lax.cond(
                check,
                lambda: gent_bits(nodes.position, mesh, mp.locking_jm, tangent_limit),
                lambda: jnp.int32(0),
            )
        return CoupledState(
            dem=spheres.set(error=error.astype(jnp.int32)),
            membrane=nodes.set(
                position=position,
                position_compensation=compensation,
                velocity=velocity,
                spring=spring,
                candidates=candidates,
                node_force=node_force,
                sphere_force=sphere_force,
                platen_reaction=reaction,
                ring_contact_force=jnp.stack(
                    [jnp.sum(contact_node_force[ring], axis=0) for ring in (mesh.bottom_ring, mesh.top_ring)]
                ),
                feature_contact=feature_contact,
            ),
        )

    return init_fn, step_fn


def grow_candidates(
    state: CoupledState,
    particles: Particles,
    capacities,
    thickness,
    mesh: MembraneMesh | None = None,
    grid=None,
    extra_reach: float | None = None,
) -> CoupledState:
    """A copy of ``state`` with a node candidate table of the given capacities, springs carried by sphere id.

    Used by the chunk driver after ``ErrorCode.MEMBRANE_CANDIDATE_OVERFLOW``, and by the batched executor
    (one table for all its members, :func:`membrax.executor.build_batch`; a resumed batch's tables fitted
    again, :func:`~membrax.membrane.candidates.fitted_candidate_capacities`). The capacities may be smaller
    than the table's.

    Args:
      state: the state to change (its table is rebuilt at its positions, on the same grid).
      particles: sphere properties.
      capacities: the new :class:`~membrax.membrane.candidates.CandidateCapacities` (e.g.
        :func:`~membrax.membrane.candidates.grown_candidate_capacities`).
      thickness: the contact's thickness f t_m (:attr:`MembraneParams.contact_thickness`), m.
      mesh: the membrane (its topology: any member's mesh of a batch), needed for a state with feature
        contacts, whose slots are rebuilt from the new table (:func:`refresh_feature_contact`).
      grid: the cell list's grid (default: the table's own); its ``cell_capacity`` is replaced by C.
      extra_reach: the reach added to every sphere's, m (default: the table's own).
    """
    nodes = state.membrane
    old = nodes.candidates
    capacities = CandidateCapacities(*capacities)
    grid = old.grid if grid is None else grid
    new = build_candidates(
        nodes.position,
        state.dem.position,
        particles.radius,
        thickness,
        old.skin,
        capacities.capacity,
        capacities.sphere_capacity,
        grid=grid._replace(cell_capacity=capacities.cell_capacity),
        extra_reach=old.extra_reach if extra_reach is None else extra_reach,
    )
    spring = remap_node_history(
        old.idx, new.idx, nodes.spring, particles.num_particles, components_first=True
    )
    feature_contact = nodes.feature_contact
    if feature_contact is not None:
        if mesh is None:
            raise ValueError("grow_candidates: a state with feature contacts needs the mesh (mesh=...).")
        # Padded to the new width first; a narrower table's springs are carried onto its slots by id.
        if capacities.capacity >= old.capacity:
            feature_contact = widen(feature_contact, capacities.capacity, particles.num_particles)
        feature_contact = refresh_feature_contact(feature_contact, mesh, new.idx, particles.num_particles)
    return state.set(membrane=nodes.set(candidates=new, spring=spring, feature_contact=feature_contact))


def refresh_feature_contact(
    feature_contact: FeatureContactState, mesh: MembraneMesh, candidates, num_spheres: int, neighbours=None
) -> FeatureContactState:
    """The feature slots of the node table ``candidates`` (n_nodes, K), the springs carried onto them by id.

    The slots are a function of the node table alone (:func:`membrax.membrane.face_contact.feature_slots`),
    so a state keeps those of its current table: the step rebuilds them when it rebuilds the table,
    :func:`grow_candidates` when it grows it (:func:`membrax.membrane.face_contact.carry_springs`).
    """
    slots = feature_slots(mesh, candidates, num_spheres, neighbours)
    return FeatureContactState(slots=slots, spring=carry_springs(feature_contact, slots, num_spheres))
