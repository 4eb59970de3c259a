"""The triaxial test protocol on a DEM specimen (rigid-wall reference test).

Contract. :func:`rigid_wall_test` builds a cell around a specimen — platens plus one servo wall per face of
the specimen's outline, as in YADE's ``TriaxialStressController`` — and returns a :class:`RigidWallTest`
whose methods run the two stages with the chunk driver and return the state and the records
(:class:`membrax.spheres.measure.Measurements`, numpy arrays with a leading time axis):

1. :meth:`RigidWallTest.consolidate`: every wall servo-controlled to the cell pressure σc until the
   unbalanced-force ratio falls below ``tolerance`` and every wall stress is within ``stress_tolerance``
   of σc;
2. :meth:`RigidWallTest.shear`: the top platen moves down at constant velocity (or both platens close,
   ``symmetric=True``, as in the membrane cell; drained, strain controlled), lateral walls held at σc by
   their servos (proportional-integral, so a dilating specimen does not raise σ3:
   :mod:`membrax.spheres.walls`), to a target axial strain. The strain rate comes
   from an inertial number I = ε̇ d √(ρ/σc) (GDR MiDi 2004, with the axial strain rate for the shear rate
   and the cell pressure for the confining stress). Records every ``record_every_fine`` steps below
   ``fine_until_strain`` (the FCC peak is a spike within 0.01–0.1 % strain), coarser after.

The membrane test of the paper replaces the lateral walls by a membrane (later module); this rigid test is
the reference every membrane result is compared with.
"""

from __future__ import annotations

import dataclasses as pydataclasses

import jax.numpy as jnp
import numpy as np

from membrax import batch
from membrax.driver import ChunkRunner
from membrax.spheres.contact import ContactParams
from membrax.spheres.fcc import Specimen
from membrax.spheres.integrate import (
    DampingParams,
    DEMParams,
    DEMState,
    make_particles,
    sphere_dem,
)
from membrax.spheres.measure import measure
from membrax.spheres.neighbors import pair_neighbor_fn
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.spheres.stability import DEFAULT_SAFETY, critical_time_step
from membrax.spheres.walls import (
    BOTTOM,
    LATERAL_INTEGRAL_FRACTION,
    LATERAL_SERVO_GAIN,
    TOP,
    ramp_acceleration,
    set_control,
    triaxial_walls,
)
from membrax.theory import strain_rate_from_inertial_number
from membrax.triaxial.protocol import StagedTest
from membrax.validation import check_range

__all__ = ["RigidWallTest", "peak", "rigid_wall_test", "strain_rate_from_inertial_number"]

#: The lateral walls' speed limit in shearing, in units of ε̇ R (:meth:`RigidWallTest.start_shear`): the
#: fastest radial velocity a dilating dense packing asks for is about ε̇ R, and the servo needs headroom above
#: it to correct an error while following it. Measured on ~250 dense spheres at 100 kPa, I = 1e-3 (σ3 past
#: 0.2 % strain, 2026-12-07): 1 × (the build's limit) up to 1.17 σc, 2 × up to 1.026 σc, 3 × 0.996–1.010 σc.
LATERAL_SPEED_MARGIN = 3.0


@pydataclasses.dataclass
class RigidWallTest(StagedTest):
    """A specimen in a rigid-wall cell, ready to run (built by :func:`rigid_wall_test`).

    Its stages, :meth:`consolidate` and :meth:`shear`, are :class:`membrax.triaxial.protocol.StagedTest`'s.
    """

    cell = "rigid"

    specimen: Specimen
    particles: object
    params: DEMParams
    dt: float
    critical_dt: float
    cell_pressure: np.ndarray
    density: float
    initial_state: DEMState
    runner: ChunkRunner
    initial_height: np.ndarray
    initial_volume: np.ndarray

    @property
    def num_members(self) -> int:
        """B, the number of batch members (folded)."""
        return self.particles.num_members

    def set_walls(self, state: DEMState, servo, velocity, target, acceleration=np.inf) -> DEMState:
        """A copy of ``state`` with every wall's mode, velocity and target stress set.

        Args:
          state: the state to change.
          servo: stress-controlled (True) or constant-velocity (False); scalar, (B,) or (B, W).
          velocity: wall velocities dh/dt, m/s (used by constant-velocity walls); scalar, (B,) or (B, W).
          target: servo target stresses, Pa; scalar, (B,) or (B, W).
          acceleration: the constant-velocity walls' ramp from rest, m/s² (inf: none;
            :func:`membrax.spheres.walls.set_control`).
        """
        return state.set(walls=set_control(state.walls, servo, velocity, target, acceleration))

    def start_consolidation(self, state: DEMState) -> DEMState:
        """Switch ``state`` to stage 1: every wall servo-controlled to σc, at rest."""
        return self.set_walls(state, True, 0.0, self.cell_pressure)

    def is_consolidated(self, records, tolerance: float, stress_tolerance: float = 0.01) -> bool:
        """The consolidation stop test on a chunk's records (module docstring, stage 1).

        Every member must be in equilibrium (members that are already there just wait): the last
        unbalanced-force ratio below ``tolerance`` and every wall stress within ``stress_tolerance`` of σc.
        """
        last_ufr = records.unbalanced_force_ratio[-1]
        wall = np.asarray(records.wall_axial_stress[-1]), np.asarray(records.wall_radial_stress[-1])
        close = all(np.all(np.abs(w / self.cell_pressure - 1.0) < stress_tolerance) for w in wall)
        return bool(np.all(last_ufr < tolerance) and close)

    def shear_rate(self, inertial_number: float) -> float:
        """ε̇ = I / (d √(ρ/σc)) at the lowest cell pressure of the batch, 1/s (module docstring).

        In a batch every member shears at this one rate (members at higher pressure shear at a smaller
        inertial number).
        """
        check_range("inertial_number", inertial_number, lower=0.0, lower_open=True)
        return strain_rate_from_inertial_number(
            inertial_number, self.specimen.particle_diameter, self.density, float(np.min(self.cell_pressure))
        )

    def start_shear(
        self,
        state: DEMState,
        inertial_number: float = 1e-3,
        ramp_strain: float = 0.0,
        symmetric: bool = False,
    ) -> DEMState:
        """Switch ``state`` to stage 2: the top platen closes at ε̇ H, the lateral walls servo-held at σc.

        ``ramp_strain`` > 0 ramps the platen up from rest, reaching full speed at that axial strain
        (:func:`membrax.spheres.walls.set_control`'s acceleration; the rigid-wall default is a step change).
        ``symmetric``: both platens close, each at ε̇ H/2, as the membrane cell's default loading
        (:meth:`membrax.triaxial.membrane_cell.MembraneTest.start_shear`); the rigid-wall default moves the
        top one alone.
        """
        check_range("ramp_strain", ramp_strain, lower=0.0, upper=1.0, upper_open=True)
        rate = self.shear_rate(inertial_number)
        heights = np.asarray(state.walls.position[:, TOP] + state.walls.position[:, BOTTOM])
        velocity = np.zeros(state.walls.velocity.shape)
        if symmetric:
            velocity[:, [BOTTOM, TOP]] = -0.5 * rate * heights[:, None]
        else:
            velocity[:, TOP] = -rate * heights
        servo = np.ones(state.walls.servo.shape, dtype=bool)
        servo[:, :2] = False
        acceleration = ramp_acceleration(velocity, rate, ramp_strain)
        state = self.set_walls(state, servo, velocity, self.cell_pressure, acceleration)
        # The lateral walls must be free to follow the dilation: a wall at radius R moves out at ε̇_r R, and
        # a dense packing's radial strain rate reaches about ε̇, so the servo's speed limit is raised to at
        # least LATERAL_SPEED_MARGIN ε̇ R. At 100 kPa and I = 1e-3 the build's limit (1 % of a diameter per
        # 1,000 steps, 18.5 mm/s) is ε̇ R itself.
        radius = np.max(np.asarray(state.walls.position[:, 2:]), axis=1, keepdims=True)
        limit = np.asarray(state.walls.max_speed).copy()
        limit[:, 2:] = np.maximum(limit[:, 2:], LATERAL_SPEED_MARGIN * rate * radius)
        return state.set(walls=state.walls.set(max_speed=jnp.asarray(limit, state.walls.max_speed.dtype)))


def rigid_wall_test(
    specimen: Specimen,
    cell_pressure,
    contact_params: ContactParams | None = None,
    damping: DampingParams | None = None,
    density: float = GRANITE_DENSITY,
    dt_safety: float = DEFAULT_SAFETY,
    skin_fraction: float = 0.2,
    servo_gain: float = 0.1,
    lateral_servo_gain: float = LATERAL_SERVO_GAIN,
    lateral_integral_gain: float | None = None,
    max_wall_speed: float | None = None,
    time_step: float | None = None,
) -> RigidWallTest:
    """Build a rigid-wall triaxial test (module docstring) on a specimen, or on a folded batch of copies.

    Args:
      specimen: from :func:`membrax.spheres.fcc.fcc_specimen`.
      cell_pressure: σc, Pa, > 0: a scalar, or one value per batch member (B,), which folds B copies of
        the specimen into one system (:mod:`membrax.batch`).
      contact_params: contact law (default: the paper's, :meth:`ContactParams.paper`); fields may be
        arrays over members.
      damping: default Cundall local 0.3 (the paper's) on the velocities relative to the walls' affine
        field (:data:`membrax.defaults.DAMPING_FRAME`); fields may be arrays over members.
      density: particle density, kg/m³ (granite by default; the paper gives none).
      dt_safety: Δt = dt_safety × Δt_crit.
      skin_fraction: neighbour skin as a fraction of the particle diameter.
      servo_gain: the platens' servo α (consolidation), a proportional servo.
      lateral_servo_gain: the lateral walls' servo α.
      lateral_integral_gain: the lateral walls' integral gain β (default
        :data:`~membrax.spheres.walls.LATERAL_INTEGRAL_FRACTION` × α, the integral root real and slow; 0:
        YADE's proportional servo), which holds σ3 at σc while the specimen dilates
        (:mod:`membrax.spheres.walls`, "Why the lateral walls need more").
      max_wall_speed: servo speed limit, m/s (default: 1 % of a diameter per 1000 steps); shearing raises
        the lateral walls' to at least :data:`LATERAL_SPEED_MARGIN` ε̇ R (:meth:`RigidWallTest.start_shear`).
      time_step: Δt in s, overriding ``dt_safety`` × Δt_crit (e.g. to run cases with one step).
    """
    check_range("cell_pressure", cell_pressure, lower=0.0, lower_open=True, hint="Pa; 10 kPa is 1e4.")
    check_range("density", density, lower=0.0, lower_open=True)
    check_range("dt_safety", dt_safety, lower=0.0, upper=1.0, lower_open=True)
    contact_params = ContactParams.paper() if contact_params is None else contact_params
    damping = DampingParams.local(0.3) if damping is None else damping
    params = DEMParams(contact=contact_params, damping=damping)
    cell_pressure = np.atleast_1d(np.asarray(cell_pressure, dtype=float))
    num_members = cell_pressure.shape[0]
    diameter = specimen.particle_diameter
    spacing = specimen.width_across_flats + 3.0 * diameter
    position, member = batch.fold(specimen.position, num_members, spacing)
    particles = make_particles(jnp.tile(specimen.radius, num_members), density, member, num_members)
    normals, distances = specimen.outline_faces()
    walls = triaxial_walls(
        np.asarray(normals),
        np.asarray(distances),
        specimen.height,
        num_members=num_members,
        servo_gain=servo_gain,
        lateral_servo_gain=lateral_servo_gain,
        lateral_integral_gain=(
            LATERAL_INTEGRAL_FRACTION * lateral_servo_gain
            if lateral_integral_gain is None
            else lateral_integral_gain
        ),
    )
    # Member b's planes pass through its shifted specimen: h_b = h + offset_b·e.
    shift = batch.member_offsets(num_members, spacing) @ np.asarray(walls.normal, dtype=float).T
    walls = walls.set(position=walls.position + jnp.asarray(shift, walls.position.dtype))
    # The cutoff is the largest sphere's diameter: with the mean's, two large graded spheres in contact
    # could be farther apart than cutoff + skin and never enter the list (the membrane cell does the same).
    largest = specimen.largest_diameter
    lower = np.min(np.asarray(position), axis=0) - largest
    upper = np.max(np.asarray(position), axis=0) + largest
    frame = pair_neighbor_fn(
        lower, upper, cutoff=largest, skin=skin_fraction * diameter, margin=0.5 * largest
    )
    neighbors = frame.allocate(position)
    probe_init, _ = sphere_dem(particles, frame, 1.0)
    probe = probe_init(position, walls, neighbors)
    critical = critical_time_step(probe, particles, params)
    dt = dt_safety * critical if time_step is None else float(time_step)
    if max_wall_speed is None:
        max_wall_speed = 0.01 * diameter / (1000 * dt)
    walls = walls.set(max_speed=jnp.full(walls.max_speed.shape, max_wall_speed, walls.max_speed.dtype))
    wall_friction = bool(np.any(np.asarray(contact_params.wall_friction_coefficient) != 0.0))
    init_fn, step_fn = sphere_dem(particles, frame, dt, wall_friction=wall_friction)
    state = init_fn(position, walls, neighbors)
    initial_height = np.full(num_members, specimen.height)
    initial_volume = np.full(num_members, specimen.cross_section_area * specimen.height)
    h0 = jnp.asarray(initial_height, position.dtype)
    v0 = jnp.asarray(initial_volume, position.dtype)

    def record(s, p):
        return measure(s, particles, p, dt, h0, v0, wall_friction=wall_friction)

    runner = ChunkRunner(step_fn, frame, record, particles.num_particles)
    return RigidWallTest(
        specimen=specimen,
        particles=particles,
        params=params,
        dt=dt,
        critical_dt=critical,
        cell_pressure=cell_pressure,
        density=density,
        initial_state=state,
        runner=runner,
        initial_height=initial_height,
        initial_volume=initial_volume,
    )


def peak(records, key: str = "love_weber_friction_angle", member: int = 0):
    """(peak value, axial strain at the peak) of a recorded quantity for one batch member."""
    values = np.asarray(getattr(records, key))[:, member]
    index = int(np.nanargmax(values))
    return float(values[index]), float(np.asarray(records.axial_strain)[index, member])
