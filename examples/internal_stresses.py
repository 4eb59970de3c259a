"""Which internal σ3? The paper's §4.3, the received and the Love–Weber stresses at the start of shearing.

Runs the random demo specimen (equal 25 mm spheres compacted in a 150 × 250 mm mould, membrane edge D/3,
I = 5e-3, float64) at σc 10 and 100 kPa in 2.5 and 5 mm membranes of 1400 kPa to 0.2 % axial strain, and
prints, at the first shearing record (ε_a = 0), each internal stress over σc: §4.3's σ3
(``internal_radial_stress``), the received σ3 (``received_radial_stress``: the same radial load over the
mid-surface's radially projected area A_r), the Love–Weber σ3, R̄/R_A = A_r / (2π H √(A/π)) (the indented
surface's mean radius over the platen's), internal σ1, the membrane's axial pull on the platens over σc A,
and the Love–Weber σ1. docs/model.md ("Which internal stress a correction reproduces") explains them.

Run: ``python examples/internal_stresses.py [folder]`` (about 4 min on 2 CPU cores; runs are kept in
``results_internal_stresses/`` and resumed).
"""

import math
import sys
from pathlib import Path

import numpy as np

import membrax
from membrax.config import DEMO_CONFIG, DEMO_RANDOM_CONFIG
from membrax.run import CHECKPOINT_NAME
from membrax.triaxial import analysis

CASES = ((10.0, 2.5), (10.0, 5.0), (100.0, 2.5), (100.0, 5.0))


def first_record(results, name):
    """The record at the start of shearing."""
    return float(np.ravel(analysis.record(results, name))[0])


def main(folder="results_internal_stresses"):
    print(
        "σc kPa | t_m mm | §4.3 σ3 | received σ3 | Love–Weber σ3 | R̄/R_A | internal σ1 | membrane pull | "
        "Love–Weber σ1   (each over σc, at ε_a = 0)"
    )
    for cell, thickness in CASES:
        name = f"s{cell:g}_t{thickness:g}"
        config = membrax.TriaxialConfig(
            **dict(
                dict(DEMO_CONFIG, **DEMO_RANDOM_CONFIG),
                name=name,
                cell_pressure_kpa=cell,
                membrane_thickness_mm=thickness,
                target_axial_strain=0.002,
                float64=True,
            )
        )
        out = Path(folder) / name
        results = membrax.run_test(config, out, resume=(out / CHECKPOINT_NAME).exists()).results

        def over_cell(record, results=results, cell=cell):
            return first_record(results, record) / (1e3 * cell)

        area, height = first_record(results, "platen_area"), first_record(results, "height")
        mean_radius_ratio = first_record(results, "radial_projected_area") / (
            2.0 * math.pi * height * math.sqrt(area / math.pi)
        )
        pull = -first_record(results, "membrane_platen_force") / (area * 1e3 * cell)
        print(
            f"{cell:6g} | {thickness:6g} | {over_cell('internal_radial_stress'):7.3f} | "
            f"{over_cell('received_radial_stress'):11.3f} | {over_cell('love_weber_radial_stress'):13.3f} | "
            f"{mean_radius_ratio:6.3f} | {over_cell('internal_axial_stress'):11.3f} | {pull:13.3f} | "
            f"{over_cell('love_weber_axial_stress'):13.3f}"
        )


if __name__ == "__main__":
    main(*sys.argv[1:])
