"""How deep the membrane indents after consolidation on the calibration grid, beside Molenkamp & Luger.

Molenkamp & Luger's relation (the reference study's eq. 2,
:func:`membrax.theory.molenkamp_luger_indentation_ratio`) predicts
α/D = C (1 + e)^(4/9) (D/t_m)^(1/3) (σ'/E_m)^(1/3), C = 0.15–0.4. This script consolidates the FCC
calibration specimen (6 across, 10 layers: :data:`calibrate.designs.CALIBRATION`'s ``d6``, the small preset of
``membrax reproduce``: membrane edge D/3, I = 5e-3, float64, consolidation to an unbalanced-force ratio
≤ 1e-3) at every σc (10, 40, 100 kPa), t_m (1, 2, 3, 5 mm) and E_m (700, 1400, 2800 kPa) the configuration
accepts (1 mm of 700 kPa at 100 kPa is above its inflation limit and refused), all members in one batch, with
the membrane law ``--law`` (default Gent, J_m = 97.2), and measures α at the end of consolidation.

α, measured. :func:`membrax.membrane.measure.indentation_field` gives each node's depth below the locally
outermost membrane surface (the envelope of the sphere tops) within ±1 row and column; α is the mean of that
depth over its local maxima (the nodes deepest in their neighbourhood: the void centres) on the rows more
than one diameter from either clamp. At an edge of D/3 a void between four boundary spheres holds one or two
nodes, so α is sampled at the mesh's resolution, not resolved (``--edges`` refines it).

Printed: per member α/D, Molenkamp & Luger's range at the FCC void ratio, and the C that would make their
formula match; then the least-squares fit ln(α/D) = ln K + a ln(D/t_m) + b ln(σc/E_m) with standard errors,
beside their a = b = 1/3, and C = K/(1 + e)^(4/9). Written to ``--out`` (CSV, one row per member).

Run: ``python examples/indentation_grid.py [--law gent|neo-hookean|svk] [--edges 3]
[--out indentation_grid.csv]`` (about 10 min on 2 CPU cores).
"""

import argparse
import csv
import itertools
import math
import tempfile
import time
from pathlib import Path

PRESSURES_KPA = (10.0, 40.0, 100.0)
THICKNESSES_MM = (1.0, 2.0, 3.0, 5.0)
MODULI_KPA = (700.0, 1400.0, 2800.0)


def void_centre_depth(node_position, mesh, diameter: float) -> float:
    """α: the mean indentation over the nodes deepest within ±1 row and column, away from the clamps, m."""
    import jax.numpy as jnp
    import numpy as np

    from membrax.membrane import measure

    depth = np.asarray(measure.indentation_field(jnp.asarray(node_position), mesh, 1))
    per_row = int(mesh.bottom_ring.shape[0])
    grid = depth.reshape(-1, per_row)
    padded = np.pad(grid, ((1, 1), (0, 0)), constant_values=-np.inf)
    around = np.stack(
        [
            np.roll(padded, shift, axis=1)[1 + dr : padded.shape[0] - 1 + dr]
            for dr in (-1, 0, 1)
            for shift in (-1, 0, 1)
        ]
    )
    peak = (grid >= around.max(axis=0)) & (grid > 0.0)
    z = np.asarray(mesh.reference_position)[:, 2].reshape(-1, per_row)[:, 0]
    away = (z > z.min() + diameter) & (z < z.max() - diameter)
    chosen = grid[away][peak[away]]
    return float(np.mean(chosen)) if chosen.size else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--law", default="gent", choices=("gent", "neo-hookean", "svk"))
    parser.add_argument("--edges", type=float, default=None, help="membrane edges per diameter (preset: 3)")
    parser.add_argument("--out", default="indentation_grid.csv")
    args = parser.parse_args()

    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)

    from membrax import executor, runner, theory
    from membrax.config import ConfigError, TriaxialConfig
    from membrax.reproduce import SIZES

    base = {
        **SIZES["small"],
        "membrane_law": args.law,
        # consolidation is what is measured; the shearing is the shortest the configuration accepts
        "target_axial_strain": 1e-3,
        "fine_until_strain": 1e-3,
    }
    if args.edges is not None:
        base["membrane_edges_per_diameter"] = args.edges
    configs, refused = [], []
    for pressure, thickness, modulus in itertools.product(PRESSURES_KPA, THICKNESSES_MM, MODULI_KPA):
        fields = dict(
            base,
            name=f"{pressure:g}kPa_{thickness:g}mm_{modulus:g}kPa",
            cell_pressure_kpa=pressure,
            membrane_thickness_mm=thickness,
            membrane_modulus_kpa=modulus,
        )
        try:
            configs.append(TriaxialConfig(**fields))
        except ConfigError as error:
            refused.append((fields["name"], str(error).splitlines()[0]))
    for name, reason in refused:
        print(f"refused {name}: {reason[:140]}")
    started = time.perf_counter()
    batch = executor.build_batch(configs, num_devices=1)
    consolidated = {}

    def after_chunk(states, phase):
        if phase == "consolidation":  # the last one holds every member at its end of consolidation
            consolidated["nodes"] = np.asarray(states.membrane.position)

    runner.run_group(batch, Path(tempfile.mkdtemp(prefix="indentation_grid_")), after_chunk=after_chunk)
    print(f"{len(configs)} members consolidated in {time.perf_counter() - started:.0f} s")

    rows = []
    e = theory.FCC_VOID_RATIO
    for b, (config, test) in enumerate(zip(batch.configs, batch.tests, strict=True)):
        diameter = float(config.particle_diameter)
        alpha = void_centre_depth(consolidated["nodes"][b], test.mesh, diameter)
        thickness, pressure, modulus = (
            1e-3 * config.membrane_thickness_mm,
            1e3 * config.cell_pressure_kpa,
            1e3 * config.membrane_modulus_kpa,
        )
        unit = float(theory.molenkamp_luger_indentation_ratio(e, diameter, thickness, pressure, modulus, 1.0))
        rows.append(
            {
                "cell_pressure_kpa": config.cell_pressure_kpa,
                "membrane_thickness_mm": config.membrane_thickness_mm,
                "membrane_modulus_kpa": config.membrane_modulus_kpa,
                "alpha_over_d": alpha / diameter,
                "ml_low": 0.15 * unit,
                "ml_high": 0.4 * unit,
                "c_that_matches": alpha / diameter / unit,
            }
        )
    print(f"{'σc kPa':>7} {'t_m mm':>7} {'E_m kPa':>8} {'α/D':>7} {'M&L (C 0.15–0.4)':>18} {'C':>6}")
    for row in sorted(rows, key=lambda r: (r["cell_pressure_kpa"], r["membrane_thickness_mm"])):
        print(
            f"{row['cell_pressure_kpa']:7g} {row['membrane_thickness_mm']:7g} "
            f"{row['membrane_modulus_kpa']:8g} {row['alpha_over_d']:7.3f} "
            f"{row['ml_low']:8.3f}–{row['ml_high']:.3f} {row['c_that_matches']:6.3f}"
        )
    # ln(α/D) = ln K + a ln(D/t_m) + b ln(σc/E_m), over the members with a measured α
    used = [r for r in rows if r["alpha_over_d"] > 0.0]
    design = np.array(
        [
            [
                1.0,
                math.log(25.0 / r["membrane_thickness_mm"]),
                math.log(r["cell_pressure_kpa"] / r["membrane_modulus_kpa"]),
            ]
            for r in used
        ]
    )
    target = np.log([r["alpha_over_d"] for r in used])
    coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = target - design @ coefficients
    dof = max(len(used) - 3, 1)
    covariance = float(residual @ residual) / dof * np.linalg.inv(design.T @ design)
    errors = np.sqrt(np.diag(covariance))
    constant = math.exp(coefficients[0]) / (1.0 + e) ** (4.0 / 9.0)
    print(
        f"fit over {len(used)} members: a (D/t_m) = {coefficients[1]:.3f} ± {errors[1]:.3f}, "
        f"b (σc/E_m) = {coefficients[2]:.3f} ± {errors[2]:.3f} (Molenkamp & Luger: 1/3, 1/3); "
        f"C = {constant:.3f}; RMS of ln(α/D) {math.sqrt(float(residual @ residual) / len(used)):.3f}"
    )
    with open(args.out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
