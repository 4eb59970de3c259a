"""Rigid planes: platens and lateral servo walls of a triaxial cell.

Contract. A :class:`WallState` holds W planes shared by every member of a batch of B specimens. Plane k is
{x : x·e_k = h_k}, with a fixed unit normal e_k pointing *away* from the specimen and a position h_k per
member; it moves along e_k at velocity dh_k/dt. The layout is fixed: wall 0 is the bottom platen
(e = −z), wall 1 the top platen (e = +z), walls 2… are lateral faces (horizontal normals, counter-clockwise),
none for a membrane test. Each wall is either position-controlled (constant velocity) or stress-controlled
by a servo, chosen per wall and member by the traced mask ``servo``, so switching a stage never recompiles.

Servo (the PFC/YADE ``TriaxialStressController`` scheme, with an integral term on the rigid cell's lateral
walls): a proportional term, scaled so that one step closes a fraction α of the force error, plus an
integral term u that accumulates a fraction β of it every step,

    v_P = α (F − σ_target A) / (k_n max(n_c, 1) Δt),
    u_{n+1} = clip(u_n + β v_P, −v_max, v_max),
    v = clip(v_P + u_{n+1}, −v_max, v_max),

F the normal force of the particles on the wall (compression positive), A the wall area, n_c the number of
particles touching it. A positive v moves the wall outward (unloading). α and β are set per wall: the
platens (every wall of the membrane cell) keep YADE's proportional servo, α = 0.1 and β = 0, to the bit
(u stays 0); the rigid cell's lateral walls take α = :data:`LATERAL_SERVO_GAIN` and β = α/4
(:data:`LATERAL_INTEGRAL_FRACTION`).

Why the lateral walls need more. A specimen that pushes a wall out at a velocity v_d (Poisson's
expansion, then dilation, while shearing) is a ramp disturbance of the wall force, dF/dt = K_w (v_d − v),
with K_w = r k_n n_c the wall's stiffness (its contact springs in series with whatever the spheres behind
them do, 0 < r ≤ 1). A proportional servo moves at v_d only once v_P = v_d, a standing error

    σ − σ_target = k_n (n_c/A) Δt v_d / α,

independent of r: ~6 kPa at α = 0.1 with n_c/A ≈ 1/D² for spheres of D = 25 mm and k_n = 1e7 N/m,
Δt = 1.4e-5 s and v_d ≈ ε̇ R/2 = 2.9 mm/s (ε̇ = 0.078 /s, I = 1e-3 at 10 kPa; R = 75 mm). Measured on 251
dense equal spheres at σc = 10 kPa, I = 1e-3: σ3 = 15–21 kPa at α = 0.1 and 10.8–12.4 kPa at α = 0.5 while
the specimen dilated. The integral term is the servo's own estimate of v_d (at rest u = v_d and v_P = 0): a
ramp leaves no standing error, and a dilation rate that changes over a time t_d leaves a fraction ~T_I/t_d
of it, T_I = Δt/β the integral time. Stability bounds α and β. The step moves the walls at the velocity
set from the previous step's force (:func:`membrax.spheres.integrate.sphere_dem`: forces, walls advanced,
then this servo), a delay of one step; per step, with g = α r and x = K_w Δt v,

    e_{n+1} = e_n − x_{n−1} + K_w Δt v_d,   x_n = g e_n + βg Σ_{k≤n} e_k,

whose characteristic polynomial is z³ − 2z² + (1 + g(1 + β)) z − g (β = 0: z² − z + g). The proportional
servo is critically damped at g = 1/4 (a double root 1/2) and marginal at g = 1 (|z| = 1: the wall's force
rings undamped). The integral root stays real and slow (the PI loop on an integrating process, T_I ≳ 4 τ_P,
τ_P = Δt/g; Åström & Hägglund, *Advanced PID Control*, ISA 2006) for β ≲ g/4: β = α/4. r is the wall's
stiffness on the loop's own time scale, a few steps against ~22 for a sphere's oscillation on its wall
contact (2π √(m/k_n)/Δt at the default Δt), so the sphere barely moves while the servo corrects and r ≈ 1.
α = 0.5 (roots 0.86 and 0.57 ± 0.51i with β = α/4) is underdamped: a kick to a wall's force overshoots once
by about a third and has decayed to 10 % after one period of ~9 steps (0.12 ms at Δt = 1.4e-5 s), far
inside the records (every 25–250 steps) and the ~0.1 s (1 % of axial strain at I = 1e-3) over which the
dilation rate builds. It is the gain measured to hold σ3 best against the packing's own fluctuations
(251 dense spheres, 64 faces of ~2 contacts each, I = 1e-3, β = α/4, records every 100 steps past 0.2 %
axial strain: the largest |σ3/σc − 1| 2.6 % at α = 0.25, the critically damped gain, 2.0 % at 0.4, 1.9 %
at 0.5; 15 % at α = 1 with β = α/16, each lateral wall off σc by a median 27 %, the marginal loop ringing).
u is clipped to the speed limit (anti-windup) but not frozen while a wall touches nothing: frozen, u forgets
the time a wall spends in the air, where the error is −σ_target A, and σ3 came out 5–14 % low.

Ramp (YADE's ``UniaxialStrainer.initAccelTime``): a constant-velocity wall does not jump to its velocity;
it approaches ``target_velocity`` at a bounded ``acceleration`` (m/s², per wall and member),

    v_{n+1} = v_n + clip(v_target − v_n, −a Δt, a Δt),

so a platen started from rest reaches speed v over v/a. A step change sends a stress wave through the
specimen whose inertial overshoot is the "peak" a dense lattice shows at ~0.01 % strain; a ramp long
against the wave transit time removes it. ``acceleration`` = inf (the default) is the step change.

Areas: the lateral planes bound a polygon (the specimen's cross-section, area A_xy); platens have area A_xy
and lateral face k has area (length of polygon edge k) × (platen separation). Without lateral walls the
platen area must be given (the membrane test updates it from the membrane).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from membrax import pytree
from membrax.compensated import compensated_add
from membrax.validation import check_range

__all__ = [
    "BOTTOM",
    "LATERAL_INTEGRAL_FRACTION",
    "LATERAL_SERVO_GAIN",
    "TOP",
    "WallState",
    "affine_velocity",
    "change_speed",
    "advance_walls",
    "cross_section",
    "platen_separation",
    "ramp_acceleration",
    "ramped_velocity",
    "servo_control",
    "set_control",
    "triaxial_walls",
    "wall_areas",
]

BOTTOM = 0
TOP = 1
#: α of the rigid cell's lateral servo walls (module docstring, "Why the lateral walls need more").
LATERAL_SERVO_GAIN = 0.5
#: β/α of the rigid cell's lateral servo walls: the integral root real and slow (module docstring).
LATERAL_INTEGRAL_FRACTION = 0.25


@pytree.dataclass
class WallState:
    """Planes of a triaxial cell for B batch members (see the module docstring).

    Attributes:
      normal: (W, 3) outward unit normals, shared by all members.
      position: (B, W) plane positions h, m.
      position_compensation: (B, W) low-order part of h (compensated summation; h + this is exact to
        ~float64 resolution even in float32, see :func:`membrax.compensated.compensated_add`).
      velocity: (B, W) dh/dt, m/s.
      target_velocity: (B, W) the velocity a constant-velocity wall ramps to, m/s (module docstring).
      acceleration: (B, W) the largest |dv/dt| of a constant-velocity wall, m/s² (inf: no ramp).
      servo: (B, W) bool, stress-controlled walls.
      target_stress: (B, W) servo target, Pa (compression positive).
      max_speed: (B, W) servo speed limit, m/s.
      servo_gain: (B, W) α, the fraction of the force error the proportional term closes per step.
      servo_integral_gain: (B, W) β, the fraction of the proportional velocity the integral term adds per
        step (0: a proportional servo; module docstring).
      servo_integral_velocity: (B, W) the integral term u, m/s (0 at the start of every stage).
      force: (B, W) normal force of the particles on each wall at the last step, N.
      contacts: (B, W) number of particles touching each wall at the last step.
    """

    normal: jnp.ndarray
    position: jnp.ndarray
    position_compensation: jnp.ndarray
    velocity: jnp.ndarray
    target_velocity: jnp.ndarray
    acceleration: jnp.ndarray
    servo: jnp.ndarray
    target_stress: jnp.ndarray
    max_speed: jnp.ndarray
    servo_gain: jnp.ndarray
    servo_integral_gain: jnp.ndarray
    servo_integral_velocity: jnp.ndarray
    force: jnp.ndarray
    contacts: jnp.ndarray

    @property
    def num_walls(self) -> int:
        """W."""
        return self.normal.shape[0]

    @property
    def num_lateral(self) -> int:
        """Number of lateral walls (W − 2)."""
        return self.normal.shape[0] - 2


def triaxial_walls(
    lateral_normals,
    lateral_positions,
    height: float,
    num_members: int = 1,
    target_stress: float = 0.0,
    max_speed: float = 1.0,
    servo_gain: float = 0.1,
    lateral_servo_gain: float | None = None,
    lateral_integral_gain: float = 0.0,
    dtype=None,
) -> WallState:
    """Platens at z = 0 and z = ``height`` and lateral planes at the given positions, all at rest.

    Args:
      lateral_normals: (F, 2) outward horizontal unit normals, counter-clockwise; (0, 2) for none.
      lateral_positions: (F,) distances of the planes from the axis, m.
      height: platen separation, m, > 0.
      num_members: B, the batch size.
      target_stress: initial servo target for every wall, Pa.
      max_speed: servo speed limit, m/s, > 0.
      servo_gain: the platens' α, in (0, 1].
      lateral_servo_gain: the lateral walls' α, in (0, 1] (default ``servo_gain``).
      lateral_integral_gain: the lateral walls' β, in [0, α/4] (the integral root stays real, module
        docstring); the platens' is 0, a proportional servo.
      dtype: float dtype of the arrays (default: JAX's default float).
    """
    check_range("height", height, lower=0.0, lower_open=True)
    check_range("max_speed", max_speed, lower=0.0, lower_open=True)
    check_range("servo_gain", servo_gain, lower=0.0, upper=1.0, lower_open=True)
    lateral_servo_gain = servo_gain if lateral_servo_gain is None else lateral_servo_gain
    check_range("lateral_servo_gain", lateral_servo_gain, lower=0.0, upper=1.0, lower_open=True)
    check_range(
        "lateral_integral_gain",
        lateral_integral_gain,
        lower=0.0,
        upper=0.25 * lateral_servo_gain,
        hint="above about α/4 the integral root turns complex and the wall rings (module docstring)",
    )
    dtype = dtype or jnp.result_type(float)
    lateral_normals = np.asarray(lateral_normals, dtype=float).reshape(-1, 2)
    lateral_positions = np.asarray(lateral_positions, dtype=float).reshape(-1)
    normal = np.zeros((2 + lateral_normals.shape[0], 3))
    normal[BOTTOM] = (0.0, 0.0, -1.0)
    normal[TOP] = (0.0, 0.0, 1.0)
    normal[2:, :2] = lateral_normals
    position = np.concatenate([[0.0, height], lateral_positions])
    shape = (num_members, normal.shape[0])
    gain = np.full(shape, servo_gain)
    gain[:, 2:] = lateral_servo_gain
    integral_gain = np.zeros(shape)
    integral_gain[:, 2:] = lateral_integral_gain
    return WallState(
        normal=jnp.asarray(normal, dtype=dtype),
        position=jnp.asarray(np.broadcast_to(position, shape), dtype=dtype),
        position_compensation=jnp.zeros(shape, dtype=dtype),
        velocity=jnp.zeros(shape, dtype=dtype),
        target_velocity=jnp.zeros(shape, dtype=dtype),
        acceleration=jnp.full(shape, jnp.inf, dtype=dtype),
        servo=jnp.zeros(shape, dtype=bool),
        target_stress=jnp.full(shape, target_stress, dtype=dtype),
        max_speed=jnp.full(shape, max_speed, dtype=dtype),
        servo_gain=jnp.asarray(gain, dtype=dtype),
        servo_integral_gain=jnp.asarray(integral_gain, dtype=dtype),
        servo_integral_velocity=jnp.zeros(shape, dtype=dtype),
        force=jnp.zeros(shape, dtype=dtype),
        contacts=jnp.zeros(shape, dtype=jnp.int32),
    )


def platen_separation(walls: WallState):
    """Specimen height between the platens, h_top + h_bottom (the bottom plane is z = −h_bottom); (B,)."""
    return walls.position[:, TOP] + walls.position[:, BOTTOM]


def affine_velocity(position, walls: WallState, member):
    """The strain-controlled walls' affine velocity field at each sphere, (N, 3), m/s: the damping reference.

    Only walls moved at an imposed velocity count (``walls.servo`` false: the platens while shearing);
    servo-controlled walls count as at rest. A servo's velocity is a control signal, not a deformation
    rate: α (F − σA)/(k_n n_c Δt), clipped, it jumps whenever a contact opens or closes (n_c) and chatters
    about its target, and a reference tied to it would pass every jump to every sphere's damping (measured
    on ``tests/test_gradients.py``'s rollout of the smooth mode, 1,000 steps of consolidation and 1,000 of
    shearing: reverse mode and central differences then differed by up to 2.5e-3, against 2.3e-4 with
    absolute damping and 1.7e-4 with this rule). So consolidation, all walls servo-held, damps absolute
    velocities as before, bit for bit.

    Axially, a homogeneous deformation between the bottom platen (height z_b, velocity v_b along z) and the
    top one (z_t, v_t) moves a point at height z with

        v_ref,z = v_b + (v_t − v_b) s,   s = clip((z − z_b)/(z_t − z_b), 0, 1),

    linear interpolation of the two platen velocities (a uniform strain rate ε̇_a = −(v_t − v_b)/(z_t − z_b)
    whose ends ride on the platens); s is clipped so that a sphere outside the platens, which a closed cell
    does not have, takes the nearer platen's velocity. z_b = −h_0 and v_b = −dh_0/dt (the bottom plane's
    normal is −e_z, module docstring).

    Laterally, with strain-controlled lateral walls (none in the membrane cell; the rigid cell's are
    servo-held at σc, so there the lateral field is 0), the isotropic radial field of the polygon's area
    rate about its centroid c,

        v_ref,xy = ε̇_r (x − c),   ε̇_r = (dA/dt)/(2A) = Σ_k L_k v_k / (2A),

    L_k and v_k the length and outward velocity of face k (dA/dt = Σ_k L_k v_k for planes moving along
    their normals; a regular polygon of apothem d gives ε̇_r = v/d, each face moving with the field); faces
    moving at different velocities give their length-weighted mean.

    Each sphere reads its own member's walls (one row of ``walls`` per member), so a folded batch or a
    ``vmap`` over members damps each in its own field.

    Args:
      position: (N, 3) sphere centres, m.
      walls: the walls (platens 0 and 1, lateral faces after).
      member: (N,) int32 batch member of each sphere.

    Returns:
      (N, 3) v_ref, m/s; exactly 0 where every wall of the sphere's member is at rest or servo-controlled.
    """

    def per_sphere(values):  # (B,) -> each sphere's member's value; one member: a scalar, no gather
        return values[0] if values.shape[0] == 1 else values[member]

    imposed = jnp.where(walls.servo, 0.0, walls.velocity)  # (B, W): servo walls count as at rest
    z_bottom = -(walls.position[:, BOTTOM] + walls.position_compensation[:, BOTTOM])
    z_top = walls.position[:, TOP] + walls.position_compensation[:, TOP]
    v_bottom = -imposed[:, BOTTOM]
    v_top = imposed[:, TOP]
    fraction = jnp.clip((position[:, 2] - per_sphere(z_bottom)) / per_sphere(z_top - z_bottom), 0.0, 1.0)
    axial = per_sphere(v_bottom) + per_sphere(v_top - v_bottom) * fraction
    if walls.num_lateral == 0:
        zeros = jnp.zeros_like(axial)
        return jnp.stack([zeros, zeros, axial], axis=1)
    vx, vy, edge_lengths, area = _polygon(walls)
    rate = jnp.sum(edge_lengths * imposed[:, 2:], axis=1) / (2.0 * area)  # (B,)
    # The area centroid of the polygon (shoelace moments), edge k from vertex k − 1 to vertex k.
    previous_vx, previous_vy = jnp.roll(vx, 1, axis=1), jnp.roll(vy, 1, axis=1)
    cross_term = previous_vx * vy - vx * previous_vy
    centre_x = jnp.sum((previous_vx + vx) * cross_term, axis=1) / (6.0 * area)
    centre_y = jnp.sum((previous_vy + vy) * cross_term, axis=1) / (6.0 * area)
    lateral_x = per_sphere(rate) * (position[:, 0] - per_sphere(centre_x))
    lateral_y = per_sphere(rate) * (position[:, 1] - per_sphere(centre_y))
    return jnp.stack([lateral_x, lateral_y, axial], axis=1)


def _polygon(walls: WallState):
    """Vertices (x, y) (B, F), edge lengths (B, F) and area (B,) of the lateral planes' polygon.

    Vertex k is the intersection of planes k and k+1 (2×2 solve, Cramer's rule); edge k runs from vertex
    k−1 to k; the area by the shoelace formula.
    """
    normals = walls.normal[2:, :2]
    positions = walls.position[:, 2:]
    next_normals = jnp.roll(normals, -1, axis=0)
    next_positions = jnp.roll(positions, -1, axis=1)
    nx, ny = normals[None, :, 0], normals[None, :, 1]
    next_nx, next_ny = next_normals[None, :, 0], next_normals[None, :, 1]
    # Cramer's rule for [n_k; n_k+1] v = [h_k; h_k+1].
    det = nx * next_ny - ny * next_nx
    vx = (positions * next_ny - next_positions * ny) / det
    vy = (nx * next_positions - next_nx * positions) / det
    previous_vx = jnp.roll(vx, 1, axis=1)
    previous_vy = jnp.roll(vy, 1, axis=1)
    edge_lengths = jnp.sqrt((vx - previous_vx) ** 2 + (vy - previous_vy) ** 2)
    area = 0.5 * jnp.sum(previous_vx * vy - vx * previous_vy, axis=1)
    return vx, vy, edge_lengths, area


def cross_section(walls: WallState):
    """Area and edge lengths of the polygon bounded by the lateral planes.

    Vertex k is the intersection of planes k and k+1 (2×2 solve); edge k runs from vertex k−1 to k.
    Area by the shoelace formula.

    Returns:
      (area (B,), edge_lengths (B, F)), m² and m.
    """
    _, _, edge_lengths, area = _polygon(walls)
    return area, edge_lengths


def wall_areas(walls: WallState, platen_area=None):
    """Area of every wall, (B, W), m².

    Args:
      walls: the walls.
      platen_area: (B,) or scalar platen area; required when there are no lateral walls, otherwise the
        lateral polygon's area is used.
    """
    height = platen_separation(walls)
    if walls.num_lateral > 0:
        polygon_area, edge_lengths = cross_section(walls)
        platens = polygon_area if platen_area is None else jnp.broadcast_to(platen_area, polygon_area.shape)
        lateral = edge_lengths * height[:, None]
        return jnp.concatenate([platens[:, None], platens[:, None], lateral], axis=1)
    if platen_area is None:
        raise ValueError("platen_area is required when there are no lateral walls.")
    platens = jnp.broadcast_to(jnp.asarray(platen_area, dtype=height.dtype), height.shape)
    return jnp.stack([platens, platens], axis=1)


def servo_control(walls: WallState, dt, normal_stiffness, platen_area=None) -> WallState:
    """``walls`` with new velocities and integral terms (B, W): the servo law, or the ramp (module docstring).

    Args:
      walls: the walls, with the particles' ``force`` and ``contacts`` of this step.
      dt: Δt, s.
      normal_stiffness: k_n of the sphere–wall contacts, N/m; a scalar or (B,).
      platen_area: as in :func:`wall_areas`.
    """
    area = wall_areas(walls, platen_area)
    error = walls.force - walls.target_stress * area
    stiffness = jnp.reshape(normal_stiffness, (-1, 1)) * jnp.maximum(walls.contacts, 1).astype(area.dtype)
    proportional = walls.servo_gain * error / (stiffness * dt)
    # Anti-windup by the speed limit; u keeps counting while a wall touches nothing (module docstring).
    accumulated = walls.servo_integral_velocity + walls.servo_integral_gain * proportional
    integral = jnp.where(
        walls.servo, jnp.clip(accumulated, -walls.max_speed, walls.max_speed), walls.servo_integral_velocity
    )
    servo = jnp.clip(proportional + integral, -walls.max_speed, walls.max_speed)
    velocity = jnp.where(walls.servo, servo, ramped_velocity(walls, dt))
    return walls.set(velocity=velocity, servo_integral_velocity=integral)


def ramped_velocity(walls: WallState, dt):
    """V + clip(v_target − v, −a Δt, a Δt) for every wall (B, W): the ramp of the module docstring."""
    step = walls.acceleration * dt
    return walls.velocity + jnp.clip(walls.target_velocity - walls.velocity, -step, step)


def ramp_acceleration(velocity, strain_rate: float, ramp_strain: float):
    """|dv/dt| of a linear ramp from rest that reaches ``velocity`` at axial strain ``ramp_strain``, m/s².

    Under a ramp of duration t_r the strain grows as ½ ε̇ t_r by full speed, so ½ ε̇ t_r = ε_r gives
    a = |v| / t_r = |v| ε̇ / (2 ε_r) (YADE's ``UniaxialStrainer.initAccelTime`` idea). inf (no ramp, for
    :func:`set_control`) where ``ramp_strain`` is 0 or the velocity is 0. Traceable in ``velocity`` and
    ``strain_rate`` (``ramp_strain`` is a Python float).

    Args:
      velocity: target wall velocities, m/s (any shape).
      strain_rate: ε̇ at full speed, 1/s.
      ramp_strain: ε_r, the axial strain at full speed, >= 0.
    """
    traced = isinstance(velocity, jax.Array) or isinstance(strain_rate, jax.Array)
    xp = jnp if traced else np  # host values stay float64
    velocity = xp.asarray(velocity) if traced else np.asarray(velocity, dtype=float)
    if ramp_strain <= 0.0:
        return xp.full(velocity.shape, xp.inf)
    return xp.where(velocity != 0.0, xp.abs(velocity) * strain_rate / (2.0 * ramp_strain), xp.inf)


def set_control(walls: WallState, servo, velocity, target_stress, acceleration=np.inf) -> WallState:
    """A copy of ``walls`` with every wall's mode, velocity, servo target and ramp set (one stage's controls).

    Each argument is a scalar, (B,) (one value per member) or (B, W). Constant-velocity walls start at
    ``velocity`` at once where ``acceleration`` is inf, and from rest, ramping to it at ``acceleration``
    (m/s²), elsewhere (module docstring).

    Args:
      walls: the walls to change.
      servo: stress-controlled (True) or constant-velocity (False).
      velocity: the constant-velocity walls' dh/dt, m/s.
      target_stress: the servo walls' target, Pa.
      acceleration: the ramp's |dv/dt|, m/s², > 0 (inf: no ramp).
    """

    def full(value, like):
        value = jnp.asarray(value, like.dtype)  # traceable: stages may be set inside jit or vmap
        value = value[:, None] if value.ndim == 1 else value
        return jnp.broadcast_to(value, like.shape)

    servo = full(servo, walls.servo)
    target_velocity = full(velocity, walls.velocity)
    acceleration = full(acceleration, walls.acceleration)
    return walls.set(
        servo=servo,
        servo_integral_velocity=jnp.zeros_like(walls.servo_integral_velocity),  # a stage starts afresh
        velocity=jnp.where(jnp.isinf(acceleration), target_velocity, 0.0).astype(walls.velocity.dtype),
        target_velocity=target_velocity,
        acceleration=acceleration,
        target_stress=full(target_stress, walls.target_stress),
    )


def change_speed(walls: WallState, factor: float, strain_rate: float, ramp_strain: float) -> WallState:
    """A copy of ``walls`` whose constant-velocity walls go ``factor`` times as fast, changing speed linearly.

    A strain-controlled stage that changes its strain rate from ε̇₁ = ``strain_rate`` to ε̇₂ = factor ε̇₁ keeps
    each wall's current velocity and ramps it to factor × its target (:func:`ramped_velocity`). The change
    lasts t = 2 ε_t/(ε̇₁ + ε̇₂), the time in which the mean rate covers the strain ε_t = ``ramp_strain``, so
    a = |v₂ − v₁|/t; ``ramp_strain`` = 0 is a step change (a = inf). Servo walls are left as they are.

    Args:
      walls: the walls of a strain-controlled stage.
      factor: ε̇₂/ε̇₁, > 0.
      strain_rate: ε̇₁, 1/s.
      ramp_strain: ε_t, the axial strain over which the speed changes, >= 0.
    """
    check_range("factor", factor, lower=0.0, lower_open=True)
    check_range("ramp_strain", ramp_strain, lower=0.0, upper=1.0, upper_open=True)
    target = jnp.where(walls.servo, walls.target_velocity, factor * walls.target_velocity)
    change = jnp.abs(target - walls.target_velocity)
    # a = |v₂ − v₁|/t = |Δv| (ε̇₁ + ε̇₂)/(2 ε_t): the ramp from rest's law with Δv and ε̇₁ + ε̇₂.
    ramp = ramp_acceleration(change, strain_rate * (1.0 + factor), ramp_strain)
    acceleration = jnp.where(change > 0.0, ramp, walls.acceleration)
    return walls.set(
        target_velocity=target.astype(walls.target_velocity.dtype),
        acceleration=acceleration.astype(walls.acceleration.dtype),
    )


def advance_walls(walls: WallState, dt) -> WallState:
    """Move every plane by its velocity over one step (compensated summation)."""
    position, compensation = compensated_add(walls.position, walls.position_compensation, dt * walls.velocity)
    return walls.set(position=position, position_compensation=compensation)
