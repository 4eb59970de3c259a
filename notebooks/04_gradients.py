# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.7
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Gradients: sensitivities of the initial membrane stresses, and an inverse problem
#
# membrax differentiates the simulator two ways:
#
# 1. **at the consolidated equilibrium**, by the implicit function theorem (`membrax.sensitivity`): the
#    derivatives of the initial external and internal stresses (the paper's Table 3) with respect to
#    σc, E_m, t_m, the friction angles and k_n, each checked against central differences of the
#    simulator. This works in the paper's own mode.
# 2. **through a run, consolidation and shearing**, by reverse mode over checkpointed windows of steps
#    (`membrax.gradients`), vmapped over a batch of members in one compiled call. This needs the smooth
#    mode, `viscous_damping = true`: the paper's Cundall local damping, F − α|F| sign(v), makes a run
#    discontinuous in its parameters, so no derivative exists through a transient.
#
# The second is what sees friction (at the equilibrium every contact is stuck, so the friction angles'
# implicit derivatives are exactly 0), and it drives the inverse problem at the end: recover E_m and the
# membrane friction angle from the initial internal stresses, starting 50 % off, with optax's L-BFGS,
# against Nelder–Mead.
#
# Smoke mode (`MEMBRAX_SMOKE=1`, what CI sets): a 4 × 4 × 5 specimen throughout, rollouts of 1,000 steps
# of consolidation and 1,000 of shearing (gradients; their check against central differences is left to
# tests/test_gradients.py, which runs the same rollout) and 2,000 steps of consolidation (the inverse
# problem, by L-BFGS alone).
# Full size: the demo specimen (6 × 10, membrane edge D/3) for the implicit sensitivities, and the
# 4 × 4 × 5 specimen with 4,000 steps of consolidation and 4,000 of shearing over Table 1's 3 × 3 grid.
#
# **Time** (2 CPU cores): smoke 2 min 13 s alone (the inverse problem 48 s of it), about 5 min beside
# another pytest worker (less when the gradient tests ran first: their programs come from the compilation
# cache); full size about 25 min (estimated: the implicit sensitivities 2 min 26 s on the demo specimen;
# the 3 × 3 rollout Jacobian took 2 min 35 s through 1,000 + 1,000 steps, so about 10 min at 4,000 +
# 4,000; the inverse problem about 2 min at 4,000 steps).

# %%
import dataclasses
import os
from pathlib import Path

import jax
import matplotlib.pyplot as plt
import numpy as np

import membrax
from calibrate import inverse
from membrax import gradients, sensitivities

jax.config.update("jax_enable_x64", True)  # derivative checks in float64 (a notebook may; the library never)
SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"

TINY = dict(particles_across=4, layers=5, membrane_edges_per_diameter=2.0)
DEMO = dict(particles_across=6, layers=10, membrane_edges_per_diameter=3.0)
SENSITIVITY_SPECIMEN = TINY if SMOKE else DEMO
# Smoke: the sizes of tests/test_gradients.py, so the two share compiled programs (conftest's cache).
ROLLOUT_STEPS = 1000 if SMOKE else 4000  # consolidation, then as many of shearing
INVERSE_STEPS = 2000 if SMOKE else 4000

# %% [markdown]
# ## 1. Implicit sensitivities at the consolidated equilibrium (the paper's mode)
#
# The table has, for each output and parameter, the value, dy/dx by the implicit function theorem,
# the same by continuation differences of the simulator, their relative gap, and the elasticity
# d ln y/d ln x (kPa, and kPa per unit of the parameter).

# %%
config = membrax.TriaxialConfig(**SENSITIVITY_SPECIMEN, cell_pressure_kpa=10.0, membrane_thickness_mm=5.0)
wrt = (
    ("cell_pressure_kpa", "membrane_modulus_kpa")
    if SMOKE
    else ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_thickness_mm")
)
table = membrax.sensitivity(config, wrt=wrt)
print(sensitivities.format_table(table))

# %% [markdown]
# Checks against theory: the servo holds the ram at σc A₀ and the cell pressure is σc, so the external
# stresses have dσ_ext/dσc = 1 (1,000 Pa per kPa) and do not depend on the membrane. The internal
# stresses' implicit derivatives agree with the simulator's differences within 1e-3.

# %%
rows = {(r["output"], r["parameter"]): r for r in table.rows}
for output in ("external_axial_stress", "external_radial_stress"):
    assert abs(rows[output, "cell_pressure_kpa"]["derivative"] / 1e3 - 1.0) < 1e-5
    scale = rows[output, "cell_pressure_kpa"]["derivative"]
    assert abs(rows[output, "membrane_modulus_kpa"]["derivative"]) < 1e-6 * scale
for output in ("internal_axial_stress", "internal_radial_stress"):
    for parameter in wrt:
        row = rows[output, parameter]
        gap = abs(row["derivative"] - row["finite_difference"]) / abs(row["finite_difference"])
        assert gap < 1e-3 or abs(row["elasticity"]) < 1e-2, (output, parameter, gap)

# %% [markdown]
# ### The Table 1 grid, as elasticities
#
# `examples/table1_sensitivities.py` runs this for the paper's 3 × 3 grid on the small specimen of
# `membrax reproduce --size small` (about 2–6 min per case on 2 cores; its output ships in `docs/`).

# %%
shipped = Path("..") / "docs" / "table1_sensitivities.csv"
if not shipped.exists():
    shipped = Path("docs") / "table1_sensitivities.csv"
if shipped.exists():
    import csv

    with open(shipped) as handle:
        grid = list(csv.DictReader(handle))
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), sharey=True)
    parameters = ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_thickness_mm")
    for axis, parameter in zip(axes, parameters, strict=True):
        for output, marker in (("additional_axial_stress", "o"), ("additional_radial_stress", "s")):
            mine = [r for r in grid if r["parameter"] == parameter and r["output"] == output]
            for thickness in sorted({float(r["membrane_thickness_mm"]) for r in mine}):
                chosen = sorted(
                    (float(r["cell_pressure_kpa"]), float(r["elasticity"]))
                    for r in mine
                    if float(r["membrane_thickness_mm"]) == thickness
                )
                axis.plot(
                    *zip(*chosen, strict=True),
                    marker=marker,
                    label=f"{output.split('_')[1]} Δσ, {thickness:g} mm",
                )
        axis.set_xscale("log")
        axis.set_xlabel("σc (kPa)")
        axis.set_title(f"elasticity w.r.t. {parameter}", fontsize=9)
        axis.axhline(0.0, color="0.7", linewidth=0.8)
    axes[0].set_ylabel("d ln y / d ln x")
    axes[-1].legend(fontsize=7)
    plt.tight_layout()
    plt.show()
else:
    print("docs/table1_sensitivities.csv not found: run examples/table1_sensitivities.py")

# %% [markdown]
# ## 2. Reverse mode through consolidation and shearing, vmapped over members (the smooth mode)
#
# `shearing_rollout` makes a batch's run, consolidation then drained shearing, a function of its
# parameters (`consolidation_rollout` stops at the end of consolidation); each member's steps run in
# windows of 50 under `jax.checkpoint`. The shearing here is fast, at an inertial number of 0.01 with a
# ramp to 0.1 % strain, so that 1,000 steps reach ε_a ≈ 0.8 % at 10 kPa (ε̇ ∝ √σc: twice that at 40 kPa).
# `rollout_jacobian` returns all members' values and Jacobians from one compiled call. The check:
# central differences with h = 1e-6 θ (small enough that no contact opens, closes or starts to slide
# between θ ± h, the condition for the two to agree). Smoke mode (CI) skips the differences, six more
# forward rollouts: tests/test_gradients.py runs this same rollout (members, parameters and steps) and
# checks the Jacobian against them, row by row, in the same CI run.

# %%
smooth = membrax.TriaxialConfig(**TINY, float64=True, viscous_damping=True)
if SMOKE:
    cases = [(10.0, 5.0), (40.0, 2.5)]
else:
    cases = [(p, t) for t in (2.5, 3.33, 5.0) for p in (10.0, 40.0, 100.0)]
shearing = {"inertial_number": 0.01, "shear_ramp_strain": 0.001}
members = [
    dataclasses.replace(smooth, cell_pressure_kpa=p, membrane_thickness_mm=t, **shearing) for p, t in cases
]
rollout_wrt = ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_friction_angle_deg")
rollout = gradients.shearing_rollout(
    members, rollout_wrt, shear_steps=ROLLOUT_STEPS, consolidation_steps=ROLLOUT_STEPS
)
values, jacobian = gradients.rollout_jacobian(rollout)
internal = [sensitivities.OUTPUTS.index(n) for n in ("internal_axial_stress", "internal_radial_stress")]
for b, (p, t) in enumerate(cases):
    elasticity = jacobian[b, internal] * rollout.theta0[b] / values[b, internal][:, None]
    print(
        f"{p:g} kPa, {t:g} mm: internal σ1, σ3 = {values[b, internal] / 1e3} kPa;"
        f" elasticities (σc, E_m, φ_m):\n{np.array2string(elasticity, precision=3)}"
    )
if not SMOKE:
    differences = gradients.rollout_differences(rollout, relative_step=1e-6)
    gap = np.abs(jacobian[:, internal] - differences[:, internal]) / np.abs(differences[:, internal])
    print(f"largest relative gap to the differences: {gap.max():.1e}")
    assert gap.max() < 1e-3
assert np.allclose(jacobian[:, 1, 0], 1e3)  # dσ_ext,radial/dσc = 1: the cell pressure itself
# sheared: the internal deviator σ1 − σ3 exceeds the cell pressure
assert np.all(values[:, internal[0]] - values[:, internal[1]] > 1e3 * rollout.theta0[:, 0])

# %% [markdown]
# ## 3. The inverse problem: E_m and the membrane friction angle from the initial internal stresses
#
# Observations: internal σ1 and σ3 at the end of the rollout, generated at E_m = 1400 kPa and φ_m = 25°.
# Start: E_m = 2100 kPa and φ_m = 12.5° (50 % off each). L-BFGS (optax) on reverse-mode gradients against
# Nelder–Mead (scipy) on values only, both to a squared relative misfit below 1e-10.

# %%
target = dataclasses.replace(smooth, cell_pressure_kpa=10.0, membrane_thickness_mm=5.0)
problem = inverse.InverseProblem(
    target, ("membrane_modulus_kpa", "membrane_friction_angle_deg"), steps=INVERSE_STEPS
)
observed = problem.observe()  # at the configuration's own E_m = 1400 kPa and φ_m = 25°
start = {"membrane_modulus_kpa": 2100.0, "membrane_friction_angle_deg": 12.5}
by_gradient = inverse.invert(problem, observed, start)
# Smoke mode (CI) runs L-BFGS alone: Nelder–Mead's ~130 forward calls are a comparison, not a check.
methods = {"L-BFGS": by_gradient}
if not SMOKE:
    methods["Nelder–Mead"] = inverse.invert_gradient_free(problem, observed, start)
for name, result in methods.items():
    print(
        f"{name:<12} iterations {result.iterations:>3}, forward calls {result.value_calls:>4}, "
        f"forward + reverse calls {result.gradient_calls:>3}, {result.seconds:.0f} s: {result.parameters}"
    )

fig, axis = plt.subplots(figsize=(5, 3.5))
for name, result in methods.items():
    axis.semilogy([h[0] for h in result.history], [h[1] for h in result.history], marker=".", label=name)
axis.set_xlabel("iteration")
axis.set_ylabel("misfit J")
axis.legend()
plt.tight_layout()
plt.show()

# %%
for result in methods.values():
    assert abs(result.parameters["membrane_modulus_kpa"] / 1400.0 - 1.0) < 0.02
    assert abs(result.parameters["membrane_friction_angle_deg"] / 25.0 - 1.0) < 0.02
    assert result.history[0][1] > 1e-3 > result.history[-1][1]  # the misfit falls from J(start)
# L-BFGS to the tolerance in few forward + reverse calls
assert by_gradient.objective < 1e-10 and by_gradient.gradient_calls <= 30
