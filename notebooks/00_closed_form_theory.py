# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Closed-form theory for membrane corrections
#
# What the classical formulas in `membrax.theory` predict for a ballast-size specimen, before any simulation:
#
# 1. Rowe's peak strength for FCC spheres against interparticle friction (the simulator's reference);
# 2. the size of the classical membrane corrections against axial strain for the paper's three membranes;
# 3. how much they change the mobilised friction angle at the paper's cell pressures.
#
# The assertions are hand checks: the notebook fails in CI if a number drifts.
#
# **Time**: no simulation, so the same at full size and in smoke mode (`MEMBRAX_SMOKE=1`, what CI sets):
# 4 s measured on 2 CPU cores (see docs/benchmarks.md, "Notebooks").

# %%
import math
import os

import jax.numpy as jnp
import matplotlib.pyplot as plt

from membrax import theory

SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"  # nothing to shrink here: closed forms only

# %% [markdown]
# ## 1. Rowe (1962): FCC peak friction angle

# %%
friction_deg = jnp.linspace(0.0, 40.0, 81)
phi_exact = theory.rowe_peak_friction_angle_deg(friction_deg, theory.FCC)
phi_paper = theory.rowe_peak_friction_angle_deg(friction_deg, theory.FCC_PAPER)
fig, ax = plt.subplots(figsize=(5, 3.5))
ax.plot(friction_deg, phi_exact, label="tan α = 2 (exact)")
ax.plot(friction_deg, phi_paper, "--", label="α = 63.5° (paper)")
ax.axvline(25.0, color="grey", lw=0.5)
ax.set(xlabel="interparticle friction φμ (°)", ylabel="peak φ' (°)", title="Rowe, FCC [100]")
ax.legend()
# φμ = 25°: 43.79° (exact) and the paper's 43.85°.
assert round(float(theory.rowe_peak_friction_angle_deg(25.0, theory.FCC)), 2) == 43.79
assert round(float(theory.rowe_peak_friction_angle_deg(25.0, theory.FCC_PAPER)), 2) == 43.85

# %% [markdown]
# ## 2. Classical corrections against axial strain (250 mm specimen, E_m = 1400 kPa)

# %%
modulus_kpa, diameter_m = 1400.0, 0.25
axial_strain = jnp.linspace(0.0, 0.10, 101)
fig, ax = plt.subplots(figsize=(5, 3.5))
for thickness_mm in (2.5, 10 / 3, 5.0):
    t = thickness_mm / 1000
    astm = theory.astm_shell_correction(modulus_kpa, t, diameter_m, axial_strain).axial_stress
    hoop = theory.hoop_tension_correction(modulus_kpa, t, diameter_m, axial_strain).radial_stress
    ax.plot(100 * axial_strain, astm, label=f"ASTM shell, {thickness_mm:.2f} mm")
    ax.plot(100 * axial_strain, hoop, ":", label=f"hoop tension, {thickness_mm:.2f} mm")
ax.set(xlabel="axial strain (%)", ylabel="stress increment (kPa)")
ax.legend(fontsize=7)
# Hand check: ASTM at 10 %, 5 mm: 4 · 1400 · 0.005 · 0.1 / 0.25 = 11.2 kPa.
astm_10 = float(theory.astm_shell_correction(1400.0, 0.005, 0.25, 0.10).axial_stress)
assert math.isclose(astm_10, 11.2, rel_tol=1e-6)  # float32

# %% [markdown]
# ## 3. Effect on φ' at the paper's cell pressures (5 mm membrane, ε_a = 5 %, ε_v = −3 %)

# %%
rowe_ratio = float(theory.rowe_stress_ratio(math.radians(25.0), theory.FCC))
for cell_kpa in (10.0, 40.0, 100.0):
    sigma_1 = rowe_ratio * cell_kpa  # a test that measured exactly Rowe's ratio
    correction = theory.right_cylinder_shell_correction(1400.0, 0.005, 0.25, 0.05, -0.03)
    corrected = theory.apply_membrane_correction(sigma_1, cell_kpa, correction)
    before = float(theory.mobilised_friction_angle_deg(sigma_1, cell_kpa))
    after = float(theory.mobilised_friction_angle_deg(*corrected))
    print(
        f"{cell_kpa:5.0f} kPa: measured {before:.2f}°, corrected {after:.2f}°, change {after - before:+.2f}°"
    )
    assert after < before  # both increments lower the ratio: the correction always reduces φ'
# The change shrinks as the cell pressure grows (the membrane matters most at low pressure).
changes = []
for cell_kpa in (10.0, 100.0):
    c = theory.right_cylinder_shell_correction(1400.0, 0.005, 0.25, 0.05, -0.03)
    s = theory.apply_membrane_correction(rowe_ratio * cell_kpa, cell_kpa, c)
    changes.append(
        float(
            theory.mobilised_friction_angle_deg(rowe_ratio * cell_kpa, cell_kpa)
            - theory.mobilised_friction_angle_deg(*s)
        )
    )
assert changes[0] > 5 * changes[1]
