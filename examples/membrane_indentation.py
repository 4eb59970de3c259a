"""Membrane indentation into the voids of a square and a triangular sphere array, beside Molenkamp & Luger.

A flat latex sheet (E_m = 1400 kPa, t_m = 2.5 and 5 mm) rests on a fixed array of touching spheres
(D = 25 mm), its mid-surface initially on the sphere tops (z = R + t_m/2 above the centres). Two arrays:

- square: the sheet covers n × n cells (n = 3 by default: 4 × 4 spheres), α measured in the central
  void of four spheres (:func:`membrax.membrane.indentation.sheet_on_square_array`);
- triangular (a hexagonal close-packed layer, the {111} face of an FCC packing): the sheet is n·D by
  2k·(√3/2)D, k = round(n/√3) (3D × 2√3 D for n = 3, 22 spheres), α measured in the triangular void
  of three touching spheres nearest its centre
  (:func:`membrax.membrane.indentation.sheet_on_triangular_array`).

The sheet's outline is pinned at the initial position; a cell pressure p pushes it down into the voids.
Static equilibrium of neo-Hookean stretching + Discrete-Shells bending + the pressure potential p V + a
frictionless node–sphere penalty (k_n = 1e6 N/m) is found with L-BFGS-B
(:func:`membrax.membrane.indentation.solve_sheet_on_spheres`), each pressure starting from the previous
solution.

Reported: α/D, α the largest downward deflection of the mid-surface in the measured void below the
plane of the sphere tops, beside Molenkamp & Luger's
α/D = C (1 + e)^(4/9) (D/t_m)^(1/3) (p/E_m)^(1/3), C = 0.275
(:func:`membrax.theory.molenkamp_luger_indentation_ratio`), with e = 6/π − 1 (simple cubic, the square
array's void ratio) or e = e_FCC ≈ 0.350 (the triangular layer's packing, their formula's triangular
grid); the constant C_sim that would make their formula match (α/D divided by their expression with
C = 1); and the exponent of α against p, the least-squares slope of ln α on ln p over the pressures,
per array and thickness, beside their 1/3. Reported, not tuned: their C spans 0.15–0.4.

Run: ``python examples/membrane_indentation.py [cells] [edges_per_diameter] [contact_offset_factor]``
(defaults 3, 10 and 1; the test uses 3 and 6). The offset factor f puts the sheet's contact with the
spheres at R + f t_m/2 (1: its lower face; 0: its mid-surface, the paper's nodes on the sphere surface);
α is measured from the sheet's initial height either way.
"""

import math
import os
import sys
import time

# scipy's L-BFGS-B does its vector algebra in OpenBLAS; on a few busy cores its threads fight jax's and
# slow each iteration ~10× on these ~10³ unknowns. One thread unless the caller says otherwise.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from membrax import theory  # noqa: E402
from membrax.membrane import indentation  # noqa: E402

DIAMETER = 0.025
MODULUS = 1.4e6
THICKNESSES = (2.5e-3, 5e-3)
PRESSURES = (10e3, 20e3, 40e3, 70e3, 100e3)
NORMAL_STIFFNESS = 1e6
SIMPLE_CUBIC_VOID_RATIO = 6.0 / math.pi - 1.0

# name: (sheet builder returning (mesh, spheres, *cell), depth from (position, *cell, top), void ratio e)
ARRAYS = {
    "square": (indentation.sheet_on_square_array, indentation.indentation_depth, SIMPLE_CUBIC_VOID_RATIO),
    "triangular": (
        indentation.sheet_on_triangular_array,
        indentation.polygon_indentation_depth,
        theory.FCC_VOID_RATIO,
    ),
}


def depth_series(name, cells, edges_per_diameter, thickness, offset_factor=1.0):
    """α/D at each of PRESSURES for one array and thickness, printing one row per pressure."""
    build, measure, void_ratio = ARRAYS[name]
    radius = 0.5 * DIAMETER
    mesh, spheres, *cell = build(cells, DIAMETER, DIAMETER / edges_per_diameter, thickness, offset_factor)
    previous, ratios = None, []
    for pressure in PRESSURES:
        tic = time.perf_counter()
        solution = indentation.solve_sheet_on_spheres(
            mesh,
            spheres,
            np.full(spheres.shape[0], radius),
            pressure,
            MODULUS,
            thickness,
            normal_stiffness=NORMAL_STIFFNESS,
            initial_position=previous,
            contact_offset_factor=offset_factor,
        )
        previous = solution.position
        ratio = measure(solution.position, *cell, radius + 0.5 * offset_factor * thickness) / DIAMETER
        ratios.append(ratio)
        prediction = float(
            theory.molenkamp_luger_indentation_ratio(void_ratio, DIAMETER, thickness, pressure, MODULUS)
        )
        print(
            f"{name:>10} {thickness * 1e3:6.1f} {pressure / 1e3:6.0f} {ratio:13.4f} {prediction:13.4f}"
            f" {0.275 * ratio / prediction:7.3f} {solution.max_overlap * 1e6:10.1f} {solution.iterations:6d}"
            f" {time.perf_counter() - tic:6.1f}{'' if solution.success else '  (not converged)'}"
        )
    return np.asarray(ratios)


def main(cells=3, edges_per_diameter=10.0, offset_factor=1.0):
    print(
        f"{cells} cells, edge D/{edges_per_diameter:g}, E_m = {MODULUS / 1e3:g} kPa,"
        f" D = {DIAMETER * 1e3:g} mm, k_n = {NORMAL_STIFFNESS:g} N/m,"
        f" nodes touch spheres at R + {offset_factor:g} t_m/2"
    )
    print("     array t_m/mm  p/kPa alpha/D (sim) alpha/D (M&L)   C_sim overlap/um  iters      s")
    exponents = {}
    for name in ARRAYS:
        for thickness in THICKNESSES:
            ratios = depth_series(name, cells, edges_per_diameter, thickness, offset_factor)
            exponents[name, thickness] = np.polyfit(np.log(np.asarray(PRESSURES)), np.log(ratios), 1)[0]
    pressures = ", ".join(f"{p / 1e3:g}" for p in PRESSURES)
    print(f"\nexponent of alpha against p (least squares of ln alpha on ln p over p = {pressures} kPa)")
    print("     array t_m/mm  fitted  Molenkamp & Luger")
    for (name, thickness), exponent in exponents.items():
        print(f"{name:>10} {thickness * 1e3:6.1f} {exponent:7.3f}  {1.0 / 3.0:.3f} (1/3)")


if __name__ == "__main__":
    arguments = sys.argv[1:]
    main(
        int(arguments[0]) if arguments else 3,
        float(arguments[1]) if len(arguments) > 1 else 10.0,
        float(arguments[2]) if len(arguments) > 2 else 1.0,
    )
