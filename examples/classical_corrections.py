"""Apply the classical membrane corrections to a laboratory-style record and compare φ'.

A drained test on ballast in a 300 mm cell at 10 kPa with a 2 mm latex membrane (the reference's
worked example §12.4, extended over the whole strain range). Prints a table of measured and corrected
φ' for the ASTM, Henkel & Gilbert hoop and right-cylinder shell corrections, and writes a plot.

Run: ``python examples/classical_corrections.py [out.png]``.
"""

import sys

import matplotlib

matplotlib.use("Agg")
import jax.numpy as jnp
import matplotlib.pyplot as plt

from membrax import theory

CELL_PRESSURE_KPA = 10.0
MODULUS_KPA = 1400.0
THICKNESS_M = 0.002
DIAMETER_M = 0.300

# A synthetic record: deviator rising to a peak near 5 % and dilating (volumetric strain negative).
axial_strain = jnp.linspace(0.0, 0.10, 21)
deviator_kpa = 70.0 * axial_strain / (0.012 + axial_strain) * (1.0 - 2.0 * (axial_strain - 0.05) ** 2)
volumetric_strain = 0.01 * axial_strain - 6.0 * axial_strain**2
sigma_1 = CELL_PRESSURE_KPA + deviator_kpa

corrections = {
    "ASTM shell": theory.astm_shell_correction(MODULUS_KPA, THICKNESS_M, DIAMETER_M, axial_strain),
    "hoop tension": theory.hoop_tension_correction(
        MODULUS_KPA, THICKNESS_M, DIAMETER_M, axial_strain, volumetric_strain
    ),
    "right cylinder": theory.right_cylinder_shell_correction(
        MODULUS_KPA, THICKNESS_M, DIAMETER_M, axial_strain, volumetric_strain
    ),
}
measured = theory.mobilised_friction_angle_deg(sigma_1, CELL_PRESSURE_KPA)
print(f"{'eps_a %':>8}{'eps_v %':>9}{'measured':>10}" + "".join(f"{k:>16}" for k in corrections))
fig, ax = plt.subplots(figsize=(6, 4))
ax.plot(100 * axial_strain, measured, "k", label="measured")
corrected = {}
for name, correction in corrections.items():
    corrected[name] = theory.mobilised_friction_angle_deg(
        *theory.apply_membrane_correction(sigma_1, CELL_PRESSURE_KPA, correction)
    )
    ax.plot(100 * axial_strain, corrected[name], label=name)
for i in range(0, axial_strain.shape[0], 2):
    row = "".join(f"{float(corrected[k][i]):>16.2f}" for k in corrections)
    print(
        f"{100 * float(axial_strain[i]):>8.1f}{100 * float(volumetric_strain[i]):>9.2f}"
        f"{float(measured[i]):>10.2f}{row}"
    )
ax.set(xlabel="axial strain (%)", ylabel="mobilised φ' (°)", title="10 kPa, 2 mm latex, 300 mm specimen")
ax.legend()
out = sys.argv[1] if len(sys.argv) > 1 else "classical_corrections.png"
fig.savefig(out, dpi=120, bbox_inches="tight")
print(f"plot written to {out}")
