"""An inverse problem through the simulator: membrane properties from the initial internal stresses.

Contract. :func:`invert` recovers membrane parameters (by default E_m and the membrane–particle friction
angle) from "observed" initial internal stresses, the internal σ1 and σ3 of the paper's §4.3 at the end of
consolidation, by minimising the squared relative misfit

    J(x) = Σ_b Σ_k ((y_bk(θ(x)) − y_bk^obs) / y_bk^obs)²,    θ = θ_start · exp(x),

with optax's L-BFGS (``optax.lbfgs``, zoom line search) on gradients by reverse mode through the
consolidation rollout (:mod:`membrax.gradients`, the smooth mode ``viscous_damping``: the paper's local
damping has no derivative through a transient). :func:`invert_gradient_free` solves the same problem with
Nelder–Mead (``scipy.optimize.minimize``), the common black-box practice, for the comparison of
simulator calls. Both take an :class:`InverseProblem` (the rollout, compiled once), whose
:meth:`InverseProblem.observe` generates the observations with the same rollout at known parameters.

Why a rollout and not the implicit derivatives. At the consolidated equilibrium every contact is stuck,
so the equilibrium conditions do not contain the friction angles (their implicit derivatives are exactly
0, :mod:`membrax.sensitivities`); friction acts through the path, as membrane nodes slide over the spheres
while the cell pressure pulls the membrane in (on the 4 × 4 × 5 specimen, internal σ1 at 12.5°, 25°, 37.5°:
14.48, 14.05, 13.92 kPa, measured with the paper's damping). The rollout sees it.

Costs are counted in simulator calls: one forward rollout (a value) or one forward-and-reverse rollout
(a value and its gradient); reverse mode costs several forward rollouts
(``benchmarks/bench_gradients.py``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.optimize

from calibrate.fit import strong_types
from membrax.config import TriaxialConfig
from membrax.gradients import WINDOW, consolidation_rollout
from membrax.sensitivities import OUTPUTS

__all__ = ["OBSERVED", "InverseProblem", "InverseResult", "invert", "invert_gradient_free"]

#: The observed outputs: the initial internal stresses (Pa).
OBSERVED = ("internal_axial_stress", "internal_radial_stress")
_ROWS = [OUTPUTS.index(name) for name in OBSERVED]


@dataclasses.dataclass
class InverseResult:
    """An inversion's outcome.

    Attributes:
      parameters: {name: recovered value} in configuration units.
      start: {name: starting value}.
      iterations: optimiser iterations.
      value_calls: forward rollouts (values only).
      gradient_calls: forward-and-reverse rollouts (value and gradient).
      objective: J at the end.
      history: [(iteration, J, {name: value})] per iteration.
      seconds: wall time, s (the first call's compilation included).
    """

    parameters: dict
    start: dict
    iterations: int
    value_calls: int
    gradient_calls: int
    objective: float
    history: list
    seconds: float


class InverseProblem:
    """The misfit J(x) over one consolidation rollout, compiled once, with call counters.

    One problem serves the observations (:meth:`observe`), :func:`invert` and :func:`invert_gradient_free`:
    the observations and the starting point are arguments of the compiled functions, not constants in
    them, so nothing compiles twice.

    Args:
      configs: the observed tests (smooth mode, ``viscous_damping = true``), one or several that differ in
        batched fields (several cell pressures, say); the parameters are shared by all.
      wrt: the parameters to recover, names from :data:`membrax.sensitivities.PARAMETERS`.
      steps: consolidation steps of the rollout.
      window: checkpoint window, steps (:data:`membrax.gradients.WINDOW`).

    Raises:
      ValueError: a configuration in the paper's mode, or an unknown parameter.
    """

    def __init__(self, configs, wrt: Sequence[str], steps: int, window: int = WINDOW):
        configs = [configs] if isinstance(configs, TriaxialConfig) else list(configs)
        if not all(c.viscous_damping for c in configs):
            raise ValueError(
                "the inversion differentiates a rollout, which needs viscous_damping = true (the paper's "
                "local damping makes the consolidation discontinuous in the parameters; membrax.gradients)."
            )
        self.rollout = consolidation_rollout(configs, wrt, steps, window)
        self.wrt = tuple(wrt)
        count = self.rollout.batch.num_members

        def misfit(x, start, observed):
            theta = jnp.broadcast_to(start * jnp.exp(x), (count, len(self.wrt)))
            y = self.rollout.outputs(theta)[:, _ROWS]
            return jnp.sum(((y - observed) / observed) ** 2)

        self._value = jax.jit(misfit)
        self._value_and_grad = jax.jit(jax.value_and_grad(misfit))

        # The line search inside the L-BFGS update calls J and ∇J through the program above, on the host,
        # rather than a copy of the rollout traced into the update: the rollout's forward and reverse
        # passes compile once (about 20 s on 2 cores at 4 × 4 × 5), not twice.
        def evaluated_on_host(x, start, observed):
            value, gradient = self.value_and_grad(x, start, observed)
            return np.asarray(value), np.asarray(gradient)

        def value_and_gradient(x, start, observed):
            shapes = (jax.ShapeDtypeStruct((), x.dtype), jax.ShapeDtypeStruct(x.shape, x.dtype))
            return jax.pure_callback(evaluated_on_host, shapes, x, start, observed)

        @jax.custom_vjp
        def counted(x, start, observed):
            return value_and_gradient(x, start, observed)[0]

        def counted_forward(x, start, observed):
            value, gradient = value_and_gradient(x, start, observed)
            return value, (gradient, start, observed)

        def counted_backward(residuals, cotangent):  # the observations and the start are constants of J
            gradient, start, observed = residuals
            return cotangent * gradient, jnp.zeros_like(start), jnp.zeros_like(observed)

        counted.defvjp(counted_forward, counted_backward)
        self.counted = counted
        self.value_calls = 0
        self.gradient_calls = 0

    def observe(self, parameters: dict | None = None) -> np.ndarray:
        """Internal σ1, σ3 (B, 2), Pa, at ``parameters`` ({name: value}; default the configurations')."""
        theta = np.array(self.rollout.theta0)
        for k, name in enumerate(self.wrt):
            if parameters is not None and name in parameters:
                theta[:, k] = parameters[name]
        return np.asarray(self.rollout.forward(jnp.asarray(theta))[0])[:, _ROWS]

    def value_and_grad(self, x, start, observed):
        """(J, ∇J) at log-parameters ``x``: one forward-and-reverse rollout, counted.

        The arguments are made uncommitted host arrays (as a callback's are not, and under no default
        device), so that every call, from the host or from the line search's callback, runs the one
        compiled program.
        """
        self.gradient_calls += 1
        with jax.default_device(None):
            return self._value_and_grad(*(jnp.asarray(np.asarray(a)) for a in (x, start, observed)))

    def _start(self, start: dict) -> np.ndarray:
        missing = [name for name in self.wrt if name not in start]
        if missing or set(start) - set(self.wrt):
            raise ValueError(f"start {sorted(start)}: give a value for each of {list(self.wrt)}.")
        return np.asarray([float(start[name]) for name in self.wrt])

    def reset(self) -> None:
        """Zero the call counters."""
        self.value_calls = self.gradient_calls = 0

    def parameters(self, x, start) -> dict:
        """{name: start · exp(x)}."""
        return dict(zip(self.wrt, (np.asarray(start) * np.exp(np.asarray(x))).tolist(), strict=True))

    def begin(self, start: dict, observed):
        """A method's start: (the time now, θ_start, observations as an array), the counters zeroed."""
        self.reset()
        return time.perf_counter(), jnp.asarray(self._start(start)), jnp.asarray(observed)

    def result(self, x, origin, start: dict, iterations: int, objective, history, began: float):
        """The :class:`InverseResult` at log-parameters ``x``, with this problem's call counters."""
        return InverseResult(
            parameters=self.parameters(x, origin),
            start=dict(start),
            iterations=iterations,
            value_calls=self.value_calls,
            gradient_calls=self.gradient_calls,
            objective=float(objective),
            history=history,
            seconds=time.perf_counter() - began,
        )


def invert(
    problem: InverseProblem,
    observed,
    start: dict,
    tolerance: float = 1e-10,
    max_iterations: int = 40,
) -> InverseResult:
    """Recover ``start``'s parameters from ``observed`` (B, 2) by L-BFGS on reverse-mode gradients.

    Args:
      problem: the :class:`InverseProblem` (its configurations, parameters and rollout).
      observed: (B, 2) internal σ1, σ3, Pa (:meth:`InverseProblem.observe`).
      start: {parameter: starting value}, configuration units.
      tolerance: stop when J falls below it (J ~ the squared relative misfit; 1e-10: 1e-5 relative).
      max_iterations: most L-BFGS iterations.
    """
    began, origin, observed = problem.begin(start, observed)
    optimizer = optax.lbfgs()
    x = jnp.zeros(len(problem.wrt))
    state = strong_types(optimizer.init(x))

    @jax.jit
    def step(x, state, value, gradient, origin, observed):
        # optax's L-BFGS adds an int32 memory index to an int64 arange under x64: standard promotion
        # for it, whatever the caller's setting.
        with jax.numpy_dtype_promotion("standard"):
            updates, state = optimizer.update(
                gradient,
                state,
                x,
                value=value,
                grad=gradient,
                value_fn=lambda y: problem.counted(y, origin, observed),
            )
            return optax.apply_updates(x, updates), state

    history = []
    iterations = 0
    while True:
        if iterations == 0:
            value, gradient = problem.value_and_grad(x, origin, observed)
        else:  # the line search's last evaluation, at the new x, carried its value and gradient
            value = optax.tree_utils.tree_get(state, "value")
            gradient = optax.tree_utils.tree_get(state, "grad")
        history.append((iterations, float(value), problem.parameters(x, origin)))
        if float(value) < tolerance or iterations == max_iterations:
            break
        x, state = step(x, state, value, gradient, origin, observed)
        iterations += 1
    return problem.result(x, origin, start, iterations, value, history, began)


def invert_gradient_free(
    problem: InverseProblem, observed, start: dict, tolerance: float = 1e-10, max_calls: int = 400
) -> InverseResult:
    """The same problem by Nelder–Mead (``scipy.optimize.minimize``), values only.

    It stops when J falls below ``tolerance`` (the criterion :func:`invert` uses) or after ``max_calls``
    rollouts; the initial simplex steps 5 % in each parameter (scipy's default).
    """
    began, origin, observed = problem.begin(start, observed)
    history = []
    best = {"x": np.zeros(len(problem.wrt)), "value": np.inf}

    class _Reached(Exception):
        pass

    def objective(x):
        problem.value_calls += 1
        value = float(problem._value(jnp.asarray(x), origin, observed))
        if value < best["value"]:
            best.update(x=np.asarray(x).copy(), value=value)
        if value < tolerance:
            raise _Reached
        return value

    def on_iteration(intermediate_result):  # scipy passes an OptimizeResult to this parameter name
        history.append(
            (len(history), float(intermediate_result.fun), problem.parameters(intermediate_result.x, origin))
        )

    try:
        result = scipy.optimize.minimize(
            objective,
            np.zeros(len(problem.wrt)),
            method="Nelder-Mead",
            callback=on_iteration,
            options={"maxfev": max_calls, "xatol": 1e-8, "fatol": 0.1 * tolerance},
        )
        iterations = int(result.nit)
    except _Reached:
        iterations = len(history)
    return problem.result(best["x"], origin, start, iterations, best["value"], history, began)
