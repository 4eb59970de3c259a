"""The triaxial element test in a periodic cell: spheres with no boundary, the box servo-controlled.

Contract. :func:`periodic_cell` returns a pair of pure functions ``(init_fn, step_fn)`` in the jax-md
style for spheres in an orthorhombic periodic cell whose box lengths L = (Lx, Ly, Lz) change in time
(a homogeneous strain rate ε̇ = L̇/L per axis, extension positive; z is the axial axis):

- ``init_fn(fraction, length, neighbors, control) -> PeriodicState`` (host side: an allocated list);
- ``step_fn(state, params) -> PeriodicState`` under ``jit`` and ``vmap`` (``params``: a
  :class:`membrax.spheres.integrate.DEMParams`, traced).

:func:`periodic_test` builds one cell ready to run, a :class:`PeriodicTest`: a
:class:`membrax.triaxial.protocol.StagedTest` like the rigid-wall and membrane cells, whose stages run in
compiled chunks through the chunk driver (:mod:`membrax.driver`) and return the state and
:class:`CellRecords`:

1. :meth:`PeriodicTest.consolidate`: every axis servo-held to σc until the unbalanced-force ratio is below
   a tolerance and each normal stress within ``stress_tolerance`` of σc;
2. :meth:`PeriodicTest.shear`: drained compression, the z axis shortened at a constant ε̇ from the
   inertial number I = ε̇ d √(ρ/σc) (GDR MiDi 2004), x and y servo-held at σc, to a target axial strain,
   recorded at two rates as the other cells (:meth:`PeriodicTest.shear_plan`).

:mod:`membrax.triaxial.periodic_packing` makes random packings in the cell as the mould's compaction does
(:mod:`membrax.spheres.compaction`) without its walls.

One step (leapfrog, velocities at half steps; the spheres' velocities are the fluctuations u about the
box's affine field v = u + ε̇ ⊙ (x − c), positions fractional, x = L ⊙ s):

1. update the neighbour list at (s_n, L_n) (:class:`membrax.spheres.neighbors.PeriodicNeighborFn`); if
   it was rebuilt, carry the tangential springs over by partner id (``remap_pair_history``);
2. contact forces at x_n with the minimum-image branches, the relative velocity of each image
   u_j − u_i + ε̇ ⊙ d (:func:`membrax.spheres.periodic.periodic_pair_forces`, Cundall–Strack);
3. the Love–Weber stress σ_n and the box servo (:func:`servo_strain_rate`) give ε̇_{n+1/2};
4. damping of u (local and viscous, :func:`membrax.spheres.integrate.apply_damping`): u is the velocity
   relative to the affine field, which is what the wall cell's ``"affine"`` frame damps (YADE damps the
   same in a periodic cell); ``DampingParams.frame`` is not read here;
5. u_{n+1/2} = u_{n−1/2} + Δt F/m, ω likewise; L_{n+1} = L_n (1 + ε̇_{n+1/2} Δt);
   s_{n+1} = s_n + Δt u_{n+1/2} / L_{n+1}, wrapped into [0, 1).

The box deformation is imposed on the positions (YADE's ``homoDeform`` by position): a change of ε̇ moves
every sphere with the box at once, with no inertial lag. Newton's law for v = u + ε̇ ⊙ (x − c) would give
m u̇ = F − m (ε̈ + ε̇²) ⊙ (x − c) − m ε̇ ⊙ u (derived here: v̇ = u̇ + ε̈ ⊙ (x − c) + ε̇ ⊙ v); those terms
are left out. Against a contact force σ d² (m ~ ρ d³, |x − c| ≤ L/2) the ε̇² term is of order I² L/d
(I = ε̇ d √(ρ/σ)): ~1e-5 at I = 1e-3 in a cell of 10 d; ε̈ matters only while the servo changes the
rate. Box lengths and fractional positions move by compensated summation (a
quasi-static sphere moves ~1e-8 of the box per step, below float32 resolution).

Cost: the pair forces run in JAX (the compiled pair kernel reads branches without images): 512 spheres
(a jittered simple cubic lattice, 2,304 pair slots, float32) ran 1,450 steps/s on this machine's 2 cores
shared with other jobs (load average ~10; 2,000 steps in one compiled chunk, 2026-11-29).

Errors ride in ``state.error`` (:class:`membrax.errors.ErrorCode`): a neighbour list that overflowed or
whose cells the box outgrew sets ``NEIGHBOR_OVERFLOW``, and the runner allocates a new list from the
chunk's starting state (:func:`membrax.driver.grow_tables`, with the list allocated by
:meth:`PeriodicRunner.allocate_list`; the members of a batch, :class:`membrax.executor.PeriodicBatch`, all
together in one shape); non-finite positions or velocities set ``NOT_FINITE``.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import functools
import math

import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.compensated import compensated_add
from membrax.driver import ChunkRunner
from membrax.errors import ErrorCode, not_finite_bit
from membrax.spheres.contact import ContactParams
from membrax.spheres.integrate import DampingParams, DEMParams, damped_velocities, make_particles
from membrax.spheres.neighbors import PeriodicNeighborFn, periodic_neighbor_fn, remap_pair_history_if
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.spheres.periodic import (
    RATTLER_CONTACTS,
    cell_stiffness,
    coordination_numbers,
    love_weber_stress,
    periodic_pair_forces,
    unbalanced_force_ratio,
)
from membrax.theory import strain_rate_from_inertial_number
from membrax.triaxial.protocol import StagedTest
from membrax.validation import check_range

__all__ = [
    "AXIAL",
    "CRITICAL_STEP_BOUND",
    "CellControl",
    "CellRecords",
    "PeriodicRunner",
    "PeriodicState",
    "PeriodicTest",
    "cell_forces",
    "measure_cell",
    "periodic_cell",
    "periodic_test",
    "servo_strain_rate",
    "stable_time_step",
]

#: The axial axis (z).
AXIAL = 2
#: The densest solid fraction a cell's cells are sized for at allocation (above FCC's 0.7405 no packing
#: of equal spheres goes): a compaction then never shrinks the box below its neighbour cells.
_DENSEST = 0.75


@pytree.dataclass
class CellControl:
    """How the box moves on each axis (extension-positive rates, compression-positive stresses).

    Attributes:
      target_stress: (3,) σ* of the stress-controlled axes, Pa.
      stress_controlled: (3,) bool: servo-held (True) or at ``imposed_strain_rate`` (False).
      imposed_strain_rate: (3,) ε̇ of the strain-controlled axes, 1/s.
      servo_gain: the servo's proportional gain α (:func:`servo_strain_rate`).
      integral_gain: its integral gain β.
      max_strain_rate: the servo's |ε̇| limit, 1/s.
    """

    target_stress: jnp.ndarray
    stress_controlled: jnp.ndarray
    imposed_strain_rate: jnp.ndarray
    servo_gain: jnp.ndarray
    integral_gain: jnp.ndarray
    max_strain_rate: jnp.ndarray


@pytree.dataclass
class PeriodicState:
    """Everything that evolves in a periodic cell.

    Attributes:
      fraction: (N, 3) fractional positions s ∈ [0, 1), x = L ⊙ s (high part).
      fraction_compensation: (N, 3) their low parts (compensated summation).
      velocity: (N, 3) u_{n−1/2}, the velocity relative to the box's affine field, m/s.
      angular_velocity: (N, 3) ω_{n−1/2}, rad/s.
      pair_spring: (C, 3) tangential spring of each pair slot (force on the higher id), N.
      length: (3,) box lengths L (high part), m.
      length_compensation: (3,) their low parts, m.
      strain_rate: (3,) ε̇_{n−1/2} = L̇/L, 1/s.
      servo_integral: (3,) the servo's integral term, 1/s (:func:`servo_strain_rate`).
      list_length: (3,) L at the neighbour list's last build, m.
      cell_length: (3,) the box its cell list's cells were sized for at allocation, m (the list's shape
        follows from it: a checkpoint's template is allocated there).
      strain_origin: (3,) L from which the strains count (the start of shearing), m.
      control: the box's :class:`CellControl`.
      neighbors: the jax-md neighbour list (fractional coordinates).
      step: steps taken.
      error: int32 :class:`membrax.errors.ErrorCode` bits.
    """

    fraction: jnp.ndarray
    fraction_compensation: jnp.ndarray
    velocity: jnp.ndarray
    angular_velocity: jnp.ndarray
    pair_spring: jnp.ndarray
    length: jnp.ndarray
    length_compensation: jnp.ndarray
    strain_rate: jnp.ndarray
    servo_integral: jnp.ndarray
    list_length: jnp.ndarray
    cell_length: jnp.ndarray
    strain_origin: jnp.ndarray
    control: CellControl
    neighbors: object
    step: jnp.ndarray
    error: jnp.ndarray

    @property
    def box_length(self):
        """L, high and low parts summed, m."""
        return self.length + self.length_compensation

    @property
    def position(self):
        """X = L ⊙ s, (N, 3), m (the driver's and a viewer's positions)."""
        return self.box_length[None, :] * (self.fraction + self.fraction_compensation)


def servo_strain_rate(stress_diagonal, stiffness, control: CellControl, integral, dt):
    """(ε̇_{n+1/2}, new integral) per axis: the stress servo on stress-controlled axes, else the imposed rate.

    A proportional–integral law on the box strain rate, in units of the cell's stiffness K_k
    (:func:`membrax.spheres.periodic.cell_stiffness`), e_k = (σ_kk − σ*_k) / (K_k Δt):

        I_k ← clip(I_k + β e_k, ±ε̇_max),   ε̇_k = clip(α e_k + I_k, ±ε̇_max).

    In an affine step the stress changes by −K_k ε̇_k Δt, so the error follows
    e_{n+1} = e_n − α e_n − β Σ_{m<=n} e_m, whose characteristic roots solve λ² − (2 − α − β) λ + 1 − α = 0:
    |λ|² = 1 − α < 1 (stable for 0 < α < 1), critically damped at β = α²/4 (the default, derived here).
    The integral removes the proportional law's lag under a steady load: shearing at ε̇ pushes the lateral
    stress up by ~K ε̇ Δt / 2 per step, which a proportional law (the wall servo's,
    :func:`membrax.spheres.walls.servo_velocity`) holds only at an error of K ε̇ Δt / (2 α), ~5 % of σc at
    I = 5e-3 (measured on 150 spheres). YADE's ``PeriTriaxController`` is an integral law with a cell mass.
    With no contact (a gas, K = 0) the box moves at ±ε̇_max. Non-affine relaxation softens the real
    response below K, which slows the loop.

    Args:
      stress_diagonal: (3,) σ_kk, Pa, compression positive.
      stiffness: (3,) K_k, Pa.
      control: the box's controls (α ``servo_gain``, β ``integral_gain``, ε̇_max).
      integral: (3,) I_k, 1/s.
      dt: time step, s.
    """
    tiny = jnp.finfo(stiffness.dtype).tiny
    error = (stress_diagonal - control.target_stress) / (jnp.maximum(stiffness, tiny) * dt)
    limit = control.max_strain_rate
    integral = jnp.clip(integral + control.integral_gain * error, -limit, limit)
    integral = jnp.where(control.stress_controlled, integral, 0.0)
    servo = jnp.clip(control.servo_gain * error + integral, -limit, limit)
    return jnp.where(control.stress_controlled, servo, control.imposed_strain_rate), integral


def periodic_cell(particles, frame: PeriodicNeighborFn, dt: float):
    """The periodic cell's simulation as ``(init_fn, step_fn)`` (module docstring).

    Args:
      particles: sphere properties (:func:`membrax.spheres.integrate.make_particles`; one cell, B = 1).
      frame: the neighbour-list factory (:func:`membrax.spheres.neighbors.periodic_neighbor_fn`).
      dt: time step, s (:func:`stable_time_step`).
    """
    n = particles.num_particles

    def init_fn(
        fraction, length, neighbors, control: CellControl, velocity=None, cell_length=None
    ) -> PeriodicState:
        fraction = jnp.asarray(fraction)
        dtype = fraction.dtype
        length = jnp.asarray(length, dtype)
        zeros = jnp.zeros_like(fraction)
        return PeriodicState(
            fraction=fraction,
            fraction_compensation=zeros,
            velocity=zeros if velocity is None else jnp.asarray(velocity, dtype),
            angular_velocity=zeros,
            pair_spring=jnp.zeros((neighbors.idx.shape[1], 3), dtype),
            length=length,
            length_compensation=jnp.zeros_like(length),
            strain_rate=jnp.zeros_like(length),
            servo_integral=jnp.zeros_like(length),
            list_length=length,
            cell_length=length if cell_length is None else jnp.asarray(cell_length, dtype),
            strain_origin=length,
            control=control,
            neighbors=neighbors,
            step=jnp.asarray(0, jnp.int32),
            error=jnp.asarray(0, jnp.int32),
        )

    def step_fn(state: PeriodicState, params: DEMParams) -> PeriodicState:
        length = state.box_length
        neighbors, rebuilt = frame.update(state.fraction, state.neighbors, length, state.list_length)
        pair_spring = remap_pair_history_if(rebuilt, state.neighbors.idx, neighbors.idx, state.pair_spring, n)
        state = state.set(
            neighbors=neighbors,
            pair_spring=pair_spring,
            list_length=jnp.where(rebuilt, length, state.list_length),
        )
        forces = cell_forces(state, particles, params, dt)
        stress = love_weber_stress(forces, length)
        stiffness = cell_stiffness(forces, length, params.contact.normal_stiffness)
        strain_rate, integral = servo_strain_rate(
            jnp.diagonal(stress), stiffness, state.control, state.servo_integral, dt
        )
        velocity, angular_velocity = damped_velocities(state, forces, particles, params.damping, dt)
        new_length, length_compensation = compensated_add(
            state.length, state.length_compensation, dt * strain_rate * length
        )
        box = new_length + length_compensation
        fraction, compensation = compensated_add(
            state.fraction, state.fraction_compensation, dt * velocity / box[None, :]
        )
        # Wrap into [0, 1): s − floor(s) is exact for |s| < 2; a tiny negative s rounds up to 1.0.
        fraction = fraction - jnp.floor(fraction)
        fraction = jnp.where(fraction >= 1.0, fraction - 1.0, fraction)
        error = state.error | jnp.where(frame.needs_new_list(neighbors), ErrorCode.NEIGHBOR_OVERFLOW, 0)
        error = error | not_finite_bit(fraction, velocity, new_length)
        return state.set(
            fraction=fraction,
            fraction_compensation=compensation,
            velocity=velocity,
            angular_velocity=angular_velocity,
            pair_spring=forces.pair_spring,
            length=new_length,
            length_compensation=length_compensation,
            strain_rate=strain_rate,
            servo_integral=integral,
            step=state.step + 1,
            error=error.astype(jnp.int32),
        )

    return init_fn, step_fn


def cell_forces(state: PeriodicState, particles, params: DEMParams, dt):
    """The contacts of ``state`` (its list current): :func:`membrax.spheres.periodic.periodic_pair_forces`."""
    return periodic_pair_forces(
        state.fraction,
        state.fraction_compensation,
        state.velocity,
        state.angular_velocity,
        particles.radius,
        state.box_length,
        state.strain_rate,
        state.neighbors.idx,
        state.pair_spring,
        params.contact,
        dt,
    )


@pytree.dataclass
class CellRecords:
    """What a periodic cell records (one row per record; compression-positive stresses and strains).

    Attributes:
      step: steps taken.
      stress: (3, 3) Love–Weber stress tensor, Pa.
      principal_stress: (3,) its eigenvalues, largest first, Pa.
      axial_stress: σ_zz, Pa.
      lateral_stress: (σ_xx + σ_yy)/2, Pa.
      mean_stress: p = tr σ / 3, Pa.
      deviator_stress: q = σ_zz − (σ_xx + σ_yy)/2, Pa.
      axial_strain: 1 − Lz/Lz0 (L0 at ``strain_origin``).
      volumetric_strain: 1 − V/V0.
      solid_fraction: Σ 4/3 π R³ / V.
      coordination_number: z = 2 C/N over closed contacts.
      rattler_free_coordination_number: z*, rattlers removed
        (:func:`membrax.spheres.periodic.coordination_numbers`).
      rattler_fraction: share of rattlers.
      unbalanced_force_ratio: mean |ΣF| / mean contact normal force.
      kinetic_energy: ½ Σ (m u² + I ω²), fluctuations only, J.
      length: (3,) box lengths, m.
      strain_rate: (3,) ε̇, 1/s.
    """

    step: jnp.ndarray
    stress: jnp.ndarray
    principal_stress: jnp.ndarray
    axial_stress: jnp.ndarray
    lateral_stress: jnp.ndarray
    mean_stress: jnp.ndarray
    deviator_stress: jnp.ndarray
    axial_strain: jnp.ndarray
    volumetric_strain: jnp.ndarray
    solid_fraction: jnp.ndarray
    coordination_number: jnp.ndarray
    rattler_free_coordination_number: jnp.ndarray
    rattler_fraction: jnp.ndarray
    unbalanced_force_ratio: jnp.ndarray
    kinetic_energy: jnp.ndarray
    length: jnp.ndarray
    strain_rate: jnp.ndarray


def measure_cell(
    state: PeriodicState, particles, params: DEMParams, dt, rattler_contacts: int = RATTLER_CONTACTS
) -> CellRecords:
    """The :class:`CellRecords` of ``state`` (its list current, as after a step).

    ``rattler_contacts`` (static): the rattler rule of z*
    (:func:`membrax.spheres.periodic.coordination_numbers`).
    """
    forces = cell_forces(state, particles, params, dt)
    length = state.box_length
    volume = jnp.prod(length)
    stress = love_weber_stress(forces, length)
    z, z_star, rattlers = coordination_numbers(
        forces, state.neighbors.idx, particles.num_particles, rattler_contacts
    )
    lateral = 0.5 * (stress[0, 0] + stress[1, 1])
    solid = jnp.sum(4.0 / 3.0 * math.pi * particles.radius**3) / volume
    kinetic = 0.5 * jnp.sum(particles.mass[:, None] * state.velocity**2) + 0.5 * jnp.sum(
        particles.inertia[:, None] * state.angular_velocity**2
    )
    return CellRecords(
        step=state.step,
        stress=stress,
        principal_stress=jnp.linalg.eigvalsh(stress)[::-1],
        axial_stress=stress[AXIAL, AXIAL],
        lateral_stress=lateral,
        mean_stress=jnp.trace(stress) / 3.0,
        deviator_stress=stress[AXIAL, AXIAL] - lateral,
        axial_strain=1.0 - length[AXIAL] / state.strain_origin[AXIAL],
        volumetric_strain=1.0 - volume / jnp.prod(state.strain_origin),
        solid_fraction=solid.astype(length.dtype),
        coordination_number=z,
        rattler_free_coordination_number=z_star,
        rattler_fraction=rattlers,
        unbalanced_force_ratio=unbalanced_force_ratio(forces),
        kinetic_energy=kinetic,
        length=length,
        strain_rate=state.strain_rate,
    )


class PeriodicRunner(ChunkRunner):
    """The chunk runner of a periodic cell: its tables grow through :func:`membrax.driver.grow_tables`.

    A list that overflowed, or whose cells the shrinking box outgrew, is allocated again at the chunk's
    starting state by :meth:`allocate_list` and the springs move over by partner id (``grow_tables``); the
    state's ``list_length`` becomes its box, at which the new list was built.

    Args:
      step_fn: ``step_fn(state, params) -> state`` (:func:`periodic_cell`).
      neighbor_frame: the cell's neighbour-list factory
        (:func:`membrax.spheres.neighbors.periodic_neighbor_fn`).
      record_fn: ``record_fn(state, params) -> pytree`` recorded every ``record_every`` steps.
      num_particles: N.
      capacity_growth: the pair capacity's growth factor where the pairs overflowed.
    """

    def __init__(
        self,
        step_fn,
        neighbor_frame: PeriodicNeighborFn,
        record_fn,
        num_particles: int,
        capacity_growth: float = 1.5,
    ):
        super().__init__(
            step_fn,
            neighbor_frame,
            record_fn,
            num_particles,
            capacity_growth,
            with_dem=self.with_list_at_box,
            allocate=self.allocate_list,
        )

    def allocate_list(self, states, capacity, overflowed):
        """The new periodic lists of the chunk's starting states (``grow_tables``' ``allocate``).

        Their cells are sized for 0.9 × the smallest of the starts' and the overflowing ends' boxes
        (``overflowed``: the end state, or the members' end states of a batch), so the rerun chunk fits;
        ``capacity`` (the growth × the old one) is asked for only where the pairs overflowed, at a start or
        an end: a list whose cells alone were outgrown keeps its slots. The members of a batch get lists of
        one shape (:meth:`membrax.spheres.neighbors.PeriodicNeighborFn.reallocate_shared`).
        """
        ends = list(overflowed) if isinstance(overflowed, (list, tuple)) else [overflowed]
        listed = [state.neighbors for state in [*states, *ends]]
        if not any(bool(listing.did_buffer_overflow) for listing in listed):
            capacity = int(states[0].neighbors.max_occupancy)
        boxes = [state.box_length for state in [*states, *ends]]
        cells = 0.9 * functools.reduce(jnp.minimum, boxes)
        self._cells = cells
        return self.neighbor_frame.reallocate_shared(
            [state.fraction for state in states], [state.box_length for state in states], cells, capacity
        )

    def with_list_at_box(self, _state, grown):
        """``grown`` noted as listed at its box, with :meth:`allocate_list`'s cells (a template needs them).

        The next update measures the box's strain from ``list_length``; ``cell_length`` fixes the list's
        shape (:meth:`PeriodicTest.template`). ``grow_tables``' ``with_dem``.
        """
        return grown.set(list_length=grown.box_length, cell_length=self._cells.astype(grown.length.dtype))


#: Δt_crit ≥ CRITICAL_STEP_BOUND √(m_min/k) (:func:`stable_time_step`): 2/√24 ≈ 0.408.
CRITICAL_STEP_BOUND = 2.0 / math.sqrt(24.0)


def stable_time_step(particles, contact_params: ContactParams, safety: float = 0.25) -> float:
    """Δt = safety × √(m_min / k), k = max(k_n, 3.5 k_s), s.

    A bound in closed form (a gas has no contact network for a Lanczos estimate,
    :mod:`membrax.spheres.stability`, whose branch vectors would also miss the minimum image): by
    Gershgorin, ω_max² of M⁻¹K is at most 2 z k/m over a sphere's z contacts; with z ≤ 12 (a sphere's
    kissing number) and the rotational–tangential mode's 3.5 k_s/m per contact,
    Δt_crit = 2/ω_max ≥ 2/√(24 k/m) = :data:`CRITICAL_STEP_BOUND` √(m/k) ≈ 0.41 √(m/k); 0.25 keeps a margin.
    """
    mass = float(np.min(np.asarray(particles.mass)))
    stiffness = max(
        float(np.max(contact_params.normal_stiffness)),
        3.5 * float(np.max(contact_params.tangential_stiffness)),
    )
    return safety * math.sqrt(mass / stiffness)


@pydataclasses.dataclass
class PeriodicTest(StagedTest):
    """A periodic cell ready to run (built by :func:`periodic_test`).

    Its stages, :meth:`consolidate` and :meth:`shear`, are :class:`membrax.triaxial.protocol.StagedTest`'s
    (the phases of :data:`membrax.triaxial.protocol.PHASES`), with the box in place of the platens and walls:
    consolidation servo-holds every axis at σc; shearing shortens z at the constant ε̇ = L̇/L of the inertial
    number (a constant rate of logarithmic strain: the box's deformation is imposed on the positions, so
    there are no platens to bring up to speed and no start-up ramp) and servo-holds x and y at σc.
    """

    cell = "periodic"
    default_ramp_strain = 0.0

    particles: object
    params: DEMParams
    dt: float
    cell_pressure: float
    density: float
    particle_diameter: float
    initial_state: PeriodicState
    runner: PeriodicRunner
    step_fn: object

    def control(self, state, stress_controlled, imposed_strain_rate=0.0, target=None, max_strain_rate=None):
        """``state`` with its box controls set (scalars or (3,) per axis; target default σc)."""
        dtype = state.length.dtype
        control = state.control
        target = self.cell_pressure if target is None else target
        control = control.set(
            target_stress=jnp.broadcast_to(jnp.asarray(target, dtype), (3,)),
            stress_controlled=jnp.broadcast_to(jnp.asarray(stress_controlled, bool), (3,)),
            imposed_strain_rate=jnp.broadcast_to(jnp.asarray(imposed_strain_rate, dtype), (3,)),
        )
        if max_strain_rate is not None:
            control = control.set(max_strain_rate=jnp.asarray(max_strain_rate, dtype))
        return state.set(control=control)

    @property
    def initial_volume(self) -> float:
        """The box's volume as built, m³ (σc V₀: the runaway stop's scale, :mod:`membrax.runner`)."""
        return float(np.prod(np.asarray(self.initial_state.length)))

    def list_shape(self, state: PeriodicState) -> dict:
        """What fixes the shape of ``state``'s neighbour list (:meth:`template`'s arguments), plain values."""
        return {
            "capacity": int(state.neighbors.idx.shape[1]),
            "cell_length": [float(x) for x in np.asarray(state.cell_length)],
            "cell_list_capacity": int(state.neighbors.cell_list_capacity or 0),
        }

    def template(self, capacity: int, cell_length, cell_list_capacity: int) -> PeriodicState:
        """The initial state with a list shaped by :meth:`list_shape`'s values (a checkpoint's template).

        The list is allocated with its cells sized for ``cell_length`` (its static cell grid, as the run's
        was), ``capacity`` pair slots and ``cell_list_capacity``; its slots and the springs are the
        checkpoint's to fill (:func:`membrax.io.load_checkpoint`).
        """
        state = self.initial_state
        dtype = state.length.dtype
        cells = jnp.asarray(cell_length, dtype)
        listing = self.runner.neighbor_frame.reallocate(state.fraction, state.length, cells, 0)
        idx = jnp.full((listing.idx.shape[0], capacity), state.fraction.shape[0], listing.idx.dtype)
        listing = listing.set(idx=idx, max_occupancy=capacity, cell_list_capacity=cell_list_capacity or None)
        return state.set(neighbors=listing, pair_spring=jnp.zeros((capacity, 3), dtype), cell_length=cells)

    def shear_rate(self, inertial_number: float) -> float:
        """ε̇ = I / (d √(ρ/σc)), 1/s (GDR MiDi 2004; d the mean diameter)."""
        check_range("inertial_number", inertial_number, lower=0.0, lower_open=True)
        return strain_rate_from_inertial_number(
            inertial_number, self.particle_diameter, self.density, self.cell_pressure
        )

    def start_consolidation(self, state) -> PeriodicState:
        """``state`` with every axis servo-held to σc."""
        return self.control(state, True)

    def is_consolidated(self, records, tolerance: float, stress_tolerance: float = 0.01) -> bool:
        """The stop test: unbalanced-force ratio below ``tolerance``, each σ_kk within 1 % (default) of σc."""
        diagonal = np.diagonal(np.asarray(records.stress[-1]))
        close = np.all(np.abs(diagonal / self.cell_pressure - 1.0) < stress_tolerance)
        return bool(close and records.unbalanced_force_ratio[-1] < tolerance)

    def start_shear(self, state, inertial_number: float = 1e-3, ramp_strain: float = 0.0, symmetric=None):
        """``state`` switched to drained compression: z at −ε̇ (``inertial_number``), x and y at σc.

        Strains count from here (``strain_origin``). ``ramp_strain`` and ``symmetric`` are the platens'
        and are not used: the box's rate changes at once, every sphere moved with it (module docstring).
        """
        del ramp_strain, symmetric
        rate = self.shear_rate(inertial_number)
        state = self.control(state, [True, True, False], [0.0, 0.0, -rate])
        return state.set(strain_origin=state.box_length)

    def change_shear_rate(self, state, inertial_number, coarse_inertial_number, ramp_strain=None):
        """``state`` shortening z at the rate of ``coarse_inertial_number`` from now (no ramp)."""
        del inertial_number, ramp_strain
        rate = self.shear_rate(coarse_inertial_number)
        return self.control(state, [True, True, False], [0.0, 0.0, -rate])

    def steps_at_rates(
        self, target_axial_strain, fine_until_strain, ramp_strain, fine_rate, coarse_rate
    ) -> tuple[int, int]:
        """:meth:`shear_plan`'s (fine, coarse) steps at the strain rates ``fine_rate`` and ``coarse_rate``.

        At a constant ε̇ = L̇/L the engineering strain ε = 1 − Lz/Lz0 reaches ε after −ln(1 − ε)/(ε̇ Δt)
        steps; the coarse phase runs at ``coarse_rate`` (None: ``fine_rate``). ``ramp_strain`` is not used
        (class docstring).
        """
        del ramp_strain
        coarse_rate = fine_rate if coarse_rate is None else coarse_rate
        fine_strain = min(fine_until_strain, target_axial_strain)
        fine = math.ceil(-math.log1p(-fine_strain) / (fine_rate * self.dt))
        rest = -math.log1p(-target_axial_strain) + math.log1p(-fine_strain)
        return fine, max(0, math.ceil(rest / (coarse_rate * self.dt)))


def periodic_test(
    fraction,
    length,
    radius,
    cell_pressure: float,
    contact_params: ContactParams | None = None,
    damping: DampingParams | None = None,
    density: float = GRANITE_DENSITY,
    dt_safety: float = 0.25,
    skin_fraction: float = 0.2,
    servo_gain: float = 0.1,
    integral_gain: float | None = None,
    max_inertial_number: float = 0.01,
    time_step: float | None = None,
    rattler_contacts: int | None = None,
) -> PeriodicTest:
    """Build a periodic cell (module docstring) on spheres at fractional positions in a box.

    Args:
      fraction: (N, 3) fractional positions in [0, 1); their dtype is the simulation's.
      length: (3,) box lengths, m.
      radius: (N,) radii, m.
      cell_pressure: σc, Pa, > 0.
      contact_params: the contact law (default the paper's, :meth:`ContactParams.paper`).
      damping: default Cundall local 0.3, on the velocities relative to the box's affine field.
      density: grain density, kg/m³.
      dt_safety: Δt = dt_safety √(m_min/k) (:func:`stable_time_step`).
      skin_fraction: neighbour skin as a fraction of the largest diameter.
      servo_gain: the box servo's α (:func:`servo_strain_rate`), 0 < α < 1.
      integral_gain: its β (default α²/4, critically damped in an affine step).
      max_inertial_number: the servo's rate limit as an inertial number at σc.
      time_step: Δt, s, overriding ``dt_safety``.
      rattler_contacts: the rattler rule of the recorded z* (default 4 for a frictionless law, Agnolin &
        Roux's, and 2 with friction; :func:`membrax.spheres.periodic.coordination_numbers`).
    """
    check_range("cell_pressure", cell_pressure, lower=0.0, lower_open=True, hint="Pa; 100 kPa is 1e5.")
    contact_params = ContactParams.paper() if contact_params is None else contact_params
    damping = DampingParams.local(0.3) if damping is None else damping
    params = DEMParams(contact=contact_params, damping=damping)
    if rattler_contacts is None:
        frictionless = not np.any(np.asarray(contact_params.friction_coefficient) != 0.0)
        rattler_contacts = RATTLER_CONTACTS if frictionless else 2
    fraction = jnp.asarray(fraction)
    dtype = fraction.dtype
    radius = jnp.asarray(radius, dtype)
    particles = make_particles(radius, density)
    diameter = 2.0 * float(np.max(np.asarray(radius)))
    mean_diameter = 2.0 * float(np.mean(np.asarray(radius)))
    length = np.asarray(length, dtype=float)
    frame = periodic_neighbor_fn(diameter, skin_fraction * diameter)
    solid = float(np.sum(4.0 / 3.0 * math.pi * np.asarray(radius, dtype=float) ** 3) / np.prod(length))
    cells = length * min(1.0, (solid / _DENSEST) ** (1.0 / 3.0))
    neighbors = frame.reallocate(fraction, jnp.asarray(length, dtype), jnp.asarray(cells, dtype), 0)
    dt = stable_time_step(particles, contact_params, dt_safety) if time_step is None else float(time_step)
    max_rate = strain_rate_from_inertial_number(max_inertial_number, mean_diameter, density, cell_pressure)
    control = CellControl(
        target_stress=jnp.full((3,), cell_pressure, dtype),
        stress_controlled=jnp.ones((3,), bool),
        imposed_strain_rate=jnp.zeros((3,), dtype),
        servo_gain=jnp.asarray(servo_gain, dtype),
        integral_gain=jnp.asarray(0.25 * servo_gain**2 if integral_gain is None else integral_gain, dtype),
        max_strain_rate=jnp.asarray(max_rate, dtype),
    )
    init_fn, step_fn = periodic_cell(particles, frame, dt)

    def record(state, p):
        return measure_cell(state, particles, p, dt, rattler_contacts)

    return PeriodicTest(
        particles=particles,
        params=params,
        dt=dt,
        cell_pressure=float(cell_pressure),
        density=density,
        particle_diameter=mean_diameter,
        initial_state=init_fn(fraction, length, neighbors, control, cell_length=cells),
        runner=PeriodicRunner(step_fn, frame, record, particles.num_particles),
        step_fn=step_fn,
    )
