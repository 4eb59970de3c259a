"""Why membrax's Δσ1 stops growing with cell pressure: the membrane's meridional tension and the funnel load.

At the end of consolidation the paper's Table 3 has Δσ1 = σ1,int − σ1,ext ≈ 0.2 σc, growing with σc and
t_m. In membrax Δσ1 is the pull of the membrane on the platens over the platen area A (the spheres receive
the ram's force plus that pull, :mod:`membrax.membrane.coupled`), and it stays at 2–6 kPa from 40 to 100 kPa.
This script consolidates the paper-size specimen (float64, unbalanced-force ratio ≤ 1e-3) at 10, 40 and
100 kPa in one membrane thickness and prints, per unit perimeter P of the clamped ring:

- ``Et·ε_z``: the meridional membrane tension, E_m t_m times the mean meridional strain of the band's
  meridians (node paths through every other ring, against their rest length);
- ``pull``: the membrane's axial pull on the platens, −R_z/P from the records (R the clamp reaction);
- ``funnel``: the cell pressure's axial load on the band where it narrows from the clamp radius r_c to the
  mean radius r₁ of the first node row, p·π(r_c² − r₁²)/P. It pushes the rings toward the platens, against
  the tension's pull;

and Δσ1 from the records beside (Et·ε_z − funnel)·P/A. Nothing is fitted.

Run: ``python examples/table3_axial_tension.py [thickness_mm] [--small]`` (about 2 min on 2 CPU cores at
paper size; ``--small`` uses the demo's 6 × 10 specimen).
"""

import math
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from membrax.assemble import build_test  # noqa: E402
from membrax.config import TriaxialConfig  # noqa: E402


def meridional_strain(position, rest, nodes_around):
    """Mean strain of the meridians: node paths through every other ring (same column), against rest."""
    rings = position.shape[0] // nodes_around
    now = position.reshape(rings, nodes_around, 3)[::2]
    before = rest.reshape(rings, nodes_around, 3)[::2]
    length = np.linalg.norm(np.diff(now, axis=0), axis=-1).sum(axis=0)
    rest_length = np.linalg.norm(np.diff(before, axis=0), axis=-1).sum(axis=0)
    return float(np.mean(length / rest_length - 1.0))


def main(thickness_mm: float, small: bool) -> None:
    size = dict(particles_across=6, layers=10, membrane_edges_per_diameter=3.0) if small else {}
    specimen = "6 × 10" if small else "paper-size 10 × 25"
    print(f"t_m = {thickness_mm} mm, {specimen} specimen; per unit perimeter:")
    print(
        "  σc kPa | UFR     | ε_z    | Et·ε_z N/m | pull N/m | funnel N/m | Δσ1 kPa"
        " | (Et·ε_z − funnel)·P/A kPa"
    )
    for pressure in (10.0, 40.0, 100.0):
        started = time.perf_counter()
        config = TriaxialConfig(
            cell_pressure_kpa=pressure, membrane_thickness_mm=thickness_mm, float64=True, **size
        )
        test = build_test(config)
        state, records = test.consolidate(tolerance=1e-3, max_steps=60000, chunk_steps=2000)
        mesh = test.mesh
        position = np.asarray(state.membrane.position)
        rest = np.asarray(mesh.reference_position)
        nodes_around = len(np.asarray(mesh.bottom_ring))
        ring = rest.reshape(-1, nodes_around, 3)[0]
        perimeter = float(np.linalg.norm(np.diff(np.vstack([ring, ring[:1]]), axis=0), axis=-1).sum())
        centre = rest[:, :2].mean(axis=0)
        radius = np.hypot(position[:, 0] - centre[0], position[:, 1] - centre[1]).reshape(-1, nodes_around)
        radius = radius.mean(axis=1)
        clamp, first_row = 0.5 * (radius[0] + radius[-1]), 0.5 * (radius[1] + radius[-2])
        funnel = 1e3 * pressure * math.pi * (clamp**2 - first_row**2) / perimeter
        tension = (
            config.membrane_modulus_kpa
            * 1e3
            * config.membrane_thickness
            * meridional_strain(position, rest, nodes_around)
        )

        def last(name, records=records):
            return float(np.asarray(getattr(records, name))[-1].ravel()[0])

        pull = -last("membrane_platen_force") / perimeter
        area = test.platen_area
        delta_sigma1 = (last("received_axial_force") - last("ram_force")) / area
        print(
            f"  {pressure:6.0f} | {last('unbalanced_force_ratio'):.1e} | "
            f"{tension / (config.membrane_modulus_kpa * 1e3 * config.membrane_thickness):.4f} | "
            f"{tension:10.0f} | {pull:8.0f} | {funnel:10.0f} | {1e-3 * delta_sigma1:7.2f} | "
            f"{1e-3 * (tension - funnel) * perimeter / area:7.2f}   ({time.perf_counter() - started:.0f} s)"
        )


if __name__ == "__main__":
    arguments = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(float(arguments[0]) if arguments else 2.5, "--small" in sys.argv)
