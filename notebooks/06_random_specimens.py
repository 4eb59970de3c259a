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
# # Random specimens: a packing made as a laboratory makes it, in the membrane cell
#
# The paper's specimens are FCC lattices; its §6 asks whether the conclusions hold for random arrangements.
# membrax makes random specimens by compaction: spheres sampled from a grading are placed as a loose cloud
# in a cylindrical mould between two platens and grown until the mould and platens carry 10 kPa
# (`membrax.random_packing`; friction during compaction sets the density). This notebook:
#
# 1. compacts equal 25 mm spheres in a mould and reports the solid fraction and coordination number;
# 2. builds the membrane cell around the specimen (a cylindrical mesh; every sphere may touch the
#    membrane), consolidates it at 10 kPa and draws a horizontal section (the paper's Fig. 4);
# 3. runs a short test with `membrax.run_test` (`packing = "random"` in the configuration) and compares
#    the mobilised friction angle with Rowe's FCC bound.
#
# Full size: a mould 150 mm across and 250 mm high (`membrax demo --packing random`), to 10 % strain.
# Smoke mode (`MEMBRAX_SMOKE=1`, what CI sets): 125 × 150 mm, to 0.4 % strain.

# %%
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import membrax
from membrax import analysis, plots, theory

SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"
OUT = Path(tempfile.mkdtemp(prefix="membrax_06_"))
DIAMETER_MM = 25.0
if SMOKE:
    SIZE = {"specimen_diameter_mm": 125.0, "specimen_height_mm": 150.0}
    BASE = {**membrax.SMOKE_CONFIG, "name": "random_smoke"}
else:
    SIZE = {"specimen_diameter_mm": 150.0, "specimen_height_mm": 250.0}
    BASE = {**membrax.DEMO_CONFIG, "name": "random_demo"}
CONFIG = membrax.TriaxialConfig(**{**BASE, **SIZE, "packing": "random", "cell_pressure_kpa": 10.0})

# %% [markdown]
# ## 1. Compaction
#
# `membrax.build_specimen(CONFIG)` compacts the configuration's packing (its seed, no friction during
# compaction, to 10 kPa) once per process: `run_test` below reuses it. The solid fraction of the whole
# specimen is below random close packing (≈ 0.64) because the mould and the platens order and loosen the
# spheres within about two diameters of them; the core's is measured away from them.

# %%
specimen = membrax.build_specimen(CONFIG)
print(specimen.summary())
for key, value in specimen.measures.items():
    print(f"{key:>24}: {value:.4g}")

# %%
measures = specimen.measures
assert 0.45 < measures["solid_fraction"] < 0.64, "a walled random packing is looser than random close packing"
assert measures["max_overlap_fraction"] < 1e-3, "10 kPa on stiff spheres: overlaps far below a diameter"
# Equal spheres: every sampled diameter is the grading's one size.
assert np.allclose(2e3 * np.asarray(specimen.radius), DIAMETER_MM)

# %% [markdown]
# ## 2. In the membrane cell: consolidation and a section
#
# The membrane is a cylinder of the specimen's diameter; consolidation under 10 kPa presses it into the
# voids between the outer spheres. The section at mid-height shows the spheres cut by the plane and the
# membrane's mid-line and faces.

# %%
test = membrax.membrane_test(
    specimen,
    cell_pressure=CONFIG.cell_pressure,
    membrane_thickness=CONFIG.membrane_thickness,
    edges_per_diameter=CONFIG.membrane_edges_per_diameter,
)
state, records = test.consolidate(max_steps=20_000 if SMOKE else 100_000)
print(f"consolidated after {int(np.ravel(records.step)[-1])} steps")

fig, ax = plt.subplots(figsize=(5, 5))
plots.plot_section(
    ax,
    np.asarray(state.dem.position),
    np.asarray(specimen.radius),
    np.asarray(state.membrane.position),
    np.asarray(test.mesh.triangles),
    0.5 * specimen.height,
    CONFIG.membrane_thickness,
)
ax.legend(loc="upper right")
plt.show()

# %% [markdown]
# ## 3. A test on the random specimen
#
# `membrax.run_test` builds the same specimen from the configuration (`packing = "random"`), consolidates
# it and shears it. Rowe's stress–dilatancy bound for FCC (the densest regular packing, 43.79° for
# φ_μ = 25°) lies above what a random packing of the same spheres can mobilise.

# %%
result = membrax.run_test(CONFIG, OUT / "run", progress=False)
angle = np.asarray(analysis.record(result.results, "love_weber_friction_angle"))
strain = np.asarray(analysis.record(result.results, "axial_strain"))
rowe = theory.rowe_peak_friction_angle_deg(CONFIG.friction_angle_deg, theory.FCC)
best = int(np.nanargmax(angle))
print(f"largest mobilised φ' (Love–Weber) {angle[best]:.2f}° at {100 * strain[best]:.2f} % strain")
print(f"Rowe's FCC bound {rowe:.2f}°")
plots.plot_friction_angles(result.results)

# %%
assert np.nanmax(angle) < rowe, "a random packing mobilises less than the FCC bound"
start = analysis.initial_state(result.results)
# The ram balances the cell pressure on the platen: the external axial stress is the cell pressure.
assert abs(start["sigma1_external_kpa"] - CONFIG.cell_pressure_kpa) < 0.05 * CONFIG.cell_pressure_kpa
