"""Random packings, second half: a loose cloud compacted in a rigid mould by radius expansion.

Contract. :func:`compact` takes sphere diameters (:func:`membrax.spheres.grading.sample_diameters`)
and a cylindrical mould (diameter and height, m), places the spheres, shrunk, as a loose random cloud in the
mould (:func:`membrax.spheres.grading.loose_cloud`), and grows them in the fixed mould until the mean
stress on the mould and its two platens is ``target_stress`` and the unbalanced-force ratio is below
``tolerance``. It returns a :class:`Compaction`: the centres and radii scaled back so that the radii are the
sampled ones (the mould shrinks by the same factor: the specimen's diameter and height are the mould's over
the final growth factor, within a few per cent of the requested ones), the run's figures and
:func:`packing_measures`. :func:`random_packing` samples a grading for a specimen size and compacts it.
Deterministic for a seed. Host side: it runs compiled chunks of ``chunk_steps`` steps and checks between
them; not traceable.

Procedure (YADE's ``TriaxialStressController`` with ``internalCompaction = True``; PFC's radius expansion).
Every radius is s R_i with one growth factor s; the masses are the final spheres' throughout (quasi-static
growth does not depend on them, and a fixed mass keeps the time step fixed). Each step multiplies s by
1 + g, from the running mean σ (over ``averaging_steps``) of σ = (σ_a + 2σ_r)/3, σ_a the platens' mean
normal force over the mould's area and σ_r the mould's radial force over its lateral area:

- below the target, g = ``growth_rate`` (1 − σ/σ_target): fast in the cloud, slowing as the packing takes
  load (the dynamic stress of a compressed dense fluid rises steeply near jamming, and the law holds it
  below the target);
- above the target, a servo closes a fraction ``servo_gain`` of the error per step through the jammed
  packing's stiffness scale K = k_n/d̄ (σ ≈ 1.2 K ln(s/s_J) for an isostatic packing of coordination 6, so
  K underestimates dσ/d ln s): g = clip(servo_gain (σ_target − σ)/K, −servo_growth, servo_growth).

Damping: Cundall's local damping (``local_damping``) and the MD quench of FIRE (:func:`quench`: every
velocity is zeroed when the packing's power turns negative), which removes kinetic energy only.

Friction during compaction (``friction_coefficient``, between spheres; mould and platens are smooth, a
lubricated mould) sets the density: μ = 0 gives the densest random state (random close packing, solid
fraction ≈ 0.64 for equal spheres, Agnolin & Roux 2007), a larger μ arrests the rearrangements earlier and
leaves a looser packing (≈ 0.59 at μ = 0.3, same source). The test sets its own friction afterwards; the
contacts' tangential springs are not carried over.

The mould: :mod:`membrax.spheres.mould`.

Frictionless: FIRE (:mod:`membrax.spheres.fire`) brings the grown packing to rest and searches the growth
factor for the target stress. With friction the servo above runs to the end.

"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import scipy.spatial

from membrax.driver import advance, drive, grow_tables
from membrax.errors import SimulationError, describe
from membrax.spheres.contact import ContactParams
from membrax.spheres.fcc import fcc_specimen
from membrax.spheres.fire import FireRelaxer, quench, unbalanced_ratio
from membrax.spheres.grading import (
    CLOUD_SOLID_FRACTION,
    Grading,
    RandomSpecimen,
    loose_cloud,
    sample_diameters,
)
from membrax.spheres.integrate import (
    DampingParams,
    DEMParams,
    compute_forces,
    make_particles,
    sphere_dem,
)
from membrax.spheres.mould import mould_energy, mould_mean_stress, mould_radial_load
from membrax.spheres.neighbors import pair_neighbor_fn
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.spheres.stability import DEFAULT_SAFETY, critical_time_step
from membrax.spheres.walls import triaxial_walls
from membrax.validation import check_range

__all__ = [
    "SOLID_FRACTION_GUESS",
    "Compaction",
    "compact",
    "compaction_time_step",
    "packing_measures",
    "random_packing",
]

#: The whole-specimen solid fraction :func:`random_packing` samples spheres for (the specimen's size then
#: comes out as the requested one times (guess/achieved)^(1/3)).
SOLID_FRACTION_GUESS = 0.58


@dataclasses.dataclass(frozen=True)
class Compaction:
    """A compacted packing (module docstring).

    Attributes:
      position: (N, 3) sphere centres, m, float64; the specimen stands on z = 0 with its axis on z.
      radius: (N,) the sampled radii, m.
      diameter: the mould's diameter over the final growth factor, m.
      height: the platens' separation over the final growth factor, m.
      growth: the final growth factor relative to the sampled radii (the mould was diameter × growth wide).
      steps: time steps run.
      seconds: wall-clock time of the run, s.
      stress: the final mean stress σ on mould and platens, Pa.
      unbalanced_force_ratio: at the end.
      converged: whether the packing ended jammed and at rest: the stop test held, or (frictionless) the
        state nearest the target was accepted at a stress jump (``stress_jump``). False: ``max_steps`` ran
        out first.
      measures: :func:`packing_measures` of the result.
      seed: the cloud's seed.
      stress_jump: None when the stress reached ``target_stress`` within ``stress_tolerance`` (or the run
        ended unconverged); else the jump that kept it out of the window (module docstring, "Stress
        jumps"): ``stress_below`` and ``stress_above`` (Pa), the relaxed stresses at the bracket's ends,
        ``growth_below`` and ``growth_above`` their growth factors (neighbouring numbers of the packing's
        dtype, or equal), and ``stress_accepted`` (Pa), the accepted state's stress (= ``stress``). Files
        saved before this field load with None.
    """

    position: np.ndarray
    radius: np.ndarray
    diameter: float
    height: float
    growth: float
    steps: int
    seconds: float
    stress: float
    unbalanced_force_ratio: float
    converged: bool
    measures: dict
    seed: int = 0
    stress_jump: dict | None = None

    def save(self, path) -> None:
        """Write the packing to ``path`` (``.npz``: the centres and radii as they are, the rest as JSON)."""
        scalars = {
            field.name: getattr(self, field.name)
            for field in dataclasses.fields(self)
            if field.name not in ("position", "radius")
        }
        scalars = json.loads(json.dumps(scalars, default=lambda value: np.asarray(value).item()))
        np.savez(path, position=self.position, radius=self.radius, scalars=json.dumps(scalars))

    @classmethod
    def load(cls, path) -> Compaction:
        """The packing :meth:`save` wrote to ``path`` (a field added since takes its default)."""
        with np.load(path) as data:
            scalars = json.loads(str(data["scalars"]))
            return cls(position=np.array(data["position"]), radius=np.array(data["radius"]), **scalars)

    def specimen(self, grading: Grading | None = None) -> RandomSpecimen:
        """The packing as a :class:`~membrax.spheres.grading.RandomSpecimen` (JAX's default float).

        Its ``packing_measures`` are :attr:`measures` and the compaction's stress: ``compaction_stress`` (Pa)
        and, where the stress jumped over the window (:attr:`stress_jump`), ``compaction_stress_below`` and
        ``compaction_stress_above`` (Pa, the jump's two sides).
        """
        dtype = jnp.result_type(float)
        measures = {**self.measures, "compaction_stress": float(self.stress)}
        if self.stress_jump is not None:
            measures["compaction_stress_below"] = float(self.stress_jump["stress_below"])
            measures["compaction_stress_above"] = float(self.stress_jump["stress_above"])
        return RandomSpecimen(
            position=jnp.asarray(self.position, dtype),
            radius=jnp.asarray(self.radius, dtype),
            diameter=self.diameter,
            height=self.height,
            grading=() if grading is None else (tuple(grading.sizes), tuple(grading.passing)),
            solid_fraction=self.measures["solid_fraction"],
            seed=self.seed,
            packing_measures=tuple(measures.items()),
        )


def packing_measures(
    position,
    radius,
    diameter: float,
    height: float,
    core_margin: float = 2.0,
    core_points: int = 200_000,
    least_contacts: int = 4,
) -> dict:
    """Solid fractions (whole, core), coordination number, rattlers and largest overlap of a packing.

    The core is the cylinder ``core_margin`` mean diameters inside the mould and the platens (the walls order
    the spheres within about two diameters of them). Its solid fraction is the fraction of ``core_points``
    random points (seed 0) inside a sphere (one standard error √(φ(1 − φ)/M) ≈ 0.001). The coordination
    number counts sphere–sphere contacts with overlap > 0 among the core's spheres that are not rattlers:
    core spheres with fewer than ``least_contacts`` contacts are removed, repeatedly (a removal lowers its
    neighbours' counts), as they carry no stable load (d + 1 = 4 for frictionless spheres, whose contact
    forces must not all lie in a plane; 2 for frictional ones, whose two opposite forces may balance within
    the friction cones); spheres outside the core are kept (their wall
    contacts are not counted, and removing them would strip the core from the outside in).

    Args:
      position: (N, 3) centres, m, the specimen standing on z = 0 on the z axis.
      radius: (N,) radii, m.
      diameter: the specimen's (mould's) diameter, m.
      height: platen separation, m.
      core_margin: in mean diameters.
      core_points: random points of the core's solid fraction.
      least_contacts: the fewest contacts of a sphere that is not a rattler.

    Returns:
      ``num_spheres``, ``solid_fraction``, ``core_solid_fraction``, ``core_spheres``,
      ``coordination_number``, ``rattler_fraction`` (of the core's spheres), ``max_overlap_fraction``
      (largest overlap over the mean diameter).
    """
    position = np.asarray(position, dtype=float)
    radius = np.asarray(radius, dtype=float)
    num = radius.size
    mould_radius = 0.5 * diameter
    mean_diameter = float(2.0 * radius.mean())
    tree = scipy.spatial.cKDTree(position)
    pairs = tree.query_pairs(2.0 * radius.max(), output_type="ndarray")
    gaps = np.linalg.norm(position[pairs[:, 1]] - position[pairs[:, 0]], axis=1)
    overlap = radius[pairs[:, 0]] + radius[pairs[:, 1]] - gaps
    touching = pairs[overlap > 0.0]
    margin = core_margin * mean_diameter
    core_radius, core_low, core_high = mould_radius - margin, margin, height - margin
    in_core = (
        (np.hypot(position[:, 0], position[:, 1]) < core_radius)
        & (position[:, 2] > core_low)
        & (position[:, 2] < core_high)
    )
    keep = np.ones(num, dtype=bool)
    while True:  # ends: each pass that goes on removes a sphere, so at most N passes
        live = touching[keep[touching[:, 0]] & keep[touching[:, 1]]]
        counts = np.bincount(live.ravel(), minlength=num)
        drop = keep & in_core & (counts < least_contacts)
        if not drop.any():
            break
        keep &= ~drop
    core_kept = keep & in_core
    core_fraction = math.nan
    if core_radius > 0.0 and core_high > core_low:
        rng = np.random.default_rng(0)
        rho = core_radius * np.sqrt(rng.random(core_points))
        theta = 2.0 * math.pi * rng.random(core_points)
        height_point = core_low + (core_high - core_low) * rng.random(core_points)
        points = np.stack([rho * np.cos(theta), rho * np.sin(theta), height_point], axis=1)
        distance, nearest = tree.query(points, k=min(8, num))
        core_fraction = float(np.any(distance < radius[nearest], axis=1).mean())
    solid = float(np.sum(4.0 / 3.0 * math.pi * radius**3))
    return {
        "num_spheres": num,
        "solid_fraction": solid / (math.pi * mould_radius**2 * height),
        "core_solid_fraction": core_fraction,
        "core_spheres": int(in_core.sum()),
        "coordination_number": float(counts[core_kept].mean()) if core_kept.any() else math.nan,
        "rattler_fraction": float(1.0 - core_kept.sum() / in_core.sum()) if in_core.any() else math.nan,
        "max_overlap_fraction": float(max(overlap.max(initial=0.0), 0.0) / mean_diameter),
    }


def compaction_time_step(smallest_diameter: float, contact_params: ContactParams, density: float) -> float:
    """Δt = ``DEFAULT_SAFETY`` × the critical step of an FCC block of the smallest spheres (s).

    The densest packing of the lightest sphere bounds the stiffest mode a compaction meets: in a random
    packing a sphere has fewer contacts than FCC's 12, and a heavier one a lower frequency.
    """
    block = fcc_specimen(smallest_diameter, 4, 4)
    particles = make_particles(block.radius, density)
    frame = pair_neighbor_fn(
        np.min(np.asarray(block.position), axis=0) - smallest_diameter,
        np.max(np.asarray(block.position), axis=0) + smallest_diameter,
        cutoff=smallest_diameter,
        skin=0.2 * smallest_diameter,
        margin=0.5 * smallest_diameter,
    )
    walls = triaxial_walls(np.zeros((0, 2)), np.zeros(0), block.height)
    init_fn, _ = sphere_dem(particles, frame, 1.0)
    state = init_fn(block.position, walls, frame.allocate(block.position))
    params = DEMParams(contact=contact_params, damping=DampingParams.none())
    return DEFAULT_SAFETY * critical_time_step(state, particles, params)


def compact(
    diameters,
    mould_diameter: float,
    mould_height: float,
    target_stress: float = 1e4,
    friction_coefficient: float = 0.0,
    seed: int = 0,
    contact_params: ContactParams | None = None,
    density: float = GRANITE_DENSITY,
    local_damping: float = 0.3,
    viscous_rate: float = 0.0,
    growth_rate: float | None = None,
    servo_gain: float = 0.02,
    servo_growth: float = 2e-6,
    averaging_steps: int = 50,
    stress_tolerance: float = 0.02,
    tolerance: float = 1e-2,
    max_steps: int = 400_000,
    chunk_steps: int = 1000,
    on_chunk: Callable[[dict], None] | None = None,
    fire_tolerance: float = 1e-3,
) -> Compaction:
    """Compact spheres of the given diameters in a cylindrical mould (module docstring).

    Args:
      diameters: (N,) the spheres' final diameters, m.
      mould_diameter: m; with ``mould_height`` it should hold the spheres at about the solid fraction
        expected (the specimen's size is the mould's over the final growth factor).
      mould_height: m.
      target_stress: σ_target, Pa, > 0.
      friction_coefficient: μ between spheres during compaction, >= 0 (0: the densest state).
      seed: the cloud's seed.
      contact_params: the contact law (default: the paper's stiffnesses); its friction is replaced by
        ``friction_coefficient`` and the walls made smooth.
      density: kg/m³.
      local_damping: Cundall's α.
      viscous_rate: γ, 1/s.
      growth_rate: g per step below the target, times 1 − σ/σ_target (default 5e-5 frictionless, where
        FIRE finishes the packing, and 1e-5 with friction, where the growth sets the density).
      servo_gain: above the target, the fraction of the stress error closed per step.
      servo_growth: above the target, the largest |g| per step.
      averaging_steps: time constant, in steps, of the running mean of σ the control reads.
      stress_tolerance: relative stress error accepted at the end.
      tolerance: unbalanced-force ratio accepted at the end.
      max_steps: give up after this many steps (``converged`` False).
      chunk_steps: steps per compiled chunk (the checks run between chunks).
      on_chunk: called after each chunk with a dict (``steps``, ``stress``, ``growth``,
        ``unbalanced_force_ratio``) — progress for long runs.
      fire_tolerance: frictionless compaction: the unbalanced-force ratio each FIRE relaxation reaches
        (module docstring, "Frictionless: FIRE").

    Raises:
      ValueError: an argument out of range, named with its accepted range.
      SimulationError: the frictionless search stalled (module docstring, "Budgets"); the message names
        the growth factor, stress, unbalanced-force ratio, steps, calls and bracket, and what to change.
        Also an error bit of the growth phase (non-finite positions, an overflowing neighbour list), named.
    """
    diameters = np.asarray(diameters, dtype=float)
    check_range("diameters", diameters, lower=0.0, lower_open=True)
    check_range("mould_diameter", mould_diameter, lower=float(diameters.max()), lower_open=True, hint="m.")
    check_range("mould_height", mould_height, lower=float(diameters.max()), lower_open=True, hint="m.")
    check_range("target_stress", target_stress, lower=0.0, lower_open=True, hint="Pa; 10 kPa is 1e4.")
    check_range("friction_coefficient", friction_coefficient, lower=0.0)
    # Each pass of the growth loop runs a chunk: with chunk_steps >= 1 it ends within max_steps.
    check_range("max_steps", max_steps, lower=1, hint="time steps, e.g. 400000.")
    check_range("chunk_steps", chunk_steps, lower=1, hint="steps per compiled chunk, e.g. 1000.")
    base = ContactParams.paper() if contact_params is None else contact_params
    law = base.set(
        friction_coefficient=jnp.asarray(friction_coefficient),
        wall_friction_coefficient=jnp.asarray(0.0),
    )
    params = DEMParams(
        contact=law,
        damping=DampingParams(
            local_coefficient=jnp.asarray(local_damping), viscous_rate=jnp.asarray(viscous_rate)
        ),
    )
    if growth_rate is None:
        growth_rate = 5e-5 if friction_coefficient == 0.0 else 1e-5
    mould_radius = 0.5 * mould_diameter
    solid = float(np.sum(math.pi / 6.0 * diameters**3))
    # The cloud: spheres shrunk so that they fill CLOUD_SOLID_FRACTION of the mould.
    start = (CLOUD_SOLID_FRACTION * math.pi * mould_radius**2 * mould_height / solid) ** (1.0 / 3.0)
    start = min(start, 1.0)
    order = np.argsort(-diameters, kind="stable")
    cloud, _ = loose_cloud(
        diameters[order] * start,
        mould_radius,
        solid_fraction=start**3 * solid / (math.pi * mould_radius**2 * mould_height),
        seed=seed,
    )
    position = np.empty_like(cloud)
    position[order] = cloud
    radius = 0.5 * diameters
    dt = compaction_time_step(float(diameters.min()), law, density)

    dtype = jnp.result_type(float)
    particles = make_particles(jnp.asarray(radius, dtype), density)
    largest = float(diameters.max())
    frame = pair_neighbor_fn(
        [-mould_radius, -mould_radius, 0.0],
        [mould_radius, mould_radius, mould_height],
        cutoff=1.1 * largest,
        skin=0.2 * largest,
        margin=largest,
    )
    walls = triaxial_walls(np.zeros((0, 2)), np.zeros(0), mould_height, dtype=dtype)
    init_fn, step_fn = sphere_dem(particles, frame, dt, wall_friction=False)
    state = init_fn(jnp.asarray(position, dtype), walls, frame.allocate(jnp.asarray(position, dtype)))
    mean_diameter = float(np.mean(diameters))
    wall_stiffness = law.wall_normal_stiffness
    stiffness_scale = float(law.normal_stiffness) / mean_diameter

    def one_step(carry, _params):
        state_, growth, average = carry
        contact_radius = growth * particles.radius
        force = -jax.grad(mould_energy)(state_.position, contact_radius, mould_radius, wall_stiffness)
        radial_load = mould_radial_load(force, state_.position)
        before = state_
        state_ = quench(before, step_fn(state_, params, sphere_force=force, contact_radius=contact_radius))
        # Collisions in the cloud load the walls in spikes; the control reads a running mean.
        stress = mould_mean_stress(state_.walls.force[0], radial_load, mould_radius, mould_height)
        average = average + (stress - average) / averaging_steps
        error = target_stress - average
        free = growth_rate * error / target_stress
        servo = jnp.clip(servo_gain * error / stiffness_scale, -servo_growth, servo_growth)
        return state_, growth * (1.0 + jnp.where(error > 0.0, free, servo)), average

    @jax.jit
    def chunk(carry):
        return advance(one_step, carry, None, chunk_steps)

    @jax.jit
    def unbalanced(state_, growth):
        touching = particles.set(radius=growth * particles.radius)
        forces = compute_forces(state_, touching, params, dt, wall_friction=False)
        net = forces.force - jax.grad(mould_energy)(
            state_.position, touching.radius, mould_radius, wall_stiffness
        )
        return unbalanced_ratio(net, forces, particles, state_.neighbors)

    carry = (state, jnp.asarray(start, dtype), jnp.asarray(0.0, dtype))
    began = time.perf_counter()
    frictionless = friction_coefficient == 0.0
    # Filled by each accepted chunk: the steps run, the last unbalanced-force ratio, whether it converged.
    done = {"steps": 0, "ratio": math.inf, "converged": False}

    def run_chunk(current, left, _num_records):
        return chunk(current), left - chunk_steps, None, None

    def grow(current, error, _overflowed):
        (grown,) = grow_tables([current[0]], int(error[0]), frame)
        return (grown, *current[1:])

    def failed(error, _new, _current):
        return SimulationError(
            f"compaction failed in the chunk ending at step {done['steps'] + chunk_steps}: "
            + "; ".join(describe(int(error[0])))
            + "; report the seed and the arguments of compact."
        )

    def accept(current, _records, _valid, _left):
        state_, growth_, stress_ = current
        done["steps"] += chunk_steps
        stress_ = float(stress_)
        done["ratio"] = ratio_ = float(unbalanced(state_, growth_))
        if on_chunk is not None:
            on_chunk(
                {
                    "steps": done["steps"],
                    "stress": stress_,
                    "growth": float(growth_),
                    "unbalanced_force_ratio": ratio_,
                }
            )
        if frictionless and stress_ > (1.0 - stress_tolerance) * target_stress:
            return [0]  # jammed: FIRE finds the packing at rest (below)
        done["converged"] = abs(stress_ / target_stress - 1.0) < stress_tolerance and ratio_ < tolerance
        return [0] if done["converged"] else []

    carry, _ = drive(
        run_chunk,
        carry,
        [max_steps],
        chunk_steps,
        chunk_steps,
        errors=lambda current: np.atleast_1d(np.asarray(current[0].error)),
        grow=grow,
        fail=failed,
        accept=accept,
    )
    state, growth, stress = carry
    stress = float(stress)
    steps, ratio, converged = done["steps"], done["ratio"], done["converged"]
    position, jump = (state.position, state.position_compensation), None
    if frictionless and steps < max_steps:
        relaxer = FireRelaxer(particles, params, frame, state, dt, mould_radius, mould_height, chunk_steps)
        position, growth, stress, ratio, fire_steps, converged, jump = relaxer.relax_to_stress(
            position,
            float(growth),
            target_stress,
            stress_tolerance,
            min(fire_tolerance, tolerance),
            max_steps - steps,
            on_chunk=None
            if on_chunk is None
            else lambda info: on_chunk({**info, "steps": steps + info["steps"]}),
        )
        steps += fire_steps
    final = float(growth)
    position = (np.asarray(position[0], dtype=float) + np.asarray(position[1], dtype=float)) / final
    return Compaction(
        position=position,
        radius=radius,
        diameter=mould_diameter / final,
        height=mould_height / final,
        growth=final,
        steps=steps,
        seconds=time.perf_counter() - began,
        stress=stress,
        unbalanced_force_ratio=ratio,
        converged=converged,
        measures=packing_measures(
            position,
            radius,
            mould_diameter / final,
            mould_height / final,
            least_contacts=4 if friction_coefficient == 0.0 else 2,
        ),
        seed=seed,
        stress_jump=jump,
    )


def random_packing(
    grading: Grading,
    specimen_diameter: float,
    specimen_height: float,
    seed: int = 0,
    solid_fraction_guess: float = SOLID_FRACTION_GUESS,
    **compaction,
) -> Compaction:
    """Spheres sampled from ``grading`` for a specimen of the given size (m), compacted (:func:`compact`).

    The spheres' volume is ``solid_fraction_guess`` of the specimen's; the compacted specimen's size is
    the requested one times (guess/achieved)^(1/3) (the radii stay the sampled ones). ``compaction``:
    further arguments of :func:`compact`.
    """
    check_range("specimen_diameter", specimen_diameter, lower=0.0, lower_open=True, hint="m.")
    check_range("specimen_height", specimen_height, lower=0.0, lower_open=True, hint="m.")
    check_range("solid_fraction_guess", solid_fraction_guess, lower=0.3, upper=0.74)
    volume = math.pi * specimen_diameter**2 / 4.0 * specimen_height
    diameters = sample_diameters(grading, solid_fraction_guess * volume, seed=seed)
    return compact(diameters, specimen_diameter, specimen_height, seed=seed, **compaction)
