"""DEM time integration: state, forces, damping and the leapfrog step.

Contract. ``sphere_dem(particles, neighbor_frame, dt)`` returns a pair of pure functions
``(init_fn, step_fn)`` in the jax-md style:

- ``init_fn(position, walls, neighbors, ...) -> DEMState`` (host side: it takes an allocated list);
- ``step_fn(state, params) -> DEMState`` advances one time step under ``jit``; ``params``
  (:class:`DEMParams`: contact law and damping) is a traced argument, so it can be differentiated and
  ``vmap``-ed over without recompiling.

One step (explicit central differences / leapfrog, velocities at half steps):

1. update the neighbour list at x_n; if it was rebuilt, remap the contact history (by partner id);
2. contact forces and torques at x_n from the velocities v_{n−1/2} (Cundall–Strack,
   :mod:`membrax.spheres.contact`),
   plus wall contacts and any external force;
3. damping (below);
4. v_{n+1/2} = v_{n−1/2} + Δt F/m,  ω_{n+1/2} = ω_{n−1/2} + Δt T/I  (I = 2/5 m R² for a solid sphere);
5. x_{n+1} = x_n + Δt v_{n+1/2}; walls move and servo walls get new velocities.

Spheres need no orientation, so none is integrated.

Damping (``DampingParams``), on the velocity u = v − v_ref relative to a reference field v_ref:

- local non-viscous (Cundall 1987): F_i ← F_i − α |F_i| sign(u_i) per component, the same for torques
  (on ω: the reference field does not rotate); α = 0.3 in the paper. It removes energy at a rate
  independent of velocity magnitude, ideal for quasi-static tests, but sign(u) is discontinuous:
  **gradients through it are meaningless** (autodiff and finite differences disagree and the latter do
  not converge).
- viscous: F ← F − γ m u, T ← T − γ I ω, γ in 1/s. Smooth: **use this mode (with α = 0) for jax.grad**.
- the frame (``DampingParams.frame``): ``"affine"`` (the default, :data:`membrax.defaults.DAMPING_FRAME`)
  damps the motion relative to the strain-controlled walls' affine field: between platens closing at an
  imposed rate, v_ref = (0, 0, v_b + (v_t − v_b) s), s = clip((z − z_b)/(z_t − z_b), 0, 1)
  (:func:`membrax.spheres.walls.affine_velocity`; servo-held walls count as at rest), as periodic codes
  damp the velocity relative to the cell's homogeneous deformation (YADE's ``NewtonIntegrator`` in a
  periodic cell); ``"absolute"`` damps v itself (v_ref = 0; the paper's and PFC's wall-bounded practice).
  With the walls at rest or servo-held (consolidation) the two are the same law, bit for bit. Why the
  default: a sphere carried by the closing platens moves with them, so absolute damping drags it against
  the motion, −α|F| sign(v_affine), and the platens carry the drag: at paper size, 10 kPa, I = 1e-3, both
  platens closing, their stress ran 1.8 % above the Love–Weber stress, 0.6 % with the affine frame
  (:data:`membrax.defaults.DAMPING_FRAME`), a load a membrane calibration learning from the ram would take
  for the membrane's.

Errors ride in ``state.error`` as a bitmask of :class:`membrax.errors.ErrorCode` (neighbour overflow, not
finite, outside the box), set inside jit and checked on the host between chunks by the driver.

The time step's stability limit is :mod:`membrax.spheres.stability`'s.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native, pytree
from membrax.compensated import compensated_add
from membrax.defaults import DAMPING_FRAME, DAMPING_FRAMES
from membrax.errors import ErrorCode, describe, not_finite_bit
from membrax.spheres import _kernels, contact
from membrax.spheres.contact import ContactParams, PairSpheres, for_members, slot_law, slot_spheres
from membrax.spheres.neighbors import PairNeighborFn, outside_box, remap_pair_history_if
from membrax.spheres.particles import moment_of_inertia, particle_mass
from membrax.spheres.walls import (
    WallState,
    advance_walls,
    affine_velocity,
    ramped_velocity,
    servo_control,
)
from membrax.vector import safe_norm, select

__all__ = [
    "DAMPING_FRAME",
    "DAMPING_FRAMES",
    "ERROR_NEIGHBOR_OVERFLOW",
    "ERROR_NOT_FINITE",
    "ERROR_OUTSIDE_BOX",
    "DEMParams",
    "DEMState",
    "DampingParams",
    "Forces",
    "Particles",
    "apply_damping",
    "damped_velocities",
    "compute_forces",
    "describe_errors",
    "make_particles",
]

# Aliases of membrax.errors.ErrorCode's bits, kept for code written against this module.
ERROR_NEIGHBOR_OVERFLOW = ErrorCode.NEIGHBOR_OVERFLOW
ERROR_NOT_FINITE = ErrorCode.NOT_FINITE
ERROR_OUTSIDE_BOX = ErrorCode.OUTSIDE_BOX


#: Alias of :func:`membrax.errors.describe`.
describe_errors = describe


@pytree.dataclass
class Particles:
    """Fixed properties of the spheres (SI).

    Attributes:
      radius: (N,) m.
      mass: (N,) kg.
      inertia: (N,) moment of inertia, kg·m².
      member: (N,) int32 batch member of each particle (all 0 for one specimen).
      num_members: B (static).
    """

    radius: jnp.ndarray
    mass: jnp.ndarray
    inertia: jnp.ndarray
    member: jnp.ndarray
    num_members: int = pytree.static_field()

    @property
    def num_particles(self) -> int:
        """N."""
        return self.radius.shape[0]


def make_particles(radius, density, member=None, num_members: int = 1) -> Particles:
    """Solid spheres: m = 4/3 π R³ ρ, I = 2/5 m R².

    Args:
      radius: (N,) radii, m.
      density: kg/m³ (scalar).
      member: (N,) batch member ids (default all 0).
      num_members: B.
    """
    radius = jnp.asarray(radius)
    mass = particle_mass(radius, density)
    member = jnp.zeros(radius.shape, dtype=jnp.int32) if member is None else jnp.asarray(member, jnp.int32)
    return Particles(
        radius=radius,
        mass=mass,
        inertia=moment_of_inertia(mass, radius),
        member=member,
        num_members=num_members,
    )


@pytree.dataclass
class DampingParams:
    """Damping (see the module docstring).

    Attributes:
      local_coefficient: α of Cundall's local non-viscous damping (paper 0.3); 0 to disable.
      viscous_rate: γ of mass-proportional viscous damping, 1/s; 0 to disable.
      frame: the velocities damped (static: part of the tree's structure): ``"affine"``, relative to the
        strain-controlled walls' affine field, or ``"absolute"`` (module docstring; :data:`DAMPING_FRAMES`).
    """

    local_coefficient: jnp.ndarray
    viscous_rate: jnp.ndarray
    frame: str = pytree.static_field(default=DAMPING_FRAME)

    def __post_init__(self):
        if self.frame not in DAMPING_FRAMES:
            raise ValueError(f"DampingParams.frame = {self.frame!r}; it must be one of {DAMPING_FRAMES}.")

    @staticmethod
    def local(coefficient: float = 0.3, frame: str = DAMPING_FRAME) -> DampingParams:
        """Cundall local damping only (the paper's 0.3)."""
        return DampingParams(
            local_coefficient=jnp.asarray(coefficient), viscous_rate=jnp.asarray(0.0), frame=frame
        )

    @staticmethod
    def viscous(rate: float, frame: str = DAMPING_FRAME) -> DampingParams:
        """Smooth viscous damping only (differentiable)."""
        return DampingParams(local_coefficient=jnp.asarray(0.0), viscous_rate=jnp.asarray(rate), frame=frame)

    @staticmethod
    def equivalent_viscous(
        stiffness: float, mass: float, coefficient: float = 0.3, frame: str = DAMPING_FRAME
    ) -> DampingParams:
        """Viscous damping that removes, per cycle of one contact oscillator, what local damping α does.

        A linear oscillator (k, m) of amplitude A loses 2αkA² per cycle to local damping (α k|x| against
        the motion over four quarter cycles) and 4πζ·½kA² to viscous damping of ratio ζ, so ζ = α/π
        (derived here by equal energy loss) and γ = 2ζω = 2αω/π with ω = √(k/m): for the paper's α = 0.3,
        k_n = 1e7 N/m and a 25 mm granite sphere, γ ≈ 4.1e3 1/s (ζ ≈ 0.095 at the contact frequency; the
        slower collective modes are damped more, ζ = γ/2ω).

        Args:
          stiffness: k_n, N/m.
          mass: a sphere's mass, kg.
          coefficient: the local damping α it replaces.
          frame: the velocities damped (``"affine"`` or ``"absolute"``).
        """
        rate = 2.0 * coefficient * np.sqrt(stiffness / mass) / np.pi
        return DampingParams.viscous(float(rate), frame)

    @staticmethod
    def none() -> DampingParams:
        """No damping (energy-conserving tests)."""
        return DampingParams(local_coefficient=jnp.asarray(0.0), viscous_rate=jnp.asarray(0.0))


@pytree.dataclass
class DEMParams:
    """The traced parameters of a step: contact law and damping. Fields may be arrays over batch members."""

    contact: ContactParams
    damping: DampingParams


@pytree.dataclass
class DEMState:
    """Everything that evolves.

    Attributes:
      position: (N, 3) centres x_n, m.
      position_compensation: (N, 3) low-order part of x_n (compensated summation: a quasi-static sphere
        moves ~1e-9 m per step, below float32 resolution at 0.1 m). Branch vectors and wall gaps use it.
      velocity: (N, 3) v_{n−1/2}, m/s.
      angular_velocity: (N, 3) ω_{n−1/2}, rad/s.
      external_force: (N, 3) applied body force (gravity, tests), N.
      pair_spring: (C, 3) tangential spring of each pair slot of ``neighbors`` (force on the higher id).
      wall_spring: (N, W, 3) tangential spring of each sphere–wall contact (force on the sphere).
      walls: the :class:`~membrax.spheres.walls.WallState`.
      neighbors: the jax-md neighbour list.
      step: number of steps taken.
      error: int32 bitmask of :class:`membrax.errors.ErrorCode` bits.
    """

    position: jnp.ndarray
    position_compensation: jnp.ndarray
    velocity: jnp.ndarray
    angular_velocity: jnp.ndarray
    external_force: jnp.ndarray
    pair_spring: jnp.ndarray
    wall_spring: jnp.ndarray
    walls: WallState
    neighbors: object
    step: jnp.ndarray
    error: jnp.ndarray


@pytree.dataclass
class Forces:
    """Output of :func:`compute_forces` (contact forces at x_n)."""

    force: jnp.ndarray  # (N, 3) total force on each sphere (contacts + external)
    torque: jnp.ndarray  # (N, 3)
    pair_spring: jnp.ndarray  # (C, 3) updated springs
    wall_spring: jnp.ndarray  # (N, W, 3)
    pair_force: jnp.ndarray  # (C, 3) force on j (the higher id) from i; zero for padded/open slots
    pair_branch: jnp.ndarray  # (C, 3) x_j − x_i
    pair_normal_force: jnp.ndarray  # (C,) >= 0 when in contact, 0 otherwise
    wall_force: jnp.ndarray  # (N, W, 3) force of each wall on each sphere
    wall_arm: jnp.ndarray  # (N, W, 3) sphere centre → contact point
    wall_normal_force: jnp.ndarray  # (N, W) >= 0
    wall_total_force: jnp.ndarray  # (B, W) normal force of the particles on each wall
    wall_contacts: jnp.ndarray  # (B, W) int number of spheres touching each wall


def _along(position_t, wall_normal):
    """x·e for every sphere (positions (3, N)) and wall (normals (W, 3)): (N, W)."""
    return (
        position_t[0][:, None] * wall_normal[None, :, 0]
        + position_t[1][:, None] * wall_normal[None, :, 1]
        + position_t[2][:, None] * wall_normal[None, :, 2]
    )


def _wall_gap(position_t, compensation_t, wall_position, wall_compensation, wall_normal):
    """Gaps d = h − x·e (N, W), high and low parts subtracted separately so no motion is rounded away."""
    return (wall_position - _along(position_t, wall_normal)) + (
        wall_compensation - _along(compensation_t, wall_normal)
    )


def _pair_branch(position, compensation, gi, gj):
    """The branch x_j − x_i of each pair slot, (3, C), position compensation included."""
    # Gathering rows of one packed array is ~10× faster on XLA-CPU than gathering columns of (3, N).
    # x_j − x_i of nearby spheres is exact in floating point (Sterbenz), then the low parts are added.
    packed = jnp.concatenate([position, compensation], axis=1)
    rows_i, rows_j = packed[gi].T, packed[gj].T
    return (rows_j[0:3] - rows_i[0:3]) + (rows_j[3:6] - rows_i[3:6])


# The sphere–sphere contacts of a neighbour list summed per sphere: the JAX definition and its binding to
# the compiled kernel and its reverse-mode rule (membrax.spheres._kernels), all on (spheres, idx, spring,
# law, dt) (compute_forces' pair part).


def _pair_totals_reference(spheres: PairSpheres, idx, spring, law: ContactParams, dt):
    """The sphere–sphere contacts of a neighbour list, summed per sphere (the JAX definition).

    Returns (totals (N, 6): force and torque on each sphere; new springs (C, 3); force on j per slot
    (C, 3)), padded slots (i = N) zeroed. j receives (F, T_j), i receives (−F, T_i).
    """
    n = spheres.radius.shape[0]
    i, j = idx[0], idx[1]
    valid, gi, gj = slot_spheres(spheres, idx)
    normal_stiffness, tangential_stiffness, friction_coefficient = slot_law(law, spheres.member[gi])
    # Gather whole rows of one packed (N, 12) array, then transpose: XLA's CPU gather is ~10× faster on
    # contiguous rows than on the columns of (3, N) arrays (measured at N = 1816, C = 11865).
    packed = jnp.concatenate(
        [spheres.position, spheres.position_compensation, spheres.velocity, spheres.angular_velocity], axis=1
    )
    rows_i = packed[gi].T
    rows_j = packed[gj].T
    # x_j − x_i of nearby spheres is exact in floating point (Sterbenz), then the low parts are added.
    branch = (rows_j[0:3] - rows_i[0:3]) + (rows_j[3:6] - rows_i[3:6])
    pairs = contact.pair_contact(
        branch,
        rows_i[6:9],
        rows_j[6:9],
        rows_i[9:12],
        rows_j[9:12],
        spheres.radius[gi],
        spheres.radius[gj],
        spring.T,
        dt,
        normal_stiffness,
        tangential_stiffness,
        friction_coefficient,
    )
    totals, pair_force = contact.pair_totals(pairs, valid, i, j, n)
    return totals, select(valid, pairs.spring).T, pair_force.T


_compiled_pair_totals = native.with_reference(
    _kernels.pair_totals_kernel, _pair_totals_reference, _kernels.pair_totals_backward
)


def compute_forces(
    state: DEMState, particles: Particles, params: DEMParams, dt, wall_friction: bool = True
) -> Forces:
    """Contact forces, torques and updated springs at the current positions (step 2 of the module docstring).

    ``state.neighbors`` must be current for ``state.position``. ``wall_friction=False`` (static) takes
    the frictionless wall path, exact when every wall friction coefficient is 0 (the paper's platens):
    F = −∂/∂x Σ ½ k_n max(δ, 0)² over the dense (N, W) sphere–wall table, no spring and no torque.
    Internally vectors are component-first (:mod:`membrax.vector`); the outputs are (N, 3) / (C, 3).
    """
    n = particles.num_particles
    spheres = PairSpheres(
        position=state.position,
        position_compensation=state.position_compensation,
        velocity=state.velocity,
        angular_velocity=state.angular_velocity,
        radius=particles.radius,
        member=particles.member,
    )
    # Padded slots point at particle n; clamp the gather and mask the result.
    valid, gi, gj = slot_spheres(spheres, state.neighbors.idx)
    law = params.contact
    pair_stiffness = for_members(law.normal_stiffness, particles.member[gi])
    pair_args = (spheres, state.neighbors.idx, state.pair_spring, law, dt)
    if native.enabled_for(state.position.dtype):
        totals, pair_spring, pair_force = _compiled_pair_totals(*pair_args)
    else:
        totals, pair_spring, pair_force = _pair_totals_reference(*pair_args)
    force_t, torque_t = totals.T[:3], totals.T[3:]
    # The pairs' geometry for the measurements (XLA drops it where no one uses it).
    branch = _pair_branch(state.position, state.position_compensation, gi, gj)
    pair_distance = safe_norm(branch)
    pair_overlap = particles.radius[gi] + particles.radius[gj] - pair_distance
    pair_normal_force = jnp.where(
        valid & (pair_distance > 0.0), pair_stiffness * jnp.maximum(pair_overlap, 0.0), 0.0
    )
    position_t = state.position.T
    compensation_t = state.position_compensation.T
    velocity_t = state.velocity.T
    angular_t = state.angular_velocity.T

    walls = state.walls
    pm = particles.member
    wall_position = walls.position[pm]  # (N, W)
    wall_normal = walls.normal  # (W, 3)
    wall_compensation = walls.position_compensation[pm]
    wall_kn = for_members(law.wall_normal_stiffness, pm)
    wall_kn = jnp.broadcast_to(wall_kn, (n,)) if wall_kn.ndim == 0 else wall_kn
    if wall_friction:
        shape = wall_position.shape

        def tile(vector_t):  # (3, N) -> (3, N, W)
            return jnp.broadcast_to(vector_t[:, :, None], (3, *shape))

        def per_particle(value):
            value = jnp.asarray(value)
            return value[:, None] if value.ndim else value

        out = contact.wall_contact(
            _wall_gap(position_t, compensation_t, wall_position, wall_compensation, wall_normal),
            tile(velocity_t),
            tile(angular_t),
            particles.radius[:, None],
            jnp.broadcast_to(wall_normal.T[:, None, :], (3, *shape)),
            walls.velocity[pm],
            jnp.moveaxis(state.wall_spring, 2, 0),
            dt,
            wall_kn[:, None],
            per_particle(for_members(law.wall_tangential_stiffness, pm)),
            per_particle(for_members(law.wall_friction_coefficient, pm)),
        )
        wall_force_t = out.force  # (3, N, W)
        force_t = force_t + jnp.sum(wall_force_t, axis=2)
        torque_t = torque_t + jnp.sum(out.torque, axis=2)
        wall_spring = jnp.moveaxis(out.spring, 0, 2)
        overlap = out.overlap
        wall_normal_force = out.normal_force
        wall_arm = jnp.moveaxis(out.arm, 0, 2)
    else:
        gaps = _wall_gap(position_t, compensation_t, wall_position, wall_compensation, wall_normal)

        def energy(gaps_):
            return jnp.sum(contact.normal_energy(particles.radius[:, None] - gaps_, wall_kn[:, None]))

        # F = −∂U/∂x = Σ_w (∂U/∂d_w) e_w, as d_w = h_w − x·e_w: jax.grad over the gaps, then the chain rule
        # by hand. jax.grad over x gave XLA a transpose whose three padded rows it fused into the spheres'
        # update, each evaluating every wall's term again (54 µs a step at paper size).
        by_gap = jax.grad(energy)(gaps)  # (N, W)
        force_t = force_t + jnp.stack(
            [sum(by_gap[:, w] * wall_normal[w, c] for w in range(wall_normal.shape[0])) for c in range(3)]
        )
        overlap = particles.radius[:, None] - gaps
        wall_normal_force = wall_kn[:, None] * jnp.maximum(overlap, 0.0)
        wall_force_t = -wall_normal_force[None] * wall_normal.T[:, None, :]
        wall_spring = jnp.zeros_like(state.wall_spring)
        wall_arm = (particles.radius[:, None] - 0.5 * overlap)[:, :, None] * wall_normal[None, :, :]
    return Forces(
        force=force_t.T + state.external_force,
        torque=torque_t.T,
        pair_spring=pair_spring,
        wall_spring=wall_spring,
        pair_force=pair_force,
        pair_branch=select(valid, branch).T,
        pair_normal_force=pair_normal_force,
        wall_force=jnp.moveaxis(wall_force_t, 0, 2),
        wall_arm=wall_arm,
        wall_normal_force=wall_normal_force,
        wall_total_force=jax.ops.segment_sum(wall_normal_force, pm, num_segments=particles.num_members),
        wall_contacts=jax.ops.segment_sum(
            (overlap > 0.0).astype(jnp.int32), pm, num_segments=particles.num_members
        ),
    )


def apply_damping(force, velocity, mass, damping: DampingParams, member, reference_velocity=None):
    """Damped force (or torque with inertia for ``mass``): local then viscous (module docstring).

    F − α |F| sign(v − v_ref) − γ m (v − v_ref), per component (Cundall 1987's local damping, here of the
    velocity relative to a reference field v_ref, as a periodic cell damps the fluctuation about its
    homogeneous deformation); α and γ per batch member. ``damping.frame`` is not read here: the caller
    passes v_ref (the step, :func:`membrax.spheres.walls.affine_velocity` for ``"affine"``).

    Args:
      force: (N, 3) force (or torque), N (N·m).
      velocity: (N, 3) velocity (or angular velocity), m/s (rad/s).
      mass: (N,) mass (or moment of inertia), kg (kg·m²).
      damping: α and γ, scalars or one value per member.
      member: (N,) int32 batch member of each row.
      reference_velocity: (N, 3) v_ref, m/s; None for 0 (the absolute law, the same bits).
    """
    alpha = for_members(damping.local_coefficient, member)
    gamma = for_members(damping.viscous_rate, member)
    alpha = alpha[:, None] if alpha.ndim else alpha
    gamma = gamma[:, None] if gamma.ndim else gamma
    relative = velocity if reference_velocity is None else velocity - reference_velocity
    return force - alpha * jnp.abs(force) * jnp.sign(relative) - gamma * mass[:, None] * relative


def damped_velocities(
    state, forces, particles: Particles, damping: DampingParams, dt, reference_velocity=None
):
    """The velocities after one step of the damped force and torque (semi-implicit Euler, module docstring).

    Args:
      state: the step's state (its ``velocity`` and ``angular_velocity``).
      forces: the step's ``force`` and ``torque`` on each sphere.
      particles: masses, moments of inertia and batch members.
      damping: :func:`apply_damping`'s α and γ.
      dt: time step, s.
      reference_velocity: the force's damping frame, v_ref (:func:`apply_damping`); the torque's is absolute.

    Returns:
      (velocity, angular_velocity), (N, 3) each.
    """
    force = apply_damping(
        forces.force, state.velocity, particles.mass, damping, particles.member, reference_velocity
    )
    torque = apply_damping(
        forces.torque, state.angular_velocity, particles.inertia, damping, particles.member
    )
    velocity = state.velocity + dt * force / particles.mass[:, None]
    angular_velocity = state.angular_velocity + dt * torque / particles.inertia[:, None]
    return velocity, angular_velocity


def sphere_dem(
    particles: Particles,
    neighbor_frame: PairNeighborFn,
    dt: float,
    platen_area=None,
    wall_friction: bool = True,
) -> tuple[Callable, Callable]:
    """The DEM simulation as a pair ``(init_fn, step_fn)`` (see the module docstring).

    Args:
      particles: sphere properties.
      neighbor_frame: the neighbour-list factory (:func:`membrax.spheres.neighbors.pair_neighbor_fn`).
      dt: time step, s (see :func:`critical_time_step`).
      platen_area: platen area for the servo when there are no lateral walls (m², scalar or (B,)).
      wall_friction: False skips the tangential springs of sphere–wall contacts (static; exact when
        every wall friction coefficient is 0, as for the paper's platens, and ~5× cheaper for the walls).
    """
    n = particles.num_particles

    def init_fn(
        position, walls: WallState, neighbors, velocity=None, angular_velocity=None, external_force=None
    ):
        zeros = jnp.zeros_like(position)
        return DEMState(
            position=position,
            position_compensation=zeros,
            velocity=zeros if velocity is None else velocity,
            angular_velocity=zeros if angular_velocity is None else angular_velocity,
            external_force=zeros if external_force is None else external_force,
            pair_spring=jnp.zeros((neighbors.idx.shape[1], 3), dtype=position.dtype),
            wall_spring=jnp.zeros((n, walls.num_walls, 3), dtype=position.dtype),
            walls=walls,
            neighbors=neighbors,
            step=jnp.asarray(0, dtype=jnp.int32),
            error=jnp.asarray(0, dtype=jnp.int32),
        )

    def step_fn(
        state: DEMState,
        params: DEMParams,
        sphere_force=None,
        sphere_torque=None,
        wall_load=None,
        contact_radius=None,
    ) -> DEMState:
        """One step; ``sphere_force``/``sphere_torque`` (N, 3) are extra loads at x_n (e.g. the membrane).

        ``wall_load`` (B, W), N, compression positive: extra normal loads on the walls besides the spheres'
        (the membrane's pull on the platens); the servos then hold the total, the ram force, at target.
        ``contact_radius`` (N,), m: radii the contacts use in place of the particles' (the growing radii of
        a compaction by radius expansion, :mod:`membrax.spheres.compaction`); masses stay the particles'.
        """
        neighbors = neighbor_frame.update(state.position, state.neighbors)
        # Flat: XLA-CPU runs the comparison over (N, 3) rows ~10× slower (membrax.compensated).
        moved = neighbors.reference_position.reshape(-1) != state.neighbors.reference_position.reshape(-1)
        rebuilt = jnp.any(moved)
        pair_spring = remap_pair_history_if(rebuilt, state.neighbors.idx, neighbors.idx, state.pair_spring, n)
        state = state.set(neighbors=neighbors, pair_spring=pair_spring)
        touching = particles if contact_radius is None else particles.set(radius=contact_radius)
        forces = compute_forces(state, touching, params, dt, wall_friction)
        if sphere_force is not None:
            forces = forces.set(force=forces.force + sphere_force)
        if sphere_torque is not None:
            forces = forces.set(torque=forces.torque + sphere_torque)
        # The walls' affine field (a static choice): spheres carried by closing platens are not dragged.
        reference = None
        if params.damping.frame == "affine":
            reference = affine_velocity(state.position, state.walls, particles.member)
        velocity, angular_velocity = damped_velocities(
            state, forces, particles, params.damping, dt, reference
        )
        position, compensation = compensated_add(state.position, state.position_compensation, dt * velocity)

        wall_force = forces.wall_total_force if wall_load is None else forces.wall_total_force + wall_load
        walls = state.walls.set(force=wall_force, contacts=forces.wall_contacts)
        walls = advance_walls(walls, dt)
        # Without lateral walls the platen area must come from outside; with none given, no servo runs.
        if walls.num_lateral > 0 or platen_area is not None:
            walls = servo_control(walls, dt, params.contact.wall_normal_stiffness, platen_area=platen_area)
        else:
            walls = walls.set(velocity=ramped_velocity(walls, dt))

        error = state.error
        error = error | jnp.where(neighbors.did_buffer_overflow > 0, ErrorCode.NEIGHBOR_OVERFLOW, 0)
        error = error | not_finite_bit(position, velocity)
        error = error | jnp.where(outside_box(position, neighbor_frame), ErrorCode.OUTSIDE_BOX, 0)
        return state.set(
            position=position,
            position_compensation=compensation,
            velocity=velocity,
            angular_velocity=angular_velocity,
            pair_spring=forces.pair_spring,
            wall_spring=forces.wall_spring,
            walls=walls,
            step=state.step + 1,
            error=error.astype(jnp.int32),
        )

    return init_fn, step_fn
