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
# # Quick start: a membrane triaxial test
#
# membrax simulates a drained triaxial test on an FCC packing of spheres (the DEM) wrapped in a
# triangulated latex membrane clamped to the platens, and reports the *external* stresses (what a
# laboratory measures: ram force and cell pressure) beside the *internal* ones (what the specimen
# carries), as in the paper's §4.3. This notebook:
#
# 1. builds the FCC specimen and its membrane, consolidates it under the cell pressure and draws a
#    horizontal section through spheres and membrane (the paper's Fig. 4);
# 2. runs the whole test (consolidation, then shearing) with one call, `membrax.run_test`, and plots the
#    stress ratio and volumetric strain against axial strain, external against internal (Fig. 5 style),
#    the mobilised friction angle (Fig. 5) and the additional membrane stresses (Fig. 6).
#
# Full size is `membrax demo`'s test: 6 spheres across, 10 layers, a membrane of edge D/3, 10 kPa in a
# 5 mm membrane, sheared to 10 % at an inertial number of 5e-3. Smoke mode (`MEMBRAX_SMOKE=1`, what CI
# sets) takes 4 × 5 layers to 1 %.
#
# **Time** (2 CPU cores, measured): smoke 28–48 s; full size 46 s (both mostly building and compiling
# the test). See docs/benchmarks.md, "Notebooks".

# %%
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import membrax
from membrax import analysis, plots, theory

SMOKE = os.environ.get("MEMBRAX_SMOKE") == "1"
OUT = Path(tempfile.mkdtemp(prefix="membrax_01_"))

if SMOKE:  # 4 spheres across, 5 layers, to 1 % strain
    CONFIG = membrax.TriaxialConfig(
        **{
            **membrax.SMOKE_CONFIG,
            "name": "quickstart_smoke",
            "cell_pressure_kpa": 10.0,
            "membrane_thickness_mm": 5.0,
            "target_axial_strain": 0.01,
        }
    )
else:  # membrax demo
    CONFIG = membrax.TriaxialConfig(**{**membrax.DEMO_CONFIG, "name": "quickstart"})
print(
    f"{'smoke' if SMOKE else 'full size'}: {CONFIG.particles_across} across, {CONFIG.layers} layers, "
    f"{CONFIG.cell_pressure_kpa:g} kPa, t_m = {CONFIG.membrane_thickness_mm:g} mm, "
    f"to {100 * CONFIG.target_axial_strain:g} %; files in {OUT}"
)

# %% [markdown]
# ## 1. The specimen and its membrane
#
# `membrax.fcc_specimen(D, spheres_across, layers)` builds the face-centred cubic packing (cube axis
# vertical, D in m); `membrax.membrane_test` wraps it in a membrane (a band of near-equilateral
# triangles, rounded about the corner spheres) and returns a `MembraneTest` whose stages run in compiled
# chunks. Units: the builders take laboratory units named in the arguments (kPa, mm); everything inside
# is SI.

# %%
specimen = membrax.fcc_specimen(CONFIG.particle_diameter_mm / 1000, CONFIG.particles_across, CONFIG.layers)
print(specimen.summary())
test = membrax.membrane_test(
    specimen,
    cell_pressure=CONFIG.cell_pressure,  # Pa: the configuration converts its kPa once
    membrane_thickness=CONFIG.membrane_thickness,  # m
    edges_per_diameter=CONFIG.membrane_edges_per_diameter,
)
print(f"membrane: {test.mesh.triangles.shape[0]} triangles; time step {test.dt:.3e} s")

# %% [markdown]
# Consolidation: the cell pressure acts on the membrane's outer face and both platens are servo-controlled
# to a ram force of σc × platen area, until the unbalanced-force ratio is small, the ram stress is σc and
# the membrane has stopped creeping into the voids.

# %%
state, consolidation = test.consolidate(chunk_steps=1000, record_every=100)
ram_stress = float(consolidation.ram_force[-1, 0]) / test.platen_area
print(
    f"{int(state.step)} steps; ram stress {ram_stress / 1e3:.3f} kPa; unbalanced-force ratio "
    f"{float(consolidation.unbalanced_force_ratio[-1, 0]):.1e}"
)
# The servo's target: ram force / platen area = σc, within the stop test's 1 %.
assert abs(ram_stress / test.cell_pressure - 1.0) < 0.01

# %% [markdown]
# The paper's Fig. 4: a horizontal section through a layer of spheres that touches the flat faces, near
# mid-height. The membrane (red: mid-surface and faces) indents into the voids between the spheres.

# %%
layer = np.asarray(specimen.layer)
middle = (layer.max() // 2) // 2 * 2
sphere_position = np.asarray(state.dem.position)
node_position = np.asarray(state.membrane.position)
triangles = np.asarray(test.mesh.triangles)
radius = np.asarray(test.particles.radius)
height = float(np.mean(sphere_position[layer == middle, 2]))
thickness = CONFIG.membrane_thickness_mm / 1000
fig, ax = plt.subplots(figsize=(6, 6))
plots.plot_section(ax, sphere_position, radius, node_position, triangles, height, thickness)
ax.set_title(
    f"after consolidation at {CONFIG.cell_pressure_kpa:g} kPa, t_m = {CONFIG.membrane_thickness_mm:g} mm,"
    f" z = {1e3 * height:.1f} mm",
    fontsize=9,
)
_ = ax.legend(loc="upper right", fontsize=8)

# %%
# The membrane's mid-surface stays outside every sphere (its inner face rests on them, t_m/2 inside the
# mid-surface), and it indents: its distance from the axis varies around the section.
centres, circle_radii = plots.particle_section(sphere_position, radius, height)
loops = plots.membrane_section(node_position, triangles, height)
points = np.concatenate(loops)
gap = np.min(np.linalg.norm(points[:, None, :] - centres[None, :, :], axis=-1) - circle_radii[None, :])
axis_distance = np.linalg.norm(points, axis=1)
print(
    f"closest approach of the mid-surface to a sphere: {1e3 * gap:.2f} mm (t_m/2 = {500 * thickness:g} mm);"
    f" radius from the axis {1e3 * axis_distance.min():.1f}–{1e3 * axis_distance.max():.1f} mm"
)
assert gap > 0.0

# %% [markdown]
# ## 2. The whole test in one call
#
# `membrax.run_test(config, folder)` runs the paper's protocol (consolidation, then drained shearing with
# the platens ramped up from rest, both moving) and writes `results.nc`/`.csv`, `consolidation.nc`, the
# Figs 5–8 PNGs and `summary.md` into the folder. `membrax run config.toml` and `membrax demo` call it.

# %%
result = membrax.run_test(CONFIG, OUT / CONFIG.name, progress=False)
print(result.summary)
print("files:", ", ".join(sorted(p.name for p in result.folder.iterdir())))
records = result.results  # an xarray.Dataset: one row per record, strains from the start of shearing


# %%
def fig5_style(records, title=""):
    """Stress ratio σ1/σ3 and volumetric strain against axial strain, external against internal."""
    strain = 100 * analysis.record(records, "axial_strain")
    ratio = {
        side: analysis.record(records, f"{side}_axial_stress")
        / analysis.record(records, f"{side}_radial_stress")
        for side in ("external", "internal")
    }
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
    left.plot(strain, ratio["external"], color="tab:blue", label="external (ram, cell pressure)")
    left.plot(strain, ratio["internal"], color="tab:red", label="internal (carried by the specimen)")
    rowe = float(theory.rowe_stress_ratio(np.radians(CONFIG.friction_angle_deg), theory.FCC))
    left.axhline(rowe, color="0.5", lw=0.8, ls="--", label=f"Rowe, FCC: {rowe:.2f}")
    left.set(xlabel="axial strain εa (%)", ylabel="stress ratio σ1/σ3")
    left.legend(fontsize=8)
    right.plot(strain, 100 * analysis.record(records, "volumetric_strain"), color="k")
    right.set(xlabel="axial strain εa (%)", ylabel="volumetric strain εv (%, contraction +)")
    for ax in (left, right):
        ax.grid(True, lw=0.5, alpha=0.5)
    fig.suptitle(title)
    return fig


figure = fig5_style(
    records,
    f"{CONFIG.cell_pressure_kpa:g} kPa, {CONFIG.membrane_thickness_mm:g} mm membrane, "
    f"{CONFIG.particles_across} × {CONFIG.layers} FCC specimen",
)

# %% [markdown]
# The paper's Fig. 5 (mobilised friction angle, external and internal, and the Love–Weber average over
# the contacts) and Fig. 6 (additional membrane stresses, internal − external) straight from
# `membrax.plots`; they return matplotlib Figures.

# %%
plots.plot_friction_angles(records)

# %%
plots.plot_additional_stresses(records)

# %% [markdown]
# ## 3. Checks
#
# - The external radial stress is the cell pressure, at every record; the external axial stress starts
#   at σc (the servo's target at the end of consolidation).
# - sin φ' = (σ1 − σ3)/(σ1 + σ3) for the derived friction angles.
# - Rowe's stress–dilatancy theory bounds the peak of a regular FCC packing sheared along its cube axis:
#   φ'_peak ≤ φ'_Rowe = 43.79° for φ_μ = 25° (`membrax.theory`), up to the shearing's dynamic overshoot.

# %%
sigma_c = 1e3 * CONFIG.cell_pressure_kpa
np.testing.assert_allclose(analysis.record(records, "external_radial_stress"), sigma_c, rtol=1e-5)
assert abs(analysis.record(records, "external_axial_stress")[0] / sigma_c - 1.0) < 0.01

for side in ("external", "internal"):
    s1 = analysis.record(records, f"{side}_axial_stress")
    s3 = analysis.record(records, f"{side}_radial_stress")
    np.testing.assert_allclose(
        analysis.record(records, f"{side}_friction_angle_deg"),
        np.degrees(np.arcsin((s1 - s3) / (s1 + s3))),
        atol=1e-4,
    )

rowe_deg = float(theory.rowe_peak_friction_angle_deg(CONFIG.friction_angle_deg, theory.FCC))
peaks = analysis.peak(records)
print(
    f"peak φ' external {peaks['peak_external_friction_angle_deg']:.2f}°, internal "
    f"{peaks['peak_internal_friction_angle_deg']:.2f}°, Rowe {rowe_deg:.2f}°"
)
assert 30.0 < peaks["peak_internal_friction_angle_deg"] < rowe_deg + 0.5
assert 30.0 < peaks["peak_external_friction_angle_deg"] < rowe_deg + 0.5
