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
# # Reproduce the paper: Table 1 → Tables 2–3 and Figs 5–9
#
# The reference study sheared an FCC packing of 25 mm spheres (10 across, 25 layers) in latex membranes
# of 2.5, 3.33 and 5 mm (E_m = 1400 kPa) at cell pressures of 10, 40 and 100 kPa: its Table 1, a 3 × 3
# grid. membrax runs the grid as **one** batched, compiled simulation (`membrax.run_sweep`: the members'
# states stacked on an axis, `lax.map` over each CPU device's members, `vmap` on a GPU, sharded over the
# devices), then compares the peak friction angles (Table 2) and the stresses at the start of shearing
# (Table 3) with the paper's, and draws Figs 5–9. `membrax reproduce --size paper` does exactly this
# (`membrax.reproduce.reproduce`).
#
# Full size is the paper's specimen (`membrax.reproduce.SIZES["paper"]`: 10 × 25, a membrane of edge
# D/5, inertial number 1e-3, float64, consolidation to an unbalanced-force ratio of 1e-3): **about
# 14–18 min on 2 CPU cores** (13 min 46 s and 18 min 13 s measured for `membrax reproduce --size paper` on
# two machines, 2026-12-07). Set
# `SIZE = "small"` below for the 6 × 10 specimen (2 min 52 s measured): a test of the pipeline, not of the
# paper's numbers. Smoke mode (`MEMBRAX_SMOKE=1`, what CI sets) keeps the 3 × 3 grid on a 4 × 5-layer
# specimen sheared to 0.4 %, in float32: 65–86 s measured, most of it building and compiling the nine members.

# %% [markdown]
# On a CPU, split the processor into one JAX device per core *before* anything else starts JAX, so that
# each core advances whole members (a membrane test's arrays are too small for XLA to split one operation
# well over cores). `membrax sweep` and `membrax reproduce` do this themselves.

# %%
import jax

from membrax.devices import split_cpu_devices

print(split_cpu_devices(), "CPU devices;", jax.default_backend(), "backend")

# %%
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

import membrax
from membrax import paper, plots, theory
from membrax.reproduce import SIZES

SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"
SIZE = "paper"  # or "small": the 6 × 10 specimen of `membrax reproduce --size small`
OUT = Path(tempfile.mkdtemp(prefix="membrax_02_"))

if SMOKE:
    BASE = membrax.TriaxialConfig(**{**membrax.SMOKE_CONFIG, "name": "reproduce_smoke"})
else:
    BASE = membrax.TriaxialConfig(name=f"reproduce_{SIZE}", **SIZES[SIZE])
print(
    f"{'smoke' if SMOKE else SIZE}: {BASE.particles_across} across × {BASE.layers} layers, membrane edge "
    f"D/{BASE.membrane_edges_per_diameter:g}, I = {BASE.inertial_number:g}, to "
    f"{100 * BASE.target_axial_strain:g} %, {'float64' if BASE.float64 else 'float32'}; files in {OUT}"
)

# %% [markdown]
# ## Table 1: the grid
#
# `membrax.paper` holds the paper's numbers (and nothing else does): its Table 1 grid, fixed parameters,
# Tables 2–3 and Fig. 9.

# %%
print("Table 1 grid:", paper.TABLE_1_GRID)
print(
    f"D = {paper.PARTICLE_DIAMETER_MM:g} mm, E_m = {paper.MEMBRANE_MODULUS_KPA:g} kPa, "
    f"φ_μ = {paper.INTERPARTICLE_FRICTION_DEG:g}°, specimen {paper.SPECIMEN_DIAMETER_MM:g} mm across"
)

# %%
sweep = membrax.run_sweep(BASE, paper.TABLE_1_GRID, OUT / "sweep", progress=not SMOKE)
print(f"{sweep.seconds:.0f} s; files: {', '.join(sorted(sweep.files))}")
sweep.dataset[["consolidation_steps", "shear_steps", "sigma1_external_kpa", "sigma1_internal_kpa"]]

# %%
cases = {
    (float(p), float(t)): sweep.member(cell_pressure_kpa=p, membrane_thickness_mm=t)
    for p in paper.PAPER_CELL_PRESSURES_KPA
    for t in paper.PAPER_THICKNESSES_MM
}

# %% [markdown]
# ## Table 2: peak mobilised friction angle, external and internal
#
# Ours beside the paper's (`paper_…`) and the difference.

# %%
table_2 = pd.DataFrame(paper.table_2(cases)).set_index(["cell_pressure_kpa", "membrane_thickness_mm"])
table_2.round(2)  # columns: ours, paper_…, difference_… (ours − paper)

# %% [markdown]
# ## Table 3: principal stresses at the start of shearing, and the additional (membrane) stresses
#
# Δσ = internal − external. `additional_sigma3_centres_kpa` reads the paper's "right cylinder" through the
# boundary spheres' centres rather than the platen's (docs/model.md, protocol notes).

# %%
table_3 = pd.DataFrame(paper.table_3(cases, particle_radius=BASE.particle_radius)).set_index(
    ["cell_pressure_kpa", "membrane_thickness_mm"]
)
table_3.filter(regex="^(paper_)?(sigma|additional)").round(2)  # the differences are in table_3 too

# %%
written = paper.write_tables(cases, OUT, particle_radius=BASE.particle_radius)  # CSV and Markdown
print("written:", ", ".join(p.name for p in written.values()))

# %% [markdown]
# ## Figs 5–8: the 10 kPa test in the 5 mm membrane

# %%
test_10_5 = cases[(10.0, 5.0)]
plots.plot_friction_angles(test_10_5)

# %%
plots.plot_additional_stresses(test_10_5)

# %%
plots.plot_axial_ratio_and_strain_ratio(test_10_5)

# %%
plots.plot_radial_ratio_and_radial_strain(test_10_5)

# %% [markdown]
# ## Fig. 9: Molenkamp & Luger's indentation ratio against the initial axial stress ratio
#
# α/D = C (1 + e)^(4/9) (D/t_m)^(1/3) (σc/E_m)^(1/3) with C = 0.275 (the paper's Eq. 2) on the left axis;
# −(σ1,int/σ1,ext − 1) at the start of shearing on the right. Open markers: ours; filled: the paper's
# Table 3.

# %%
ours_fig9 = paper.fig9_data(
    cases, particle_diameter_mm=BASE.particle_diameter_mm, membrane_modulus_kpa=BASE.membrane_modulus_kpa
)
plots.plot_fig9(ours_fig9, paper=paper.paper_fig9_data())

# %% [markdown]
# ## Checks
#
# - External stresses at the start of shearing: σ3 is the cell pressure; σ1 is the servo's σc (within its
#   1 % stop test), for all nine members.
# - The paper's trend (its Table 3): at every cell pressure the thicker the membrane, the larger the
#   additional axial stress Δσ1 = σ1,int − σ1,ext (the membrane's axial tension adds to the load the
#   spheres carry).
# - Fig. 9's α/D is the paper's Eq. 2, and it grows as σc^(1/3): α/D(100 kPa)/α/D(10 kPa) = 10^(1/3).

# %%
for (pressure, thickness), row in table_3.iterrows():
    assert abs(row["sigma3_external_kpa"] / pressure - 1.0) < 1e-5, (pressure, thickness)
    assert abs(row["sigma1_external_kpa"] / pressure - 1.0) < 0.01, (pressure, thickness)

for pressure in paper.PAPER_CELL_PRESSURES_KPA:
    delta = [table_3.loc[(pressure, t), "additional_sigma1_kpa"] for t in paper.PAPER_THICKNESSES_MM]
    print(f"{pressure:5g} kPa: Δσ1 {np.round(delta, 2)} kPa for t_m = {paper.PAPER_THICKNESSES_MM} mm")
    assert np.all(np.diff(delta) > 0.0), pressure

for thickness, series in ours_fig9.items():
    by_hand = (
        0.275
        * (1.0 + theory.FCC_VOID_RATIO) ** (4.0 / 9.0)
        * np.cbrt(BASE.particle_diameter_mm / thickness)
        * np.cbrt(series["cell_pressure_kpa"] / BASE.membrane_modulus_kpa)
    )
    np.testing.assert_allclose(series["indentation_ratio"], by_hand, rtol=1e-5)
    ratio = series["indentation_ratio"][-1] / series["indentation_ratio"][0]
    np.testing.assert_allclose(ratio, 10.0 ** (1.0 / 3.0), rtol=1e-5)
