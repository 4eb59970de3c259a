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

Damping: Cundall's local damping (``local_damping``) and the MD quench of FIRE (:func:`_quench`: every
velocity is zeroed when the packing's power turns negative), which removes kinetic energy only.

Friction during compaction (``friction_coefficient``, between spheres; mould and platens are smooth, a
lubricated mould) sets the density: μ = 0 gives the densest random state (random close packing, solid
fraction ≈ 0.64 for equal spheres, Agnolin & Roux 2007), a larger μ arrests the rearrangements earlier and
leaves a looser packing (≈ 0.59 at μ = 0.3, same source). The test sets its own friction afterwards; the
contacts' tangential springs are not carried over.

The mould wall is a true cylinder: a frictionless sphere of radius r at distance ρ from the axis overlaps it
by δ = ρ + r − R_m, energy ½ k_w max(δ, 0)² (k_w the contact law's wall stiffness), force its gradient
(:func:`mould_energy`).

Frictionless: FIRE. Near jamming a damped dynamics relaxes slowly (the critical slowing down of jamming:
several 1e5 steps left the unbalanced-force ratio at 0.03 and the core coordination at 5.4–5.6). Without
friction the forces are conservative, so the packing at rest is an energy minimum, and the protocol of
O'Hern, Silbert, Liu & Nagel (2003, Phys. Rev. E 68, 011306) applies: the growth above stops when the
running stress first reaches the target (the dense fluid's dynamic stress, not yet a jammed network's); then
the growth factor is fixed and FIRE (``_FireRelaxer``; Bitzek et al. 2006) brings the spheres to rest; an
unjammed result (stress below 1 % of the target) grows s by a doubling step, a jammed one corrects s by a
secant step in ln s (bisecting once the target is bracketed), until the relaxed stress is within
``stress_tolerance`` of the target. With friction the servo above runs to the end.

Stress jumps. A jammed packing's relaxed stress is not a continuous function of s: where the contact network
rearranges it jumps, and FIRE from the last state can land on either branch. Measured on the paper-size
specimen (``benchmarks/bench_compaction.py``, float64): seed 8 relaxed to 7.73 kPa at s = 1.0169722844042632
and to 11.29 kPa at the next float64, nothing in the ±2 % window around 10 kPa; seed 5 from unjammed (~0)
to 35.5 kPa. When the bracket in s has closed to round-off (no growth of the packing's dtype lies strictly
between its ends) with no relaxed state in the window, the search relaxes to rest an end whose relaxation
stopped short (far from the target FIRE stops once the stress settles). Near jamming a settled stress can
be far from the stress at rest (the calibration grid's 300 × 600 mm seed-0 specimen: settled at 32.7 kPa,
2.0 kPa relaxed on): an end that at rest lies on the other side of the target, or in the window, was a false
end, and the search drops it and goes on from its state at rest. Otherwise it accepts the jammed state at
rest (ratio below 10 × the FIRE tolerance, as in the window's test) nearest the target in ratio,
|ln σ/σ_target| (its relaxed positions at its own growth), and records the jump in
:attr:`Compaction.stress_jump`;
``converged`` is True: the packing is jammed and at rest, and no growth the search can still try brings it
nearer the target. Callers that need the window check ``stress_jump is None``.

Budgets. Every host loop ends: the growth loop and each FIRE relaxation count steps against ``max_steps``
and run at least one step per compiled chunk; a relaxation that gets no FIRE step from a neighbour list
allocated afresh for its positions, and a search whose calls stop running FIRE steps without narrowing the
bracket (:data:`_IDLE_CALLS` in a row), raise :class:`membrax.errors.SimulationError` naming the growth, the
stress, the unbalanced-force ratio, the steps, the calls and the bracket.
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

from membrax.compensated import compensated_add
from membrax.driver import advance
from membrax.errors import SimulationError, describe
from membrax.spheres.contact import ContactParams, normal_energy
from membrax.spheres.fcc import fcc_specimen
from membrax.spheres.grading import (
    CLOUD_SOLID_FRACTION,
    Grading,
    RandomSpecimen,
    loose_cloud,
    sample_diameters,
)
from membrax.spheres.integrate import (
    DEFAULT_SAFETY,
    DampingParams,
    DEMParams,
    compute_forces,
    critical_time_step,
    make_particles,
    sphere_dem,
)
from membrax.spheres.measure import unbalanced_force_ratio
from membrax.spheres.neighbors import pair_neighbor_fn
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.spheres.walls import BOTTOM, TOP, triaxial_walls
from membrax.validation import check_range

__all__ = [
    "SOLID_FRACTION_GUESS",
    "Compaction",
    "compact",
    "compaction_time_step",
    "mould_energy",
    "packing_measures",
    "random_packing",
]

#: The whole-specimen solid fraction :func:`random_packing` samples spheres for (the specimen's size then
#: comes out as the requested one times (guess/achieved)^(1/3)).
SOLID_FRACTION_GUESS = 0.58

#: The calls in a row, each running no FIRE step and leaving the growth bracket as it was, after which the
#: frictionless search stops (:class:`membrax.errors.SimulationError`). Such a call relaxed the positions it
#: was given at a growth whose logarithm is already an end of the bracket (a secant step rounded onto it), so
#: it learnt nothing; a step that finds anything new runs FIRE or narrows the bracket and resets the count.
#: 64, the bits of a float64, is far more than roundings repeat in a row, and ends a stuck search within a
#: second: an idle call is one force evaluation (on the paper-size seed-8 specimen, 1,740 spheres in
#: float64, the search before jumps were accepted repeated 3,963 of them in 55 s).
_IDLE_CALLS = 64


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


def mould_energy(position, radius, mould_radius, stiffness):
    """Σ_i ½ k_w max(ρ_i + r_i − R_m, 0)², J: the spheres' overlap with a smooth cylinder on the z axis.

    Args:
      position: (N, 3) centres, m.
      radius: (N,) radii, m.
      mould_radius: R_m, m.
      stiffness: k_w, N/m.
    """
    rho = jnp.sqrt(position[:, 0] ** 2 + position[:, 1] ** 2 + jnp.finfo(position.dtype).tiny)
    return jnp.sum(normal_energy(rho + radius - mould_radius, stiffness))


def _quench(before, after):
    """Stop every sphere when the packing's power P = Σ F·v turns negative.

    The MD quench of FIRE (Bitzek et al. 2006), with the step's own velocity change for F: it removes kinetic
    energy only, at the moments the packing moves uphill in energy; a packing at rest is unchanged.
    """
    power = jnp.sum((after.velocity - before.velocity) * before.velocity) + jnp.sum(
        (after.angular_velocity - before.angular_velocity) * before.angular_velocity
    )
    uphill = power < 0.0
    return after.set(
        velocity=jnp.where(uphill, 0.0, after.velocity),
        angular_velocity=jnp.where(uphill, 0.0, after.angular_velocity),
    )


def _mould_radial_load(mould_force, position):
    """The mould's radial load, N: the spheres push it outward by −Σ F_i·ρ̂_i (F_i its force on sphere i)."""
    rho = jnp.sqrt(jnp.sum(position[:, :2] ** 2, axis=1)) + jnp.finfo(position.dtype).tiny
    return -jnp.sum((mould_force[:, 0] * position[:, 0] + mould_force[:, 1] * position[:, 1]) / rho)


def _mean_stress(wall_force, radial_load, mould_radius, mould_height):
    """σ = (σ_a + 2σ_r)/3, Pa, of the mould and its platens.

    σ_a is the platens' mean normal force (``wall_force``: one member's (W,) wall forces) over the mould's
    area, σ_r the mould's radial load over its lateral area.
    """
    axial = 0.5 * (wall_force[BOTTOM] + wall_force[TOP]) / (math.pi * mould_radius**2)
    return (axial + 2.0 * radial_load / (2.0 * math.pi * mould_radius * mould_height)) / 3.0


def _unbalanced_ratio(net_force, forces, particles, neighbors):
    """The packing's unbalanced-force ratio (:func:`membrax.spheres.measure.unbalanced_force_ratio`)."""
    first = neighbors.idx[0]
    pair_member = particles.member[jnp.where(first < particles.num_particles, first, 0)]
    return unbalanced_force_ratio(net_force, forces, particles, pair_member)[0]


class _FireRelaxer:
    """Frictionless spheres at fixed radii relaxed to rest with FIRE, and the growth that gives a stress.

    FIRE (Bitzek, Koskinen, Gähler, Moseler & Gumbsch 2006, Phys. Rev. Lett. 97, 170201): semi-implicit
    Euler steps v ← v + Δt F/m, x ← x + Δt v, with, before each, the power P = F·v tested: downhill (P > 0)
    the velocity is turned toward the force, v ← (1 − α) v + α |v| F̂, and after ``N_min`` downhill steps the
    step grows (Δt ← min(f_inc Δt, Δt_max), α ← f_α α); uphill the spheres stop (v = 0), Δt ← f_dec Δt and α
    is reset. The parameters are the paper's (N_min 5, f_inc 1.1, f_dec 0.5, α₀ 0.1, f_α 0.99, Δt_max 10 Δt).
    It minimises the energy of the contacts, the platens and the mould, so it needs conservative forces: only
    for frictionless spheres. Masses only set the path, not the minimum.
    """

    def __init__(self, particles, params, frame, template, dt, mould_radius, mould_height, chunk_steps):
        self.particles, self.params, self.frame, self.template = particles, params, frame, template
        self.dt, self.mould_radius, self.mould_height = dt, mould_radius, mould_height
        self.chunk_steps = chunk_steps
        self.neighbors = None
        self._chunk = jax.jit(self._chunk_impl)
        self._measure = jax.jit(self._measure_impl)

    def _forces(self, position, compensation, neighbors, growth):
        """(net force (N, 3), Forces, the mould's force on the spheres (N, 3)) at rest."""
        zeros = jnp.zeros_like(position)
        state = self.template.set(
            position=position,
            position_compensation=compensation,
            velocity=zeros,
            angular_velocity=zeros,
            neighbors=neighbors,
            pair_spring=jnp.zeros((neighbors.idx.shape[1], 3), position.dtype),
        )
        touching = self.particles.set(radius=growth * self.particles.radius)
        forces = compute_forces(state, touching, self.params, self.dt, wall_friction=False)
        stiffness = self.params.contact.wall_normal_stiffness
        mould = -jax.grad(mould_energy)(position, touching.radius, self.mould_radius, stiffness)
        return forces.force + mould, forces, mould

    def _chunk_impl(self, carry, growth):
        mass = self.particles.mass[:, None]
        # Bitzek et al. cap the step at 10 Δt_MD; here Δt is already half the critical step of the stiffest
        # (FCC) contact network, and a random packing's is larger but not known in advance: 1.8 Δt.
        largest_step = 1.8 * self.dt

        def fire_step(carry, _params):
            position, compensation, velocity, neighbors, step, alpha, downhill_steps = carry
            neighbors = self.frame.update(position, neighbors)
            force, _, _ = self._forces(position, compensation, neighbors, growth)
            power = jnp.sum(force * velocity)
            downhill = power > 0.0
            speed = jnp.sqrt(jnp.sum(velocity * velocity))
            force_norm = jnp.sqrt(jnp.sum(force * force)) + jnp.finfo(force.dtype).tiny
            mixed = (1.0 - alpha) * velocity + alpha * speed * force / force_norm
            downhill_steps = jnp.where(downhill, downhill_steps + 1, 0)
            speeding = downhill & (downhill_steps > 5)
            step = jnp.where(speeding, jnp.minimum(1.1 * step, largest_step), step)
            step = jnp.where(downhill, step, 0.5 * step)
            alpha = jnp.where(speeding, 0.99 * alpha, jnp.where(downhill, alpha, 0.1))
            velocity = jnp.where(downhill, mixed, 0.0) + step * force / mass
            # Compensated: a step moves a sphere ~1e-9 m, below float32's resolution at 0.1 m.
            position, compensation = compensated_add(position, compensation, step * velocity)
            return position, compensation, velocity, neighbors, step, alpha, downhill_steps

        return advance(fire_step, carry, None, self.chunk_steps)

    def _measure_impl(self, position, compensation, neighbors, growth):
        """(σ = (σ_a + 2σ_r)/3 in Pa, unbalanced-force ratio, neighbour overflow) of the spheres at rest."""
        neighbors = self.frame.update(position, neighbors)
        net, forces, mould = self._forces(position, compensation, neighbors, growth)
        radial = _mould_radial_load(mould, position)
        stress = _mean_stress(forces.wall_total_force[0], radial, self.mould_radius, self.mould_height)
        ratio = _unbalanced_ratio(net, forces, self.particles, neighbors)
        return stress, ratio, neighbors.did_buffer_overflow

    def relax(self, position, growth, target, tolerance, max_steps, on_chunk=None, settle=True):
        """FIRE at growth s until the unbalanced-force ratio is below ``tolerance``.

        ``position`` is (x, compensation); returns ((x, compensation), σ, ratio, steps), the very arrays
        given when it ran no step. ``settle`` False relaxes to ``tolerance`` even far from the target (a
        state the search may accept, module docstring "Stress jumps"). Each pass measures, then runs a chunk
        of ``chunk_steps`` steps or returns: at most ``max_steps`` / ``chunk_steps`` + 1 passes, plus one
        neighbour-list reallocation per chunk.

        Raises:
          SimulationError: the neighbour list overflowed again at the positions it was just allocated for.
        """
        position, compensation = position
        dtype = position.dtype
        # One list for every relaxation (a new allocation may change its capacity and recompile the chunk).
        if self.neighbors is None:
            self.neighbors = self.frame.allocate(position)
        neighbors = self.neighbors
        carry = (
            position,
            compensation,
            jnp.zeros_like(position),
            neighbors,
            jnp.asarray(self.dt, dtype),
            jnp.asarray(0.1, dtype),
            jnp.asarray(0, jnp.int32),
        )
        growth = jnp.asarray(growth, dtype)
        steps, best, best_at, last_stress = 0, math.inf, 0, math.nan
        calls, reallocated = 0, False
        while True:
            stress, ratio, overflow = (float(x) for x in self._measure(*carry[:2], carry[3], growth))
            calls += 1
            if overflow:
                # A list allocated at these very positions holds their pairs: overflowing again, it never
                # will (non-finite positions, or a sphere outside the list's box).
                if reallocated:
                    finite = bool(np.isfinite(np.asarray(carry[0])).all())
                    raise SimulationError(
                        f"compaction: the FIRE relaxation at growth factor s = {float(growth)!r} overflowed "
                        f"its neighbour list again right after allocating it for the same positions (stress "
                        f"{stress:.6g} Pa, unbalanced-force ratio {ratio:.3g}, {steps} FIRE steps, {calls} "
                        f"calls, positions {'finite' if finite else 'NOT finite'}). "
                        + (
                            "A sphere has left the mould's neighbour box: check the mould's size against "
                            "the spheres (mould_diameter, mould_height) and the contact stiffness."
                            if finite
                            else "The relaxation went unstable (FIRE's step is capped at 1.8 times "
                            "compaction_time_step's): report the seed and the arguments of compact."
                        )
                    )
                self.neighbors = self.frame.allocate(carry[0])
                carry = (*carry[:3], self.neighbors, *carry[4:])
                reallocated = True
                continue
            if on_chunk is not None and steps:
                on_chunk(
                    {
                        "steps": steps,
                        "stress": stress,
                        "growth": float(growth),
                        "unbalanced_force_ratio": ratio,
                    }
                )
            # Unjammed (the contacts all open once at rest): nothing to converge, the growth must rise.
            unjammed = steps > 0 and stress < 1e-2 * target
            # At the round-off floor (float32: an unbalanced-force ratio of a few 1e-3) FIRE stalls.
            if ratio < 0.9 * best:
                best, best_at = ratio, steps
            stalled = steps - best_at >= 5 * self.chunk_steps
            # Far from the target, a settled stress is all the growth correction needs.
            settled = settle and abs(stress - last_stress) < 0.01 * abs(stress - target) and ratio < 0.1
            last_stress = stress
            done = ratio < tolerance or unjammed or stalled or settled
            if done or steps >= max_steps or not math.isfinite(ratio):
                return carry[:2], stress, ratio, steps
            carry = self._chunk(carry, growth)
            steps += self.chunk_steps
            reallocated = False

    def relax_to_stress(
        self,
        position,
        growth,
        target,
        stress_tolerance,
        tolerance,
        max_steps,
        on_chunk=None,
        accept_jump=True,
    ):
        """Relax, then correct the growth s until the relaxed stress is within ``stress_tolerance`` of target.

        A jammed frictionless packing's stress rises about linearly in ln s above its jamming point. An
        unjammed state (stress below 1 % of the target at rest) grows s by a step that doubles each time
        (from Δ ln s = 1e-3); a jammed one takes a secant step in
        ln s through the last jammed state (the first with the stiffness scale), bisecting instead once a
        state below and one above the target bracket it. Where the stress jumps over the window, the bracket
        closes to round-off and the jammed state at rest nearest the target is returned (module docstring,
        "Stress jumps"; ``accept_jump`` False searches on, for tests of the budget).

        Returns:
          (positions, growth, stress, ratio, steps, converged, jump): ``jump`` None, or the
          :attr:`Compaction.stress_jump` dict of an accepted jump.

        Raises:
          SimulationError: :data:`_IDLE_CALLS` calls in a row ran no FIRE step and left the bracket as it
            was, or the bracket closed with no jammed state at rest to accept.
        """
        mean_diameter = float(2.0 * jnp.mean(self.particles.radius))
        stiffness_scale = float(self.params.contact.normal_stiffness) / mean_diameter
        first_increment = 1e-3  # Δ ln s of the first growth of an unjammed state: a jamming distance's scale
        increment = first_increment
        below, above, previous = -math.inf, math.inf, None
        steps, stress, ratio = 0, math.nan, math.nan
        # The device sees s rounded to the packing's dtype: the bracket is closed when none lies inside.
        dtype = np.dtype(position[0].dtype)
        # (growth, stress) at the bracket's ends; the jammed state at rest nearest the target.
        low_end = high_end = closest = None
        end_states = {}  # "below"/"above": the relaxed state at that end of the bracket
        calls = idle = 0
        window = (target, stress_tolerance, 10.0 * tolerance)
        while steps < max_steps:
            position, stress, ratio, used = self.relax(
                position,
                growth,
                target,
                tolerance,
                max_steps - steps,
                on_chunk=None
                if on_chunk is None
                else lambda info, done=steps: on_chunk({**info, "steps": done + info["steps"]}),
            )
            steps += used
            calls += 1
            if not math.isfinite(ratio):
                break
            at_rest = ratio < 10.0 * tolerance
            if abs(stress / target - 1.0) < stress_tolerance and at_rest:
                return position, growth, stress, ratio, steps, True, None
            # Nearest in ratio, |ln σ/σ_target|: a jammed packing's stress spans decades above jamming, and a
            # difference would rank a barely jammed state (−99 %) above one at 2.01 times the target. A tie
            # goes to the later state: the bracket closes in, so it is the one nearer the jump.
            if at_rest and stress >= 1e-2 * target:
                if closest is None or abs(math.log(stress / target)) <= abs(math.log(closest[2] / target)):
                    closest = (position, growth, stress, ratio)
            bracket = (below, above)
            log_growth = math.log(growth)
            state = (position, growth, stress, ratio)
            if stress < 1e-2 * target:  # unjammed
                below, low_end, end_states["below"] = log_growth, (growth, stress), state
                step_to = log_growth + increment
                increment *= 2.0
            else:
                if stress < target:
                    below, low_end, end_states["below"] = log_growth, (growth, stress), state
                else:
                    above, high_end, end_states["above"] = log_growth, (growth, stress), state
                slope = stiffness_scale
                # A secant needs two distinct growths (a bisection can land on the previous one).
                if previous is not None and stress != previous[1] and log_growth != previous[0]:
                    slope = max((stress - previous[1]) / (log_growth - previous[0]), 1e-2 * stiffness_scale)
                previous = (log_growth, stress)
                step_to = log_growth + (target - stress) / slope
            # Progress: a FIRE step, or an end of the bracket moved in.
            idle = 0 if used or below > bracket[0] or above < bracket[1] else idle + 1
            where = (growth, stress, ratio, steps, calls, (low_end, high_end), window)
            if idle >= _IDLE_CALLS:
                raise SimulationError(
                    f"compaction: the search for the growth factor made no progress in {idle} calls in a row "
                    f"(no FIRE step, the bracket unchanged): {_describe_search(*where)}. No growth left to "
                    "try reaches the window: widen stress_tolerance, or report the seed and the arguments "
                    "of compact."
                )
            if accept_jump and low_end is not None and high_end is not None:
                low, high = dtype.type(low_end[0]), dtype.type(high_end[0])
                if not np.nextafter(low, high) < high:
                    # Closed: every further growth would repeat an end's, so the nearest state at rest is the
                    # answer. Only a jump gets here: one spacing of s (1.2e-7 in float32) moves a smooth
                    # branch's stress by ~1.2 k_n/d̄ × 1.2e-7 ≈ 60 Pa at k_n/d̄ = 4e8 Pa, under the window's
                    # 2 × 2 % of 10 kPa, so a bisection lands in the window before the bracket closes.
                    # Unless an end was a settled state short of rest that, at rest, lies on the other side of
                    # the target: then the bracket was false and the search goes on from that state.
                    reopened, used = self._relax_ends(
                        end_states, target, stress_tolerance, tolerance, max_steps - steps
                    )
                    steps += used
                    if reopened is not None:
                        position, growth, stress, ratio = end_states[reopened]
                        if reopened == "above":
                            above, high_end = math.inf, None
                        else:
                            below, low_end = -math.inf, None
                        del end_states[reopened]
                        # The unjammed calls inside the false bracket doubled the growth step (to e^(2^40)):
                        # start again from the jamming distance's scale.
                        previous, increment = None, first_increment
                        continue
                    closest, jump = self._accept_jump(end_states, closest, target, tolerance, where)
                    return *closest, steps, True, jump
            if not below < step_to < above:
                step_to = 0.5 * (below + above)
            growth = math.exp(step_to)
        return position, growth, stress, ratio, steps, False, None

    def _relax_ends(self, end_states, target, stress_tolerance, tolerance, max_steps):
        """Relax to rest each end of a closed bracket whose relaxation stopped short of rest.

        Far from the target FIRE stops once the stress settles, and near jamming a settled stress is not yet
        the stress at rest: measured on the calibration grid's 300 × 600 mm specimen of 25 mm spheres, seed 0,
        float64, a state that settled at 32.7 kPa (ratio 0.029) relaxed on to 2.0 kPa, under the 10 kPa
        target, so the bracket it closed was false.

        Args:
          end_states: {"below", "above"}: (positions, s, σ, ratio) at the bracket's ends; updated in place
            with the relaxed states.
          target: the target stress, Pa.
          stress_tolerance: the window's relative half-width.
          tolerance: the FIRE tolerance (at rest below 10×).
          max_steps: FIRE steps left.

        Returns:
          (the end, "below" or "above", whose state at rest crossed the target or lies in the window, or None;
          FIRE steps used).
        """
        steps = 0
        for end in ("above", "below"):
            end_position, end_growth, end_stress, end_ratio = end_states[end]
            if end_ratio < 10.0 * tolerance or end_stress < 1e-2 * target or steps >= max_steps:
                continue
            end_position, end_stress, end_ratio, used = self.relax(
                end_position, end_growth, target, tolerance, max_steps - steps, settle=False
            )
            steps += used
            end_states[end] = (end_position, end_growth, end_stress, end_ratio)
            crossed = end_stress < target if end == "above" else end_stress >= target
            in_window = abs(end_stress / target - 1.0) < stress_tolerance and end_ratio < 10.0 * tolerance
            if crossed or in_window:
                return end, steps
        return None, steps

    @staticmethod
    def _accept_jump(end_states, closest, target, tolerance, where):
        """The jammed state at rest nearest the target once the bracket closed on a jump (module docstring).

        Args:
          end_states: {"below", "above"}: (positions, s, σ, ratio) at the bracket's ends, relaxed to rest
            where they were short of it (:meth:`_relax_ends`).
          closest: the nearest state at rest so far, (positions, s, σ, ratio), or None.
          target: the target stress, Pa.
          tolerance: the FIRE tolerance (at rest below 10×).
          where: the search's state for :func:`_describe_search`.

        Returns:
          (closest state, the :attr:`Compaction.stress_jump` dict).

        Raises:
          SimulationError: no jammed state at rest to accept.
        """
        for end_position, end_growth, end_stress, end_ratio in end_states.values():
            if end_ratio < 10.0 * tolerance and end_stress >= 1e-2 * target:
                if closest is None or abs(math.log(end_stress / target)) < abs(math.log(closest[2] / target)):
                    closest = (end_position, end_growth, end_stress, end_ratio)
        if closest is None:
            raise SimulationError(
                "compaction: the stress jumps over the window between neighbouring growths and no jammed "
                f"state was at rest to accept: {_describe_search(*where)}. Lower fire_tolerance or raise "
                "max_steps so that each relaxation reaches rest."
            )
        (_, growth_below, stress_below, _), (_, growth_above, stress_above, _) = (
            end_states["below"],
            end_states["above"],
        )
        jump = {
            "stress_below": stress_below,
            "stress_above": stress_above,
            "growth_below": growth_below,
            "growth_above": growth_above,
            "stress_accepted": closest[2],
        }
        return closest, jump


def _describe_search(growth, stress, ratio, steps, calls, ends, window) -> str:
    """The state of :meth:`_FireRelaxer.relax_to_stress` in words, for an error message.

    ``ends``: the bracket's (s, σ) ends, each None until set; ``window``: (target σ, its relative tolerance,
    the unbalanced-force ratio at rest).
    """
    low, high = ("(none)" if end is None else f"s = {end[0]!r} at {end[1]:.6g} Pa" for end in ends)
    target, stress_tolerance, at_rest = window
    return (
        f"growth factor s = {growth!r}, relaxed stress {stress:.6g} Pa (target {target:.6g} Pa "
        f"± {stress_tolerance:.3g}), unbalanced-force ratio {ratio:.3g} (at rest below {at_rest:.3g}), "
        f"{steps} FIRE steps, {calls} calls, bracket below {low}, above {high}"
    )


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
        radial_load = _mould_radial_load(force, state_.position)
        before = state_
        state_ = _quench(before, step_fn(state_, params, sphere_force=force, contact_radius=contact_radius))
        # Collisions in the cloud load the walls in spikes; the control reads a running mean.
        stress = _mean_stress(state_.walls.force[0], radial_load, mould_radius, mould_height)
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
        return _unbalanced_ratio(net, forces, particles, state_.neighbors)

    carry = (state, jnp.asarray(start, dtype), jnp.asarray(0.0, dtype))
    began = time.perf_counter()
    steps, converged, ratio = 0, False, math.inf
    frictionless = friction_coefficient == 0.0
    while steps < max_steps:
        carry = chunk(carry)
        state, growth, stress = carry
        steps += chunk_steps
        if int(state.error):
            raise SimulationError(
                f"compaction failed at step {steps}: {describe(int(state.error))}; report the seed and the "
                "arguments of compact."
            )
        stress = float(stress)
        ratio = float(unbalanced(state, growth))
        if on_chunk is not None:
            on_chunk(
                {"steps": steps, "stress": stress, "growth": float(growth), "unbalanced_force_ratio": ratio}
            )
        if frictionless and stress > (1.0 - stress_tolerance) * target_stress:
            break  # jammed: FIRE finds the packing at rest (below)
        if abs(stress / target_stress - 1.0) < stress_tolerance and ratio < tolerance:
            converged = True
            break
    position, jump = (state.position, state.position_compensation), None
    if frictionless and steps < max_steps:
        relaxer = _FireRelaxer(particles, params, frame, state, dt, mould_radius, mould_height, chunk_steps)
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
