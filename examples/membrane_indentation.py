"""Membrane indentation into the voids of a square array of spheres, beside Molenkamp & Luger (1981).

A flat latex sheet (E_m = 1400 kPa, t_m = 2.5 and 5 mm) rests on a fixed, touching square array of
spheres (D = 25 mm), its mid-surface initially on the sphere tops (z = R + t_m/2 above the centres). The
sheet covers n × n cells (n = 3 by default: 4 × 4 spheres) and its outline is pinned at the initial
position; a cell pressure p pushes it down into the voids. Static equilibrium of neo-Hookean stretching
+ Discrete-Shells bending + the pressure potential p V + a frictionless node–sphere penalty
(k_n = 1e6 N/m) is found with L-BFGS-B (:func:`membrax.indentation.solve_sheet_on_spheres`), each
pressure starting from the previous solution.

Reported: α/D, α the largest downward deflection of the mid-surface in the central cell below the
plane of the sphere tops (:func:`membrax.indentation.indentation_depth`), beside Molenkamp & Luger's
α/D = 0.275 (1 + e)^(4/9) (D/t_m)^(1/3) (p/E_m)^(1/3)
(:func:`membrax.theory.molenkamp_luger_indentation_ratio`) with e = 6/π − 1 (simple cubic packing,
the square array's void ratio; their formula is for a triangular grid), and the fitted exponent
d ln α / d ln p per thickness beside their 1/3. Reported, not tuned: their constant C spans 0.15–0.4.

Run: ``python examples/membrane_indentation.py [cells] [edges_per_diameter]`` (defaults 3 and 10; the
test uses 3 and 6).
"""

import math
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from membrax import indentation, theory  # noqa: E402

DIAMETER = 0.025
MODULUS = 1.4e6
THICKNESSES = (2.5e-3, 5e-3)
PRESSURES = (10e3, 20e3, 40e3, 70e3, 100e3)
NORMAL_STIFFNESS = 1e6
SIMPLE_CUBIC_VOID_RATIO = 6.0 / math.pi - 1.0


def main(cells=3, edges_per_diameter=10.0):
    radius = 0.5 * DIAMETER
    print(f"{cells} x {cells} cells, edge D/{edges_per_diameter:g}, E_m = {MODULUS / 1e3:g} kPa, D = 25 mm")
    print(" t_m/mm  p/kPa  alpha/D (sim)  alpha/D (M&L)  overlap/um  iterations  seconds")
    for thickness in THICKNESSES:
        mesh, spheres, low, high = indentation.sheet_on_square_array(
            cells, DIAMETER, DIAMETER / edges_per_diameter, thickness
        )
        previous, depths = None, []
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
            )
            previous = solution.position
            depth = indentation.indentation_depth(solution.position, low, high, radius + 0.5 * thickness)
            depths.append(depth)
            ratio = float(
                theory.molenkamp_luger_indentation_ratio(
                    SIMPLE_CUBIC_VOID_RATIO, DIAMETER, thickness, pressure, MODULUS
                )
            )
            print(
                f"{thickness * 1e3:7.1f} {pressure / 1e3:6.0f} {depth / DIAMETER:14.4f} {ratio:14.4f}"
                f" {solution.max_overlap * 1e6:11.1f} {solution.iterations:11d}"
                f" {time.perf_counter() - tic:8.1f}"
            )
        slope = np.polyfit(np.log(np.asarray(PRESSURES)), np.log(np.asarray(depths)), 1)[0]
        print(f"  t_m = {thickness * 1e3:g} mm: fitted d ln(alpha)/d ln(p) = {slope:.3f} (M&L: 1/3)")


if __name__ == "__main__":
    arguments = sys.argv[1:]
    main(int(arguments[0]) if arguments else 3, float(arguments[1]) if len(arguments) > 1 else 10.0)
