"""Gradients through a rollout of the simulator: reverse mode over ``jax.checkpoint`` windows, vmapped.

Contract. :func:`consolidation_rollout` builds, for a list of configurations that may differ in the
batched fields (σc, t_m, E_m, …: :data:`membrax.assemble.BATCHED_FIELDS`), one :class:`Rollout`:
``rollout.outputs(theta)`` runs every member from the start of consolidation (as-built specimen and
membrane, both platens servo-controlled to σc A₀) for ``steps`` time steps and returns the §4.3 stresses
of :data:`membrax.sensitivities.OUTPUTS` at the end (areas from the end, as Table 3's from the start of
shearing), (B, 6) in Pa, for parameters ``theta`` (B, P) in
configuration units (the ``wrt`` names, from :data:`membrax.sensitivities.PARAMETERS`).
:func:`shearing_rollout` goes on from there into drained shearing (the platens switched to constant
velocity inside the differentiated function) and measures at the end of shearing, areas from its start;
the whole path, consolidation included, is differentiated. Each rollout is a pure
function of ``theta`` under ``jit``, ``vmap`` (it is one) and reverse mode (``jax.grad``, ``jax.vjp``,
``jax.jacrev``); forward mode is not defined (the compiled kernels carry reverse-mode rules only,
:mod:`membrax.native`). :func:`rollout_jacobian` returns the values and dy/dθ of every member from one
compiled call; :func:`rollout_differences` the same by central differences of the forward rollout.

Memory: each member's rollout is a ``lax.scan`` over windows of ``window`` steps, each window wrapped in
``jax.checkpoint``, so reverse mode keeps steps/window window-start states and recomputes one window's
steps at a time (``benchmarks/bench_gradients.py`` measures the time and memory against the forward).
With ``unroll`` ≥ ``window`` each window runs without a loop, faster but slower to compile; where the step
runs the JAX code on a CPU instead of the compiled kernels, each step is checkpointed too (both:
:func:`checkpoint_window`).

Which outputs have a derivative. The rollout is differentiable where the map θ → final state is: with
``viscous_damping`` (the smooth mode, :class:`membrax.config.TriaxialConfig`), the step is continuous and
piecewise smooth in the state and θ (Coulomb caps and contact onsets are kinks, not jumps) and reverse
mode matches central differences within 1e-3 (``tests/test_gradients.py``). In the paper's mode (Cundall
local damping, F − α|F| sign(v)) the step jumps by 2α|F|Δt/m wherever a velocity component changes sign;
a transient crosses such jumps on every sphere and node, the final state is discontinuous in θ and no
derivative exists: central differences do not converge (their value changes sign with the step), and
reverse mode returns the derivative of the smooth pieces, which grows without bound with the steps.
There, use the implicit derivatives of the consolidated equilibrium (:mod:`membrax.sensitivities`); the
friction angles, which the equilibrium does not see (every contact stuck), need the rollout.

t_m is applied as in :mod:`membrax.sensitivities` (the rest geometry and clamp rings moved linearly along
their derivative, by central differences of the mesh construction), exact to first order at the members'
own t_m.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native
from membrax.assemble import loading, parameter_values, thickness_derivative
from membrax.config import TriaxialConfig
from membrax.driver import advance, drive, record_blocks
from membrax.errors import SimulationError, describe
from membrax.executor import GEOMETRY_FIELDS, BatchedTest, build_batch
from membrax.sensitivities import (
    _check_wrt,
    apply_parameters,
    measure_outputs,
    reference_size,
)

__all__ = [
    "UNROLL",
    "WINDOW",
    "Rollout",
    "checkpoint_window",
    "consolidation_rollout",
    "rollout_differences",
    "rollout_jacobian",
    "shearing_rollout",
]


WINDOW = 50
"""Steps per ``jax.checkpoint`` window of the rollouts (the default of every rollout's ``window``)."""

UNROLL = 2
"""Steps per iteration of a window's loop (the default of :func:`checkpoint_window` and the rollouts)."""


def checkpoint_window(
    step, window: int, dtype, rematerialize_steps: bool | None = None, unroll: int = UNROLL
):
    """``window`` steps of ``step(state, params)`` as one ``jax.checkpoint`` window.

    Reverse mode through a scan of these keeps each window's start state, and, while it goes back through
    a window, what each of its steps' derivatives needs (the residuals). With the compiled kernels
    (:func:`membrax.native.runs_kernels`) that is about 2.5 MB per paper-size float32 step, against a 2.35-MB
    state. On a CPU without them (``MEMBRAX_NATIVE=0``, a dtype they lack), XLA's derivative of the JAX
    code keeps far more, about 70 MB per step (``benchmarks/bench_gradients.py``'s program buffers), so
    there each step is itself checkpointed: the window's pass keeps the steps' input states alone and each
    step runs once more, forward, just before its backward pass. On a GPU, which runs the JAX code too,
    that does not pay: on one H200 (paper size, float32, 2,000 steps of consolidation) checkpointing each
    step made the reverse pass slower (2.57 → 2.99 s) and its program larger (261 → 294 MB of buffers,
    device peak 268 → 301 MB), so there the steps are not checkpointed one by one.

    The window's loop (``fori_loop``) runs ``unroll`` steps per iteration: by 2, 5.6 % came off the
    reverse pass against 1 (paper size, float32, 500 steps of consolidation, windows of 50, runs
    alternated in one process: median 2.663 → 2.514 s). With ``unroll >= window`` the window has no loop
    (a Python loop, unrolled whole). A loop keeps its steps' residuals in stacks, which XLA zero-fills,
    writes one slice at a time, reads back and copies with the loop's carry; a whole window keeps each
    residual in a buffer of its own. Whole windows of 10 took 9 % off the reverse pass against loop
    windows of 50 (same script: median 2.37 → 2.16 s; 2,000 steps: 10–18 %) at the cost of 17–18 s more
    compile time per differentiated program (31 against 10 s at paper size, 28 against 10 s at the
    small one), five times as many window starts to keep, and a slower forward (0.549 against
    0.524 s), so they pay only for long or repeated reverse passes; forward runs keep the loop
    (:attr:`Rollout.forward`).

    Args:
      step: the time step, ``(state, params) → state``.
      window: steps per window.
      dtype: the simulation's float dtype (which path the step takes).
      rematerialize_steps: checkpoint each step too; None (default) where the step runs the JAX code on a
        CPU.
      unroll: steps per iteration of the window's loop; ``window`` or more: the whole window, no loop.

    Returns:
      ``(state, params) → state`` after ``window`` steps, checkpointed.
    """
    if rematerialize_steps is None:
        rematerialize_steps = jax.default_backend() == "cpu" and not native.enabled_for(dtype)
    inner = jax.checkpoint(step) if rematerialize_steps else step

    @jax.checkpoint
    def run(state, params):
        # unroll >= window: the whole window, no loop and no residual stacks
        return advance(inner, state, params, window, unroll=unroll)

    return run


@dataclasses.dataclass
class Rollout:
    """A batch's rollout as a function of its parameters (module docstring).

    Attributes:
      batch: the members (:class:`membrax.executor.BatchedTest`, in the configurations' order).
      wrt: parameter names (:data:`membrax.sensitivities.PARAMETERS`).
      steps: consolidation time steps, a multiple of ``window``.
      window: steps per ``jax.checkpoint`` window.
      theta0: (B, P) the members' own parameter values, configuration units.
      geometry: d(rest geometry)/d t_m per member (empty unless t_m is in ``wrt``).
      shear_steps: shearing time steps after the consolidation, a multiple of ``window`` (0: none).
      shear: (inertial number, ramp strain, symmetric) of the shearing (the configurations').
      unroll: steps per iteration of the windows' loops in reverse mode (:func:`checkpoint_window`;
        ≥ ``window``: whole windows); forward-only runs loop by :data:`UNROLL`.
    """

    batch: BatchedTest
    wrt: tuple
    steps: int
    window: int
    theta0: np.ndarray
    geometry: dict
    shear_steps: int = 0
    shear: tuple = ()
    unroll: int = UNROLL

    def member_final(self, theta, params, member, state, geometry, unroll=None):
        """One member's run at ``theta`` (P,): (final state, reference (height, volume), mesh, params).

        Consolidation for :attr:`steps`, then, if :attr:`shear_steps`, shearing from where it stopped
        (the platens switched to constant velocity, :meth:`MembraneTest.start_shear`, the reference the
        state there); each a ``lax.scan`` over ``jax.checkpoint`` windows, their loops unrolled by
        ``unroll`` steps (:func:`checkpoint_window`; None: :attr:`unroll`).
        """
        template = self.batch.tests[0]
        mesh = template.mesh.set(**{name: member[name] for name in GEOMETRY_FIELDS})
        values = dict(zip(self.wrt, [theta[k] for k in range(len(self.wrt))], strict=True))
        thickness_mm = 1e3 * params.membrane.thickness
        params, mesh, state = apply_parameters(
            values,
            params,
            mesh,
            state,
            thickness_mm=thickness_mm,
            geometry=geometry,
            clamp_position=state.membrane.clamp_position,
        )
        unroll = self.unroll if unroll is None else unroll
        run = checkpoint_window(
            template.make_step(mesh), self.window, mesh.reference_position.dtype, unroll=unroll
        )

        def window(s):
            return run(s, params), None

        final, _ = record_blocks(window, state, self.steps // self.window)
        reference = None
        if self.shear_steps:
            inertial_number, ramp_strain, symmetric = self.shear
            final = template.start_shear(
                final, inertial_number, ramp_strain, symmetric, cell_pressure=params.membrane.cell_pressure
            )
            reference = reference_size(final, mesh, params)
            final, _ = record_blocks(window, final, self.shear_steps // self.window)
        return final, reference, mesh, params

    def member_outputs(self, theta, params, member, state, geometry, unroll=None):
        """One member's outputs (6,), Pa, at ``theta`` (P,) (§4.3's stresses at the end), and error bits."""
        final, reference, mesh, params = self.member_final(theta, params, member, state, geometry, unroll)
        outputs = measure_outputs(final, self.batch.tests[0], mesh, params, reference)
        return outputs, final.dem.error

    def outputs_and_errors(self, theta, unroll=None):
        """((B, 6) outputs in Pa, (B,) error bits) at ``theta`` (B, P); ``unroll`` as :meth:`member_final`."""
        member = functools.partial(self.member_outputs, unroll=unroll)
        return jax.vmap(member)(jnp.asarray(theta), *self.real_members(), self.geometry)

    def real_members(self):
        """(params, members, start states) of the real members (the batch's padding dropped)."""
        count = self.batch.num_members
        batch = self.batch
        return jax.tree_util.tree_map(
            lambda leaf: leaf[:count], (batch.params, batch.members, batch.initial_state)
        )

    def outputs(self, theta):
        """(B, 6) outputs, Pa, at ``theta`` (B, P), configuration units; differentiable (reverse mode)."""
        return self.outputs_and_errors(theta)[0]

    @functools.cached_property
    def forward(self):
        """:meth:`outputs_and_errors` compiled (``jax.jit``), once per rollout.

        Its windows' loops run :data:`UNROLL` steps per iteration whatever :attr:`unroll` is: a forward
        runs faster so than through whole windows (:func:`checkpoint_window`).
        """
        return jax.jit(functools.partial(self.outputs_and_errors, unroll=UNROLL))

    @functools.cached_property
    def values_and_jacobians(self):
        """θ (B, P) → ((B, 6) outputs, (B, 6, P) dy/dθ): each member's ``jax.jacrev``, vmapped, compiled."""

        def member(t, params, m, state, geometry):
            def outputs(t_):  # the outputs twice: the Jacobian's function and its value (aux)
                y = self.member_outputs(t_, params, m, state, geometry)[0]
                return y, y

            rows, value = jax.jacrev(outputs, has_aux=True)(t)
            return value, rows

        return jax.jit(lambda t: jax.vmap(member)(t, *self.real_members(), self.geometry))

    def final_states(self):
        """The members' final states at their own parameters (to size the tables), stacked."""

        def one(*args):
            return self.member_final(*args, unroll=UNROLL)[0]

        return jax.jit(jax.vmap(one))(jnp.asarray(self.theta0), *self.real_members(), self.geometry)


def consolidation_rollout(
    configs: Sequence[TriaxialConfig] | TriaxialConfig,
    wrt: Sequence[str],
    steps: int,
    window: int = WINDOW,
    unroll: int = UNROLL,
) -> Rollout:
    """The consolidation rollout of ``configs`` (one batch, one Δt and mesh topology) over ``wrt``.

    Run in float64 (``jax.enable_x64``) with ``float64 = true`` configurations for derivative checks. The
    neighbour lists and node candidate tables are sized by one forward rollout first (grown and rerun on
    overflow), so the differentiated rollout never reallocates.

    Args:
      configs: one configuration or several that differ only in batched fields.
      wrt: parameter names, from :data:`membrax.sensitivities.PARAMETERS`.
      steps: time steps from the start of consolidation (rounded up to whole windows).
      window: steps per checkpoint window.
      unroll: steps per iteration of the windows' loops in reverse mode; ≥ ``window``: whole windows,
        faster to run and slower to compile (:func:`checkpoint_window`).

    Raises:
      ValueError: an unknown parameter, or steps, window or unroll below 1.
      membrax.errors.SimulationError: the forward rollout failed (not finite, outside the box).
    """
    return _rollout(configs, wrt, steps, 0, window, unroll)


def shearing_rollout(
    configs: Sequence[TriaxialConfig] | TriaxialConfig,
    wrt: Sequence[str],
    shear_steps: int,
    consolidation_steps: int,
    window: int = WINDOW,
    unroll: int = UNROLL,
) -> Rollout:
    """The rollout of ``configs`` through consolidation and then shearing, for the given steps of each.

    The whole path is differentiated: θ acts on the consolidation, on the start of shearing (σc sets the
    strain rate ε̇ = I √(σc/ρ)/d) and on the shearing. The shearing is the configurations' own
    (``inertial_number``, ``shear_ramp_strain``, ``symmetric_loading``); the outputs are §4.3's stresses at
    the end, with strains and areas counted from the start of shearing (Table 3). As
    :func:`consolidation_rollout` otherwise (float64 for checks; tables sized by a forward run first).

    Args:
      configs: one configuration or several that differ only in batched fields.
      wrt: parameter names, from :data:`membrax.sensitivities.PARAMETERS`.
      shear_steps: time steps of shearing (rounded up to whole windows), ≥ 1.
      consolidation_steps: time steps of consolidation before it (rounded up to whole windows), ≥ 1.
      window: steps per checkpoint window.
      unroll: as :func:`consolidation_rollout`'s.

    Raises:
      ValueError: an unknown parameter, steps, window or unroll below 1, or configurations that shear
        differently.
      membrax.errors.SimulationError: the forward rollout failed (not finite, outside the box).
    """
    if shear_steps < 1:
        raise ValueError(f"shear_steps = {shear_steps}: give a positive integer.")
    return _rollout(configs, wrt, consolidation_steps, shear_steps, window, unroll)


def _rollout(configs, wrt, steps: int, shear_steps: int, window: int, unroll: int = UNROLL) -> Rollout:
    configs = [configs] if isinstance(configs, TriaxialConfig) else list(configs)
    wrt = tuple(wrt)
    _check_wrt(wrt)
    if steps < 1 or window < 1 or unroll < 1:
        raise ValueError(f"steps = {steps}, window = {window}, unroll = {unroll}: give positive integers.")
    loadings = [loading(c) for c in configs]
    shear = {(plan.inertial_number, plan.ramp_strain, plan.symmetric) for plan in loadings}
    if shear_steps and len(shear) > 1:
        raise ValueError(
            f"the configurations shear differently (inertial_number, shear_ramp_strain, symmetric_loading: "
            f"{sorted(shear)}): give them one shearing."
        )
    steps = window * -(-steps // window)
    shear_steps = window * -(-shear_steps // window)
    batch = build_batch(configs, order=list(range(len(configs))), mode="vmap", num_devices=1)
    if "membrane_thickness_mm" in wrt:
        members = zip(batch.configs, batch.tests, strict=True)
        geometry = [thickness_derivative(c, t, GEOMETRY_FIELDS) for c, t in members]
        geometry = {name: jnp.stack([g[name] for g in geometry]) for name in GEOMETRY_FIELDS}
    else:
        geometry = {}
    theta0 = np.stack([parameter_values(c, wrt) for c in batch.configs])
    rollout = Rollout(batch, wrt, steps, window, theta0, geometry, shear_steps, next(iter(shear)), unroll)
    errors = {}

    def run(states, left, _num_records):  # the whole rollout is the chunk
        batch.initial_state = states
        errors["now"] = np.asarray(rollout.forward(jnp.asarray(theta0))[1])
        return states, left - 1, None, None

    def grow(states, error, _overflowed):
        # The tables the rollout needed are those of its end states.
        grown = batch.grow(states, error, rollout.final_states().membrane.candidates)
        for compiled in ("forward", "values_and_jacobians"):  # the tables' shapes changed: compile again
            rollout.__dict__.pop(compiled, None)
        return grown

    def fail(error, _new, _states):
        bad = int(np.flatnonzero(error)[0])
        return SimulationError(
            f"member {bad} ({batch.settings[bad].name}) failed in the rollout: "
            + "; ".join(describe(int(error[bad])))
        )

    # One pass of the one host loop: an overflow grows the start states' tables and runs the rollout again.
    batch.initial_state, _ = drive(
        run,
        batch.initial_state,
        [1],
        1,
        1,
        errors=lambda _: errors["now"],
        grow=grow,
        fail=fail,
        accept=lambda *_: [],
    )
    return rollout


def rollout_jacobian(rollout: Rollout, theta=None) -> tuple[np.ndarray, np.ndarray]:
    """(outputs (B, 6), Pa; dy/dθ (B, 6, P), Pa per unit) at ``theta`` (default the members' own).

    One compiled call (:attr:`Rollout.values_and_jacobians`, compiled once per rollout): ``jax.jacrev`` of
    each member's rollout, vmapped over the members.
    """
    theta = rollout.theta0 if theta is None else np.asarray(theta)
    value, jacobian = rollout.values_and_jacobians(jnp.asarray(theta))
    return np.asarray(value), np.asarray(jacobian)


def rollout_differences(rollout: Rollout, relative_step: float = 1e-4, theta=None) -> np.ndarray:
    """dy/dθ (B, 6, P) by central differences of the forward rollout, h = ``relative_step`` × |θ|."""
    theta = rollout.theta0 if theta is None else np.asarray(theta, dtype=float)

    def forward(t):
        return rollout.forward(t)[0]

    columns = []
    for k in range(theta.shape[1]):
        step = relative_step * np.abs(theta[:, k])
        plus, minus = theta.copy(), theta.copy()
        plus[:, k] += step
        minus[:, k] -= step
        difference = np.asarray(forward(jnp.asarray(plus))) - np.asarray(forward(jnp.asarray(minus)))
        columns.append(difference / (2.0 * step[:, None]))
    return np.stack(columns, axis=-1)
