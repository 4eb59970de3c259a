"""Sensitivities of the consolidated specimen by implicit differentiation, checked by continuation.

Contract. :func:`sensitivity` consolidates the membrane test of a configuration (float64, to an
unbalanced-force ratio ≤ ``tolerance``) and returns, for each output y of :data:`OUTPUTS` (the initial
external and internal stresses of the paper's §4.3 and Δσ = internal − external, as in its Table 3) and
each parameter x of :data:`PARAMETERS` (configuration fields, in their units), the value, dy/dx by the
implicit function theorem, the same by central differences of the simulator (optional) and the
elasticity d ln y/d ln x. ``membrax sensitivity config.toml --wrt a,b`` prints that table.

Equilibrium. The consolidated state u* (sphere centres x and rotations φ, free membrane nodes y, the two
platen heights h) satisfies R(u*, θ) = 0, with R the out-of-balance forces and torques on spheres and
nodes and the platens' ram-force errors F_ram − σc A₀. R is evaluated by **one step of the simulator
itself** (:func:`membrax.membrane.coupled.membrane_dem`, damping off) from a state displaced by δu and
moving at δu/Δt: the step's contact laws then advance every tangential spring by k_t times the contact's
relative tangential displacement, so R carries the frictional contacts' history as the quasi-static
incremental (tangent) stiffness, stuck springs at k_t and sliding ones at the Coulomb limit. By the
implicit function theorem

    du*/dθ = −(∂R/∂u)⁺ ∂R/∂θ,    dy/dθ = ∂y/∂θ + ∂y/∂u · du*/dθ,

with ∂R/∂u formed densely by reverse mode (``jax.vjp`` over batches of unit cotangents; the compiled CPU
kernels have reverse-mode rules only) and solved by least squares (``numpy.linalg.lstsq``, singular values
below 1e-12 of the largest cut). The cut removes the zero-stiffness modes. The one measured on a 4 × 4 × 5
specimen is the vertical rigid translation of specimen, membrane and both servo platens together (singular
value 2e-17 of the largest), which no output sees. A rotation about the axis or a lateral drift is held by
the clamps, which fix the membrane's end rings on the platens. A sphere without contacts, or a contact
sliding at the Coulomb limit, gives a zero mode too, and the cut removes those as well. The dense Jacobian
limits this to small specimens (:data:`MAX_DENSE_UNKNOWNS`).

Parameters (θ): σc (cell pressure and the servo target), E_m, t_m (with the membrane's rest geometry,
which is built t_m/2 off the spheres, and the clamp rings, both linearised by central differences of the
mesh construction), the membrane–particle and interparticle friction angles (through tan φ) and the
particle stiffness k_n (with k_t = k_n/2 and the platens' stiffnesses, as
:func:`membrax.assemble.build_test`).

Finite differences by continuation (:func:`continuation_differences`): from the consolidated state, set
θ ± h and let the simulator (its own damping) relax to equilibrium again, then measure. The two agree
where the path is smooth: no contact opens, closes or starts to slide between θ − h and θ + h, and the
servo platens end at rest. A full re-consolidation at θ ± h would follow another path, and its friction
history would differ.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from membrax.assemble import build_test, parameter_values, thickness_derivative
from membrax.config import TriaxialConfig, to_si
from membrax.defaults import LATEX_DENSITY
from membrax.driver import advance, drive
from membrax.errors import SimulationError, describe
from membrax.executor import GEOMETRY_FIELDS
from membrax.membrane import energies
from membrax.membrane.coupled import platen_heights
from membrax.membrane.mesh import free_node_mask, inner_volume
from membrax.membrane.records import measure_coupled
from membrax.spheres.integrate import DampingParams
from membrax.spheres.walls import BOTTOM, TOP, platen_separation

__all__ = [
    "DIFFERENCE_STEPS",
    "MAX_DENSE_UNKNOWNS",
    "OUTPUTS",
    "PARAMETERS",
    "Equilibrium",
    "SensitivityTable",
    "apply_parameters",
    "consolidated",
    "continuation_differences",
    "format_table",
    "implicit_sensitivities",
    "measure_outputs",
    "sensitivity",
]

#: Outputs, Pa: the initial stresses of the paper's §4.3 (Table 3) and Δσ = internal − external.
OUTPUTS = (
    "external_axial_stress",
    "external_radial_stress",
    "internal_axial_stress",
    "internal_radial_stress",
    "additional_axial_stress",
    "additional_radial_stress",
)
#: Parameters (configuration fields, in their units) and what they set.
PARAMETERS = {
    "cell_pressure_kpa": "σc: the cell pressure on the membrane and the ram's servo target σc A₀",
    "membrane_modulus_kpa": "E_m",
    "membrane_thickness_mm": "t_m, with the membrane's rest geometry and clamp rings",
    "membrane_friction_angle_deg": "membrane–particle friction angle (μ = tan φ)",
    "friction_angle_deg": "interparticle friction angle (μ = tan φ)",
    "particle_stiffness_n_m": "k_n, with k_t = k_n/2 and the platens' k_n, k_t",
}
#: Largest number of unknowns (6 per sphere, 3 per free node, 2 platens) for the dense Jacobian.
MAX_DENSE_UNKNOWNS = 12_000
#: Relative steps h/θ of the continuation differences where 1e-4 is too large. A node–sphere contact
#: touches at R + t_m/2, so t_m moves every contact's offset: on the 6 × 10 demo specimen h = 1e-4 t_m
#: opened or closed a contact (internal σ1's difference 16 % off), 1e-5 t_m agreed within 7e-4.
DIFFERENCE_STEPS = {"membrane_thickness_mm": 1e-5}
#: Cotangents per batch of the reverse-mode Jacobian (memory: about 17 MB each on the demo specimen).
JACOBIAN_BATCH = 64
#: Relative singular-value cut of the least-squares solve (module docstring).
RCOND = 1e-12


class Equilibrium(NamedTuple):
    """A consolidated membrane test: the test, its state and the configuration it came from."""

    config: TriaxialConfig
    test: object
    state: object


class SensitivityTable(NamedTuple):
    """Rows (output, parameter): y (Pa), x (its unit), dy/dx, the difference check, d ln y/d ln x.

    Attributes:
      rows: list of dicts with ``output``, ``parameter``, ``value`` (Pa), ``at`` (x), ``derivative``
        (Pa per unit of x), ``finite_difference`` (the same by continuation, or NaN), ``elasticity``.
      seconds: {"consolidation", "implicit", "finite_differences"} wall times, s.
      unknowns: size of the equilibrium system.
    """

    rows: list
    seconds: dict
    unknowns: int


def consolidated(config: TriaxialConfig, tolerance: float = 1e-7, max_steps: int = 200_000) -> Equilibrium:
    """Build the configuration's test and consolidate it to an unbalanced-force ratio ≤ ``tolerance``.

    Call inside ``jax.enable_x64(True)`` with ``config.float64`` true (:func:`sensitivity` does).
    """
    test = build_test(config)
    state, _ = test.consolidate(tolerance=tolerance, max_steps=max_steps, chunk_steps=2000, record_every=500)
    return Equilibrium(config, test, state)


def _free_and_rings(mesh):
    """(free node ids, bottom ring ids, top ring ids)."""
    return (
        np.flatnonzero(free_node_mask(mesh)),
        np.asarray(mesh.bottom_ring),
        np.asarray(mesh.top_ring),
    )


def apply_parameters(
    values: dict, params, mesh, state, thickness_mm=None, geometry=None, clamp_position=None
):
    """(params, mesh, state) with the :data:`PARAMETERS` in ``values`` (configuration units, traced) set.

    σc sets the membrane's cell pressure and the platens' servo target σc (the ram force σc A₀); t_m sets
    the membrane's thickness and moves its rest geometry and clamp rings linearly from those at
    ``thickness_mm`` along ``geometry`` (d field/d t_m per mm, :func:`membrax.assemble.thickness_derivative`),
    the clamp rings from ``clamp_position``; the friction angles set μ = tan φ; k_n sets k_t = k_n/2 and the
    platens' k_n, k_t alike (as :func:`membrax.assemble.build_test`).
    """
    membrane, dem_params = params.membrane, params.dem
    if "cell_pressure_kpa" in values:
        pressure = to_si("cell_pressure_kpa", values["cell_pressure_kpa"])
        membrane = membrane.set(cell_pressure=pressure)
        walls = state.dem.walls
        target = jnp.full_like(walls.target_stress, 1.0) * pressure
        state = state.set(dem=state.dem.set(walls=walls.set(target_stress=target)))
    if "membrane_modulus_kpa" in values:
        membrane = membrane.set(modulus=to_si("membrane_modulus_kpa", values["membrane_modulus_kpa"]))
    if "membrane_thickness_mm" in values:
        change = values["membrane_thickness_mm"] - thickness_mm
        membrane = membrane.set(thickness=to_si("membrane_thickness_mm", values["membrane_thickness_mm"]))
        mesh = mesh.set(**{name: getattr(mesh, name) + change * d for name, d in geometry.items()})
        clamp_change = jnp.stack(
            [geometry["reference_position"][ring] for ring in (mesh.bottom_ring, mesh.top_ring)]
        )
        state = state.set(membrane=state.membrane.set(clamp_position=clamp_position + change * clamp_change))
    if "membrane_friction_angle_deg" in values:
        friction = jnp.tan(jnp.deg2rad(values["membrane_friction_angle_deg"]))
        membrane = membrane.set(contact=membrane.contact.set(friction_coefficient=friction))
    contact = dem_params.contact
    if "friction_angle_deg" in values:
        contact = contact.set(friction_coefficient=jnp.tan(jnp.deg2rad(values["friction_angle_deg"])))
    if "particle_stiffness_n_m" in values:
        stiffness = values["particle_stiffness_n_m"]
        contact = contact.set(
            normal_stiffness=stiffness,
            tangential_stiffness=0.5 * stiffness,
            wall_normal_stiffness=stiffness,
            wall_tangential_stiffness=0.5 * stiffness,
        )
    return params.set(membrane=membrane, dem=dem_params.set(contact=contact)), mesh, state


class _System:
    """The equilibrium residual R(u, θ) and the outputs y(u, θ) around one consolidated state."""

    def __init__(self, equilibrium: Equilibrium, wrt):
        config, test, state = equilibrium
        self.test, self.state = test, state
        self.wrt = tuple(wrt)
        self.theta0 = parameter_values(config, self.wrt)
        self.thickness_mm = float(parameter_values(config, ["membrane_thickness_mm"])[0])
        self.free, bottom, top = _free_and_rings(test.mesh)
        self.rings = np.concatenate([bottom, top])
        self.ring_sizes = (bottom.size, top.size)
        self.num_spheres = int(state.dem.position.shape[0])
        self.size = 6 * self.num_spheres + 3 * self.free.size + 2
        moved_by_thickness = "membrane_thickness_mm" in self.wrt
        self.geometry = thickness_derivative(config, test, GEOMETRY_FIELDS) if moved_by_thickness else None
        self.dt = test.dt
        self.node_mass_per_thickness = energies.lumped_mass(test.mesh, 1.0, LATEX_DENSITY)

    def apply(self, theta, state):
        """(params, step, mesh, state) at parameters ``theta`` (configuration units).

        The state's parameter-dependent parts (the servo target, the clamp rings) are set from the
        equilibrium's, so applying θ to a state that already carries it changes nothing.
        """
        value = dict(zip(self.wrt, [theta[k] for k in range(len(self.wrt))], strict=True))
        params, mesh, state = apply_parameters(
            value,
            self.test.params,
            self.test.mesh,
            state,
            thickness_mm=self.thickness_mm,
            geometry=self.geometry,
            clamp_position=self.state.membrane.clamp_position,
        )
        return params, self.test.make_step(mesh), mesh, state

    def displaced(self, u, state):
        """``state`` displaced by u and moving at u/Δt (module docstring); the clamped rings ride along."""
        n, free = self.num_spheres, self.free
        dx = u[: 3 * n].reshape(n, 3)
        dphi = u[3 * n : 6 * n].reshape(n, 3)
        dy = u[6 * n : 6 * n + 3 * free.size].reshape(free.size, 3)
        dh = u[6 * n + 3 * free.size :]
        dt = self.dt
        spheres = state.dem
        walls = spheres.walls
        # The bottom platen's wall coordinate is −z (its normal is −e_z).
        wall_position = walls.position.at[0, BOTTOM].add(-dh[0]).at[0, TOP].add(dh[1])
        spheres = spheres.set(
            position=spheres.position + dx,
            velocity=dx / dt,
            angular_velocity=dphi / dt,
            walls=walls.set(position=wall_position, velocity=jnp.zeros_like(walls.velocity)),
        )
        nodes = state.membrane
        # The clamped rings sit where the step puts them, on the clamp moved with the platens (the clamp
        # itself moves with t_m); their velocity is the platens' alone, as in the step.
        lift = platen_heights(spheres.walls) - nodes.clamp_platen_height
        rings = nodes.clamp_position.at[:, :, 2].add(lift[:, None]).reshape(-1, 3)
        shift = jnp.concatenate([jnp.full(self.ring_sizes[0], dh[0]), jnp.full(self.ring_sizes[1], dh[1])])
        position = nodes.position.at[free].add(dy).at[self.rings].set(rings)
        velocity = jnp.zeros_like(nodes.velocity).at[free].set(dy / dt).at[self.rings, 2].set(shift / dt)
        return state.set(dem=spheres, membrane=nodes.set(position=position, velocity=velocity))

    def evaluate(self, u, theta, state=None):
        """(R(u, θ), y(u, θ)) around ``state`` (default the consolidated one)."""
        state = self.state if state is None else state
        params, step, mesh, state = self.apply(theta, state)
        params_static = params.set(dem=params.dem.set(damping=DampingParams.none()))
        before = self.displaced(u, state)
        after = step(before, params_static)
        dt, free = self.dt, self.free
        particles = self.test.particles
        sphere = particles.mass[:, None] * (after.dem.velocity - before.dem.velocity) / dt
        torque = particles.inertia[:, None] * (after.dem.angular_velocity - before.dem.angular_velocity) / dt
        node_mass = params.membrane.thickness * self.node_mass_per_thickness[free]
        node = node_mass[:, None] * (after.membrane.velocity[free] - before.membrane.velocity[free]) / dt
        walls = after.dem.walls
        platens = jnp.asarray([BOTTOM, TOP])
        ram = walls.force[0, platens] - walls.target_stress[0, platens] * self.test.platen_area
        residual = jnp.concatenate([sphere.ravel(), torque.ravel(), node.ravel(), ram])
        # Measure at the displaced positions with the membrane's forces computed there by the step.
        measured = before.set(
            membrane=before.membrane.set(
                node_force=after.membrane.node_force,
                sphere_force=after.membrane.sphere_force,
                platen_reaction=after.membrane.platen_reaction,
                ring_contact_force=after.membrane.ring_contact_force,
            )
        )
        outputs = measure_outputs(measured, self.test, mesh, params)
        return residual, outputs


def reference_size(state, mesh, params):
    """(height between the platens (m), volume inside the membrane (m³)) of a membrane-test state."""
    height = platen_separation(state.dem.walls)[0]
    volume = inner_volume(state.membrane.position, mesh, params.membrane.contact_thickness)
    return height, volume


def measure_outputs(state, test, mesh, params, reference=None):
    """The :data:`OUTPUTS` (6,), Pa, of a membrane-test state.

    The strains and the area A = A₀ (1 − ε_v)/(1 − ε_a) count from ``reference`` ((height, volume) of
    :func:`reference_size`), by default the state's own (Table 3: areas from the start of shearing, so
    A = A₀), not the as-built ones, which the indenting membrane leaves ~11 % larger on the 4 × 4 × 5
    specimen.
    """
    height, volume = reference_size(state, mesh, params) if reference is None else reference
    record = measure_coupled(state, test.particles, mesh, params, test.dt, height, volume, test.platen_area)
    internal = jnp.stack([record.internal_axial_stress[0], record.internal_radial_stress[0]])
    external = jnp.stack([record.external_axial_stress[0], record.external_radial_stress[0]])
    return jnp.concatenate([external, internal, internal - external])


def _check_wrt(wrt) -> None:
    unknown = [name for name in wrt if name not in PARAMETERS]
    if unknown or not wrt:
        raise ValueError(f"wrt {list(unknown)}: choose one or more of {', '.join(PARAMETERS)}.")


def implicit_sensitivities(
    equilibrium: Equilibrium, wrt=tuple(PARAMETERS)
) -> tuple[np.ndarray, np.ndarray, int]:
    """(outputs y (Pa), dy/dθ (Pa per unit, (outputs, parameters)), unknowns) at the equilibrium.

    Raises:
      ValueError: an unknown parameter, or a system above :data:`MAX_DENSE_UNKNOWNS` unknowns.
    """
    _check_wrt(wrt)
    system = _System(equilibrium, wrt)
    if system.size > MAX_DENSE_UNKNOWNS:
        raise ValueError(
            f"{system.size} unknowns: the dense implicit solve is limited to {MAX_DENSE_UNKNOWNS} (a "
            "specimen of about 6 × 10 spheres with a membrane of edge D/3); use a smaller specimen."
        )
    u0 = jnp.zeros(system.size)
    theta0 = jnp.asarray(system.theta0)

    def stacked(u, theta):  # [R; y]: one reverse-mode Jacobian, one compilation
        residual, outputs = system.evaluate(u, theta)
        return jnp.concatenate([residual, outputs])

    # Rows by reverse mode, JACOBIAN_BATCH unit cotangents per compiled call: all rows at once
    # (``jax.jacrev``, or ``lax.map`` inside one jit) asked for 75 GB on the 6 × 10 demo specimen.
    value, pullback = jax.jit(lambda u, t: jax.vjp(stacked, u, t))(u0, theta0)
    rows = jax.jit(lambda back, cotangents: jax.vmap(back)(cotangents))
    count = int(value.shape[0])
    by_u, by_theta = np.empty((count, system.size)), np.empty((count, theta0.shape[0]))
    for first in range(0, count, JACOBIAN_BATCH):
        cotangents = np.zeros((JACOBIAN_BATCH, count))  # a fixed batch shape: one compilation
        last = min(first + JACOBIAN_BATCH, count)
        cotangents[np.arange(last - first), np.arange(first, last)] = 1.0
        batch_u, batch_theta = rows(pullback, jnp.asarray(cotangents))
        by_u[first:last] = np.asarray(batch_u)[: last - first]
        by_theta[first:last] = np.asarray(batch_theta)[: last - first]
    value, by_u, by_theta = np.asarray(value), np.asarray(by_u), np.asarray(by_theta)
    n = system.size
    displacement = np.linalg.lstsq(by_u[:n], -by_theta[:n], rcond=RCOND)[0]
    return value[n:], by_theta[n:] + by_u[n:] @ displacement, n


def continuation_differences(
    equilibrium: Equilibrium,
    wrt=tuple(PARAMETERS),
    relative_step: float | None = None,
    chunk_steps: int = 2000,
    max_chunks: int = 50,
    tolerance: float = 1e-9,
) -> np.ndarray:
    """dy/dθ by central differences of the simulator, continued from the equilibrium (module docstring).

    For each parameter, θ ± h (h = ``relative_step`` × θ; default :data:`DIFFERENCE_STEPS`, else 1e-4) is
    set on the consolidated state and the simulator relaxes (its own damping) in chunks until the largest
    out-of-balance force on a sphere or a node is below ``tolerance`` × σc A₀ (the platens' servo error
    excepted), then the outputs are measured.
    """
    system = _System(equilibrium, wrt)
    load = equilibrium.test.cell_pressure * equilibrium.test.platen_area
    u0 = jnp.zeros(system.size)

    @jax.jit
    def relax_chunk(state, theta):  # θ traced: one compilation for every parameter and sign
        params, step, _, state = system.apply(theta, state)
        return advance(step, state, params, chunk_steps)

    evaluate = jax.jit(lambda state, theta: system.evaluate(u0, theta, state))
    runner = equilibrium.test.runner
    columns = []
    for k in range(len(system.wrt)):
        relative = DIFFERENCE_STEPS.get(system.wrt[k], 1e-4) if relative_step is None else relative_step
        step_size = relative * abs(system.theta0[k])
        outputs = []
        for sign in (1.0, -1.0):
            theta = system.theta0.copy()
            theta[k] += sign * step_size
            theta = jnp.asarray(theta)

            def chunk(state, left, _num_records, theta=theta):
                return relax_chunk(state, theta), left - chunk_steps, None, None

            def balanced(state, _records, _valid, _left, theta=theta):
                residual = np.asarray(evaluate(state, theta)[0])
                return [0] if np.max(np.abs(residual[:-2])) < tolerance * load else []

            relaxed, _ = drive(
                chunk,
                equilibrium.state,
                [max_chunks * chunk_steps],
                chunk_steps,
                chunk_steps,
                errors=lambda state: np.atleast_1d(np.asarray(state.error)),
                grow=runner.grow,
                fail=functools.partial(_relaxation_failed, system.wrt[k], sign),
                accept=balanced,
            )
            outputs.append(np.asarray(evaluate(relaxed, theta)[1]))
        columns.append((outputs[0] - outputs[1]) / (2.0 * step_size))
    return np.stack(columns, axis=1)


def _relaxation_failed(parameter, sign, error, new, state):
    """The :class:`SimulationError` of a relaxation after a parameter step that ran away."""
    return SimulationError(
        f"the relaxation after stepping {parameter} by {'+' if sign > 0 else '-'}h stopped in the chunk "
        f"ending at step {int(new.step)}: "
        + "; ".join(describe(int(np.asarray(error)[0])))
        + ". Lower relative_step.",
        state=state,
    )


def sensitivity(
    config: TriaxialConfig,
    outputs=OUTPUTS,
    wrt=tuple(PARAMETERS),
    finite_differences: bool = True,
    tolerance: float = 1e-7,
) -> SensitivityTable:
    """The sensitivity table of a configuration's consolidated equilibrium (module docstring).

    Runs in float64 (scoped to this call).

    Args:
      config: the test; it is consolidated to an unbalanced-force ratio ≤ ``tolerance``.
      outputs: names from :data:`OUTPUTS` (stresses in Pa).
      wrt: names from :data:`PARAMETERS` (configuration fields, in their units: kPa, mm, degrees, N/m).
      finite_differences: also compute the continuation differences (the check column).
      tolerance: the unbalanced-force ratio that ends consolidation (dimensionless).

    Returns:
      A :class:`SensitivityTable`: derivatives in Pa per unit of the parameter, elasticities dimensionless.

    Raises:
      ValueError: an unknown output or parameter.
    """
    unknown = [name for name in outputs if name not in OUTPUTS]
    if unknown:
        raise ValueError(f"outputs {unknown}: choose from {', '.join(OUTPUTS)}.")
    _check_wrt(wrt)
    config = dataclasses.replace(config, float64=True)
    seconds = {}
    with jax.enable_x64(True):
        start = time.perf_counter()
        equilibrium = consolidated(config, tolerance)
        seconds["consolidation"] = time.perf_counter() - start
        start = time.perf_counter()
        values, derivative, size = implicit_sensitivities(equilibrium, wrt)
        seconds["implicit"] = time.perf_counter() - start
        check = np.full(derivative.shape, np.nan)
        if finite_differences:
            start = time.perf_counter()
            check = continuation_differences(equilibrium, wrt)
            seconds["finite_differences"] = time.perf_counter() - start
    rows = []
    at = parameter_values(config, wrt)
    for name in outputs:
        i = OUTPUTS.index(name)
        for k, parameter in enumerate(wrt):
            x = float(at[k])
            y = float(values[i])
            rows.append(
                {
                    "output": name,
                    "parameter": parameter,
                    "value": y,
                    "at": x,
                    "derivative": float(derivative[i, k]),
                    "finite_difference": float(check[i, k]),
                    "elasticity": float(derivative[i, k]) * x / y if y != 0.0 else math.nan,
                }
            )
    return SensitivityTable(rows, seconds, size)


def format_table(table: SensitivityTable) -> str:
    """The table as text: stresses in kPa, derivatives in kPa per unit of the parameter.

    ``rel. err`` is |implicit − difference| / max(|implicit|, |difference|); ``~0`` where both are below an
    elasticity of 1e-6 (zero within the differences' floor).
    """
    lines = [
        f"{'output':<26}{'parameter':<30}{'y (kPa)':>10}{'x':>10}{'dy/dx':>13}{'difference':>13}"
        f"{'rel. err':>10}{'d ln y/d ln x':>15}"
    ]
    for row in table.rows:
        derivative, check = 1e-3 * row["derivative"], 1e-3 * row["finite_difference"]
        scale = abs(row["value"]) / max(abs(row["at"]), 1e-300)  # dy/dx of an elasticity of 1, Pa per unit
        if not np.isfinite(check):
            error = "—"
        elif max(abs(row["derivative"]), abs(row["finite_difference"])) < 1e-6 * scale:
            error = "~0"  # both below an elasticity of 1e-6: zero within the differences' floor
        else:
            error = f"{abs(derivative - check) / max(abs(check), abs(derivative)):.1e}"
        lines.append(
            f"{row['output']:<26}{row['parameter']:<30}{1e-3 * row['value']:>10.4g}{row['at']:>10.4g}"
            f"{derivative:>13.5g}{check:>13.5g}{error:>10}{row['elasticity']:>15.4g}"
        )
    seconds = ", ".join(f"{name} {value:.1f} s" for name, value in table.seconds.items())
    lines.append(f"{table.unknowns} unknowns; {seconds}")
    return "\n".join(lines)
