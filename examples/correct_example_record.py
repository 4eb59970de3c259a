"""The shipped synthetic example record corrected by every method, beside the stresses it really carried.

Reads ``calibrate/data/example_record.csv`` (a membrax simulation held out of the fit: a medium-dense random
packing of ballast-graded spheres, seed 1, 150.5 mm across and 301 mm tall, d50 16.1 mm, 25 kPa, a 4 mm
membrane of 1400 kPa),
corrects it as ``membrax correct`` does, prints φ' at a few strains
by method with the internal φ', and writes the plot with the internal stresses drawn in grey
(``docs/example_record_corrected.png`` in the README).

Run: ``python examples/correct_example_record.py [out.png]``.
"""

import sys

import matplotlib.pyplot as plt

from calibrate import correct, evaluate, report

record, specimen, internal_1, internal_3 = evaluate.read_example_record()
result = correct.correct_record(record, specimen)
print(evaluate.friction_angle_table(record, result, internal_1, internal_3))
errors = evaluate.friction_angle_errors(record, specimen, internal_1, internal_3)
print(
    "mean / worst |φ' − φ'_internal| over 0 < ε_a ≤ 10 %: "
    + ", ".join(f"{m} {e[0]:.2f}/{e[1]:.2f}°" for m, e in errors.items())
)
out = sys.argv[1] if len(sys.argv) > 1 else "example_record_corrected.png"
title = (
    f"synthetic example: graded random packing, {record.cell_pressure[0] / 1e3:g} kPa, "
    f"{1e3 * specimen.membrane_thickness:g} mm membrane of {specimen.membrane_modulus / 1e3:g} kPa, "
    f"D/D_s = 1/{specimen.specimen_diameter / specimen.particle_diameter:.1f}"
)
figure = report.plot_correction(result, title, (internal_1, internal_3))
figure.savefig(out, dpi=110)
plt.close(figure)
print(f"plot written to {out}")
