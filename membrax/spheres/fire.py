"""FIRE in the mould: a frictionless packing brought to rest, and the growth factor giving a target stress.

Contract. :class:`FireRelaxer` relaxes a frictionless packing at a fixed growth factor s with FIRE
(:meth:`FireRelaxer.relax`) and searches s for a target mean stress on the mould
(:meth:`FireRelaxer.relax_to_stress`); :func:`membrax.spheres.compaction.compact` runs it after its growth
phase. Host side: compiled chunks of FIRE steps, checks between them; not traceable. :func:`quench` is FIRE's
MD quench, shared with the growth phase.

Frictionless: FIRE. Near jamming a damped dynamics relaxes slowly (the critical slowing down of jamming:
several 1e5 steps left the unbalanced-force ratio at 0.03 and the core coordination at 5.4–5.6). Without
friction the forces are conservative, so the packing at rest is an energy minimum, and the protocol of
O'Hern, Silbert, Liu & Nagel (2003, Phys. Rev. E 68, 011306) applies: the growth above stops when the
running stress first reaches the target (the dense fluid's dynamic stress, not yet a jammed network's); then
the growth factor is fixed and FIRE (:class:`FireRelaxer`; Bitzek et al. 2006) brings the spheres to rest; an
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
:attr:`membrax.spheres.compaction.Compaction.stress_jump`;
``converged`` is True: the packing is jammed and at rest, and no growth the search can still try brings it
nearer the target. Callers that need the window check ``stress_jump is None``.

Budgets. Every loop ends: the growth phase's chunks and each FIRE relaxation's run through
:func:`membrax.driver.drive` with ``max_steps`` as their budget (a chunk whose neighbour list overflowed is
run again from its start with a larger list, :func:`membrax.driver.grow_tables`; one whose positions are no
longer finite raises :class:`membrax.errors.SimulationError`); a relaxation whose positions overflow a list
allocated afresh for them, and a search whose calls stop running FIRE steps without narrowing the bracket
(:data:`IDLE_CALLS` in a row), raise :class:`membrax.errors.SimulationError` naming the growth, the stress,
the unbalanced-force ratio, the steps, the calls and the bracket.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from membrax.compensated import compensated_add
from membrax.driver import advance, drive, grow_tables
from membrax.errors import ErrorCode, SimulationError, describe, not_finite_bit
from membrax.spheres.integrate import (
    compute_forces,
)
from membrax.spheres.measure import unbalanced_force_ratio
from membrax.spheres.mould import mould_energy, mould_mean_stress, mould_radial_load

__all__ = ["IDLE_CALLS", "FireRelaxer", "describe_search", "quench", "unbalanced_ratio"]


#: The calls in a row, each running no FIRE step and leaving the growth bracket as it was, after which the
#: frictionless search stops (:class:`membrax.errors.SimulationError`). Such a call relaxed the positions it
#: was given at a growth whose logarithm is already an end of the bracket (a secant step rounded onto it), so
#: it learnt nothing; a step that finds anything new runs FIRE or narrows the bracket and resets the count.
#: 64, the bits of a float64, is far more than roundings repeat in a row, and ends a stuck search within a
#: second: an idle call is one force evaluation (on the paper-size seed-8 specimen, 1,740 spheres in
#: float64, the search before jumps were accepted repeated 3,963 of them in 55 s).
IDLE_CALLS = 64


class _FireCarry(NamedTuple):
    """What FIRE carries from step to step: the spheres, its adaptive step and mixing, and the error bits."""

    position: jax.Array
    compensation: jax.Array
    velocity: jax.Array
    neighbors: object
    step: jax.Array  # FIRE's Δt, s
    alpha: jax.Array  # the velocity mixing α
    downhill_steps: jax.Array  # downhill steps in a row (P > 0)
    error: jax.Array  # ErrorCode bits at the chunk's end: the list's overflow, non-finite positions


class _Spheres(NamedTuple):
    """FIRE's spheres as :func:`membrax.driver.grow_tables` sees them: frictionless, so no contact history."""

    position: jax.Array
    neighbors: object
    pair_spring: None = None

    def set(self, **changes):
        return self._replace(**changes)


def quench(before, after):
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


def unbalanced_ratio(net_force, forces, particles, neighbors):
    """The packing's unbalanced-force ratio (:func:`membrax.spheres.measure.unbalanced_force_ratio`)."""
    first = neighbors.idx[0]
    pair_member = particles.member[jnp.where(first < particles.num_particles, first, 0)]
    return unbalanced_force_ratio(net_force, forces, particles, pair_member)[0]


class FireRelaxer:
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
            position, compensation, velocity, neighbors, step, alpha, downhill_steps, error = carry
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
            return _FireCarry(position, compensation, velocity, neighbors, step, alpha, downhill_steps, error)

        carry = advance(fire_step, carry, None, self.chunk_steps)
        # The list at the end positions, so that its overflow bit covers the state the search measures.
        neighbors = self.frame.update(carry.position, carry.neighbors)
        overflow = jnp.where(neighbors.did_buffer_overflow, ErrorCode.NEIGHBOR_OVERFLOW, 0)
        error = (overflow | not_finite_bit(carry.position)).astype(jnp.int32)
        return carry._replace(neighbors=neighbors, error=error)

    def _measure_impl(self, position, compensation, neighbors, growth):
        """(σ = (σ_a + 2σ_r)/3 in Pa, unbalanced-force ratio, neighbour overflow) of the spheres at rest."""
        neighbors = self.frame.update(position, neighbors)
        net, forces, mould = self._forces(position, compensation, neighbors, growth)
        radial = mould_radial_load(mould, position)
        stress = mould_mean_stress(forces.wall_total_force[0], radial, self.mould_radius, self.mould_height)
        ratio = unbalanced_ratio(net, forces, self.particles, neighbors)
        return stress, ratio, neighbors.did_buffer_overflow

    def relax(self, position, growth, target, tolerance, max_steps, on_chunk=None, settle=True):
        """FIRE at growth s until the unbalanced-force ratio is below ``tolerance``.

        ``position`` is (x, compensation); returns ((x, compensation), σ, ratio, steps), the very arrays
        given when it ran no step. ``settle`` False relaxes to ``tolerance`` even far from the target (a
        state the search may accept, module docstring "Stress jumps"). It measures the positions given,
        then runs chunks of ``chunk_steps`` steps through :func:`membrax.driver.drive`, measuring after
        each, until done or ``max_steps`` / ``chunk_steps`` (rounded up) chunks have run; a chunk whose
        neighbour list overflowed is run again with a larger list.

        Raises:
          SimulationError: the neighbour list overflowed again at the positions it was just allocated for,
            or a chunk left positions that are not finite.
        """
        position, compensation = position
        dtype = position.dtype
        # One list for every relaxation (a new allocation may change its capacity and recompile the chunk).
        if self.neighbors is None:
            self.neighbors = self.frame.allocate(position)
        carry = _FireCarry(
            position=position,
            compensation=compensation,
            velocity=jnp.zeros_like(position),
            neighbors=self.neighbors,
            step=jnp.asarray(self.dt, dtype),
            alpha=jnp.asarray(0.1, dtype),
            downhill_steps=jnp.asarray(0, jnp.int32),
            error=jnp.asarray(0, jnp.int32),
        )
        growth = jnp.asarray(growth, dtype)
        stress, ratio, overflow = self._measured(carry, growth)
        if overflow:  # the list of an earlier relaxation is too small for these positions
            carry = self._grow(carry, ErrorCode.NEIGHBOR_OVERFLOW)
            stress, ratio, overflow = self._measured(carry, growth)
            if overflow:
                # A list allocated at these very positions holds their pairs: overflowing again, it never
                # will (non-finite positions, or a sphere outside the list's box).
                finite = bool(np.isfinite(np.asarray(carry.position)).all())
                raise SimulationError(
                    f"compaction: the FIRE relaxation at growth factor s = {float(growth)!r} overflowed "
                    f"its neighbour list again right after allocating it for the same positions (stress "
                    f"{stress:.6g} Pa, unbalanced-force ratio {ratio:.3g}, 0 FIRE steps, 2 calls, positions "
                    f"{'finite' if finite else 'NOT finite'}). "
                    + (
                        "A sphere has left the mould's neighbour box: check the mould's size against the "
                        "spheres (mould_diameter, mould_height) and the contact stiffness."
                        if finite
                        else "The relaxation went unstable (FIRE's step is capped at 1.8 times "
                        "compaction_time_step's): report the seed and the arguments of compact."
                    )
                )
        track = {
            "steps": 0,
            "stress": stress,
            "ratio": ratio,
            "best": math.inf,
            "best_at": 0,
            "last": math.nan,
        }

        def finished(stress, ratio):
            """Whether the relaxation is done at (σ, ratio) after ``track["steps"]`` steps."""
            steps = track["steps"]
            # Unjammed (the contacts all open once at rest): nothing to converge, the growth must rise.
            unjammed = steps > 0 and stress < 1e-2 * target
            # At the round-off floor (float32: an unbalanced-force ratio of a few 1e-3) FIRE stalls.
            if ratio < 0.9 * track["best"]:
                track["best"], track["best_at"] = ratio, steps
            stalled = steps - track["best_at"] >= 5 * self.chunk_steps
            # Far from the target, a settled stress is all the growth correction needs.
            settled = settle and abs(stress - track["last"]) < 0.01 * abs(stress - target) and ratio < 0.1
            track["last"] = stress
            return ratio < tolerance or unjammed or stalled or settled or not math.isfinite(ratio)

        if finished(stress, ratio) or max_steps <= 0:
            return (carry.position, carry.compensation), stress, ratio, 0

        def chunk(current, left, _num_records):
            return self._chunk(current, growth), left - self.chunk_steps, None, None

        def accept(current, _records, _valid, _left):
            track["steps"] += self.chunk_steps
            stress, ratio, _ = self._measured(current, growth)
            track["stress"], track["ratio"] = stress, ratio
            if on_chunk is not None:
                on_chunk(
                    {
                        "steps": track["steps"],
                        "stress": stress,
                        "growth": float(growth),
                        "unbalanced_force_ratio": ratio,
                    }
                )
            return [0] if finished(stress, ratio) else []

        def failed(error, new, _current):
            return SimulationError(
                f"compaction: the FIRE relaxation at growth factor s = {float(growth)!r} stopped in the "
                f"chunk after {track['steps']} FIRE steps: "
                + "; ".join(describe(int(error[0])))
                + " (FIRE's step is capped at 1.8 times compaction_time_step's): report the seed and the "
                "arguments of compact."
            )

        carry, _ = drive(
            chunk,
            carry,
            [max_steps],
            self.chunk_steps,
            self.chunk_steps,
            errors=lambda current: np.atleast_1d(np.asarray(current.error)),
            grow=lambda current, error, _overflowed: self._grow(current, int(error[0])),
            fail=failed,
            accept=accept,
        )
        return (carry.position, carry.compensation), track["stress"], track["ratio"], track["steps"]

    def _grow(self, carry, error):
        """The FIRE carry with a larger neighbour list at its positions (``grow_tables``)."""
        spheres = _Spheres(carry.position, carry.neighbors)
        ((_, neighbors, _),) = grow_tables([spheres], error, self.frame)
        self.neighbors = neighbors  # later relaxations start from it
        return carry._replace(neighbors=neighbors)

    def _measured(self, carry: _FireCarry, growth) -> tuple[float, float, bool]:
        """(σ in Pa, unbalanced-force ratio, list overflow) of the carry's spheres at rest, on the host."""
        stress, ratio, overflow = self._measure(carry.position, carry.compensation, carry.neighbors, growth)
        return float(stress), float(ratio), bool(overflow)

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
          :attr:`membrax.spheres.compaction.Compaction.stress_jump` dict of an accepted jump.

        Raises:
          SimulationError: :data:`IDLE_CALLS` calls in a row ran no FIRE step and left the bracket as it
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
            if idle >= IDLE_CALLS:
                raise SimulationError(
                    f"compaction: the search for the growth factor made no progress in {idle} calls in a row "
                    f"(no FIRE step, the bracket unchanged): {describe_search(*where)}. No growth left to "
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
          where: the search's state for :func:`describe_search`.

        Returns:
          (closest state, the :attr:`membrax.spheres.compaction.Compaction.stress_jump` dict).

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
                f"state was at rest to accept: {describe_search(*where)}. Lower fire_tolerance or raise "
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


def describe_search(growth, stress, ratio, steps, calls, ends, window) -> str:
    """The state of :meth:`FireRelaxer.relax_to_stress` in words, for an error message.

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
