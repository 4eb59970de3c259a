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
# # A parameter study beyond the paper: membrane modulus × membrane friction
#
# The paper varied the cell pressure and the membrane thickness at one latex (E_m = 1400 kPa) and one
# membrane–particle friction. Here the grid is the membrane's Young's modulus E_m against its friction
# angle φ_m, at 40 kPa in a 2.5 mm membrane: every member differs only in traced parameters
# (`membrax.assemble.BATCHED_FIELDS`), so the whole grid runs as **one** compiled batch (`lax.map` over each
# CPU device's members, `vmap` on a GPU, sharded over the devices). `calibrate/designs.py` specifies the
# calibration study the same way; `membrax sweep config.toml --grid membrane_modulus_kpa=700,1400,2800,5600
# --grid membrane_friction_angle_deg=10,25,40` is the command-line equivalent.
#
# The question: how does the additional stress Δσ at the start of shearing (internal − external, the
# paper's Table 3) follow Molenkamp & Luger's indentation ratio α/D = C (1 + e)^(4/9) (D/t_m)^(1/3)
# (σc/E_m)^(1/3), the paper's Eq. 2 and Fig. 9, when α/D moves through E_m instead of σc and t_m?
#
# Full size: the demo's specimen (6 × 10, membrane edge D/3, I = 5e-3), 4 moduli × 3 friction angles =
# 12 members, sheared to 5 %: 1 min 53 s measured on 2 CPU cores. Smoke mode (`MEMBRAX_SMOKE=1`, what
# CI sets): 2 × 2 members on a 4 × 5-layer specimen to 0.4 %, 53–61 s measured.

# %%
import jax

from membrax.devices import split_cpu_devices

print(split_cpu_devices(), "CPU devices;", jax.default_backend(), "backend")

# %%
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import membrax
from membrax import analysis, paper, theory

SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"
OUT = Path(tempfile.mkdtemp(prefix="membrax_03_"))
CELL_PRESSURE_KPA, THICKNESS_MM = 40.0, 2.5

if SMOKE:
    GRID = {"membrane_modulus_kpa": (700.0, 2800.0), "membrane_friction_angle_deg": (10.0, 40.0)}
    BASE = membrax.TriaxialConfig(
        **{
            **membrax.SMOKE_CONFIG,
            "name": "study_smoke",
            "cell_pressure_kpa": CELL_PRESSURE_KPA,
            "membrane_thickness_mm": THICKNESS_MM,
        }
    )
else:
    GRID = {
        "membrane_modulus_kpa": (700.0, 1400.0, 2800.0, 5600.0),
        "membrane_friction_angle_deg": (10.0, 25.0, 40.0),
    }
    BASE = membrax.TriaxialConfig(
        **{
            **membrax.DEMO_CONFIG,
            "name": "study",
            "cell_pressure_kpa": CELL_PRESSURE_KPA,
            "membrane_thickness_mm": THICKNESS_MM,
            "target_axial_strain": 0.05,
        }
    )
print(
    f"{'smoke' if SMOKE else 'full size'}: {BASE.particles_across} × {BASE.layers} specimen, grid {GRID};",
    f"files in {OUT}",
)

# %%
study = membrax.run_sweep(BASE, GRID, OUT / "study", progress=not SMOKE)
print(f"{study.seconds:.0f} s for {np.prod([len(v) for v in GRID.values()])} members")

# %% [markdown]
# ## Additional stresses at the start of shearing against α/D
#
# One row per member: the stresses of the first shearing record (the end of consolidation) and α/D of
# Eq. 2 with C = 0.275 and the FCC void ratio.

# %%
rows = []
for modulus in GRID["membrane_modulus_kpa"]:
    for friction in GRID["membrane_friction_angle_deg"]:
        member = study.member(membrane_modulus_kpa=modulus, membrane_friction_angle_deg=friction)
        start = analysis.initial_state(member)
        peak = analysis.peak(member)
        rows.append(
            {
                "membrane_modulus_kpa": modulus,
                "membrane_friction_angle_deg": friction,
                "indentation_ratio": float(
                    theory.molenkamp_luger_indentation_ratio(
                        theory.FCC_VOID_RATIO,
                        BASE.particle_diameter_mm,
                        THICKNESS_MM,
                        CELL_PRESSURE_KPA,
                        modulus,
                    )
                ),
                "sigma3_external_kpa": start["sigma3_external_kpa"],
                "sigma1_external_kpa": start["sigma1_external_kpa"],
                "additional_sigma1_kpa": start["sigma1_internal_kpa"] - start["sigma1_external_kpa"],
                "additional_sigma3_kpa": start["sigma3_internal_kpa"] - start["sigma3_external_kpa"],
                "peak_external_deg": peak["peak_external_friction_angle_deg"],
                "peak_internal_deg": peak["peak_internal_friction_angle_deg"],
            }
        )
table = pd.DataFrame(rows).set_index(["membrane_modulus_kpa", "membrane_friction_angle_deg"])
table.round(3)

# %% [markdown]
# The paper's nine cases (its Table 3, α/D through σc and t_m at E_m = 1400 kPa) are drawn for context:
# the grey crosses.

# %%
paper_points = []
for (pressure, thickness), values in paper.PAPER_TABLE_3.items():
    ratio = float(
        theory.molenkamp_luger_indentation_ratio(
            theory.FCC_VOID_RATIO, paper.PARTICLE_DIAMETER_MM, thickness, pressure, paper.MEMBRANE_MODULUS_KPA
        )
    )
    paper_points.append(
        (
            ratio,
            (values["sigma1_internal_kpa"] - values["sigma1_external_kpa"]) / pressure,
            (values["sigma3_internal_kpa"] - values["sigma3_external_kpa"]) / pressure,
        )
    )
paper_points = np.array(paper_points)

fig, axes = plt.subplots(1, 2, figsize=(10, 4), layout="constrained")
for ax, column, label, k in (
    (axes[0], "additional_sigma1_kpa", "Δσ1 / σc (axial)", 1),
    (axes[1], "additional_sigma3_kpa", "Δσ3 / σc (radial)", 2),
):
    ax.plot(paper_points[:, 0], paper_points[:, k], "x", color="0.6", label="paper, Table 3")
    for friction, marker in zip(GRID["membrane_friction_angle_deg"], "osD^", strict=False):
        part = table.xs(friction, level="membrane_friction_angle_deg")
        ax.plot(
            part["indentation_ratio"],
            part[column] / CELL_PRESSURE_KPA,
            marker + "-",
            mfc="none",
            label=f"membrax, φ_m = {friction:g}°",
        )
    ax.axvline(0.2, color="0.8", lw=0.8)  # Molenkamp & Luger's stated validity: α/D > 0.2
    ax.set(xlabel="indentation ratio α/D (Molenkamp & Luger, C = 0.275)", ylabel=label)
    ax.grid(True, lw=0.5, alpha=0.5)
axes[0].legend(fontsize=8)
_ = fig.suptitle(
    f"Initial membrane stress at σc = {CELL_PRESSURE_KPA:g} kPa, t_m = {THICKNESS_MM:g} mm; "
    "E_m varies along each line"
)

# %% [markdown]
# ## During shearing
#
# The membrane's friction acts once the membrane slides over the spheres: φ' from the external and the
# internal stresses against axial strain, one line per member.

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 4), layout="constrained", sharey=True)
for modulus in GRID["membrane_modulus_kpa"]:
    for friction, style in zip(GRID["membrane_friction_angle_deg"], ("-", "--", ":"), strict=False):
        member = study.member(membrane_modulus_kpa=modulus, membrane_friction_angle_deg=friction)
        derived = analysis.derived_quantities(member)
        strain = 100 * analysis.record(member, "axial_strain")
        for ax, side in zip(axes, ("external", "internal"), strict=True):
            ax.plot(
                strain,
                derived[f"{side}_friction_angle_deg"],
                style,
                label=f"E_m {modulus:g} kPa, φ_m {friction:g}°",
            )
for ax, side in zip(axes, ("external", "internal"), strict=True):
    ax.set(xlabel="axial strain εa (%)", title=f"φ' from the {side} stresses")
    ax.grid(True, lw=0.5, alpha=0.5)
axes[0].set_ylabel("mobilised friction angle φ' (°)")
_ = axes[1].legend(fontsize=7)

# %% [markdown]
# ## Checks
#
# - Eq. 2 scales as E_m^(−1/3): α/D at the stiffest membrane over α/D at the softest is
#   (E_min/E_max)^(1/3).
# - The external stresses at the start of shearing are the cell pressure (σ3) and the servo's σc (σ1,
#   within its 1 % stop test), whatever the membrane.
# - A stiffer membrane carries more of the load: at each friction angle the additional axial stress grows
#   with E_m (the membrane's tension, E_m t_m times its strain, pulls the platens together).
# - Membrane friction is left unchecked: it acts only through the consolidation's path (consolidation is
#   isotropic and ends with the membrane's contacts stuck, so d/dφ_m = 0 at the equilibrium,
#   docs/gradients.md), but over 10°–40° that path is not a small change (the table above).

# %%
moduli = np.array(GRID["membrane_modulus_kpa"])
ratios = table.xs(GRID["membrane_friction_angle_deg"][0], level="membrane_friction_angle_deg")[
    "indentation_ratio"
]
np.testing.assert_allclose(ratios.iloc[-1] / ratios.iloc[0], (moduli[0] / moduli[-1]) ** (1 / 3), rtol=1e-5)

np.testing.assert_allclose(table["sigma3_external_kpa"], CELL_PRESSURE_KPA, rtol=1e-5)
np.testing.assert_allclose(table["sigma1_external_kpa"], CELL_PRESSURE_KPA, rtol=0.01)

by_modulus = table["additional_sigma1_kpa"].unstack("membrane_friction_angle_deg")  # rows E_m, columns φ_m
print("Δσ1 (kPa), rows E_m, columns φ_m:\n", by_modulus.round(3))
assert np.all(np.diff(by_modulus.to_numpy(), axis=0) > 0.0)
friction_effect = np.ptp(by_modulus.to_numpy(), axis=1)
print("φ_m moves Δσ1 by", dict(zip(by_modulus.index, np.round(friction_effect, 3), strict=True)), "kPa")
