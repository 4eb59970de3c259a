"""The shipped synthetic example record corrected by every method, beside the stresses it really carried.

Reads ``calibrate/data/example_record.csv`` (a membrax simulation held out of the fit: 7 spheres across,
25 kPa, a 2 mm membrane of 1000 kPa), corrects it as ``membrax correct`` does, prints φ' at a few strains
by method with the internal φ', and writes the plot with the internal stresses drawn in grey
(``docs/example_record_corrected.png`` in the README).

Run: ``python examples/correct_example_record.py [out.png]``.
"""

import sys

import matplotlib.pyplot as plt

from calibrate import correct, evaluate

record, specimen, internal_1, internal_3 = evaluate.read_example_record()
result = correct.correct_record(record, specimen)
print(evaluate.friction_angle_table(record, result, internal_1, internal_3))
errors = evaluate.friction_angle_errors(record, specimen, internal_1, internal_3)
print(
    "mean / worst |φ' − φ'_internal| over 0 < ε_a ≤ 10 %: "
    + ", ".join(f"{m} {e[0]:.2f}/{e[1]:.2f}°" for m, e in errors.items())
)
out = sys.argv[1] if len(sys.argv) > 1 else "example_record_corrected.png"
figure = correct.plot_correction(
    result, "synthetic example: 25 kPa, 2 mm membrane of 1000 kPa, D/D_s = 1/7", (internal_1, internal_3)
)
figure.savefig(out, dpi=110)
plt.close(figure)
print(f"plot written to {out}")
