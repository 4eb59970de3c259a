"""Paper-size specimen consolidated in a latex membrane: the paper's Fig. 4 section, VTK files, figures.

Builds the paper's specimen (FCC, D = 25 mm, 10 across, 25 layers, 1816 spheres) in a membrane of E_m =
1400 kPa (edge D/5, 34,320 triangles), consolidates it at the cell pressure (default 10 kPa, t_m = 5 mm),
and writes into ``--out`` (default ``results/membrane_consolidation``):

- ``section.png``: a horizontal section at mid-height of a particle layer next to the membrane
  (particles, and the membrane's mid-surface and faces indenting between them), as the paper's Fig. 4;
- ``membrane.vtu`` (fields: stretch λ₁, λ₂ per triangle; node force, contact force share and indentation
  per node) and ``particles.vtu`` (radius, diameter, membrane force) for ParaView;
- ``state.npz``: the final positions, so the pictures can be redrawn with ``--redraw``.

Run: ``python examples/membrane_consolidation.py [--cell-pressure-kpa 10] [--thickness-mm 5]
[--max-steps 12000]`` (float32 on 2 idle CPU cores: 3,000 steps to a UFR of 0.010 at 71 steps/s, 80 s wall
with the build).
"""

import argparse
import pathlib
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


def render(state_file: pathlib.Path, out: pathlib.Path, thickness: float, cell_pressure_kpa: float):
    """Draw the section and write the VTK files from a saved state."""
    import jax.numpy as jnp

    from membrax import io, plots
    from membrax.membrane import measure as membrane_measure
    from membrax.membrane.mesh import prism_mesh
    from membrax.spheres import fcc

    data = np.load(state_file)
    specimen = fcc.fcc_specimen(0.025, 10, 25)
    mesh = prism_mesh(
        np.asarray(specimen.outline_vertices),
        0.5 * thickness,
        specimen.height,
        0.025 / 5.0,
        corner_radius=specimen.particle_radius,
    )
    nodes = jnp.asarray(data["nodes"])
    # Section through the centres of a layer that touches the flat faces (even layers), near mid-height.
    layer = np.asarray(specimen.layer)
    middle = (layer.max() // 2) // 2 * 2
    height = float(np.mean(data["sphere"][layer == middle, 2]))
    fig, ax = plt.subplots(figsize=(7, 7))
    plots.plot_section(
        ax, data["sphere"], data["radius"], data["nodes"], data["triangles"], height, thickness
    )
    ax.set_title(
        f"Horizontal section at z = {1e3 * height:.1f} mm after consolidation at {cell_pressure_kpa:g} kPa, "
        f"t_m = {1e3 * thickness:g} mm\n(step {int(data['step'])}; largest sphere penetration "
        f"{1e3 * float(data['penetration']):.2f} mm, limit t_m/2 = {0.5e3 * thickness:g} mm)",
        fontsize=9,
    )
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "section.png", dpi=130)
    plt.close(fig)
    stretch_major, stretch_minor = membrane_measure.triangle_stretches(nodes, mesh)
    window = 5  # one particle diameter in edges
    io.write_membrane_vtk(
        out / "membrane.vtu",
        data["nodes"],
        data["triangles"],
        point_data={
            "node_force": data["node_force"],
            "indentation": np.asarray(membrane_measure.indentation_field(nodes, mesh, window)),
        },
        cell_data={"stretch_major": np.asarray(stretch_major), "stretch_minor": np.asarray(stretch_minor)},
    )
    io.write_particles_vtk(
        out / "particles.vtu",
        data["sphere"],
        data["radius"],
        point_data={"membrane_force": data["sphere_force"]},
    )
    print(f"wrote {out / 'section.png'}, {out / 'membrane.vtu'}, {out / 'particles.vtu'}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cell-pressure-kpa", type=float, default=10.0)
    parser.add_argument("--thickness-mm", type=float, default=5.0)
    parser.add_argument("--max-steps", type=int, default=12000)
    parser.add_argument(
        "--tolerance", type=float, default=0.013, help="unbalanced-force ratio (float32 floor)"
    )
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/membrane_consolidation"))
    parser.add_argument("--redraw", action="store_true", help="only redraw from OUT/state.npz")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    thickness = 1e-3 * args.thickness_mm
    state_file = args.out / "state.npz"
    if not args.redraw:
        from tqdm import tqdm

        from membrax.spheres import fcc
        from membrax.triaxial import membrane_cell as membrane_triaxial

        specimen = fcc.fcc_specimen(0.025, 10, 25)
        start = time.time()
        test = membrane_triaxial.membrane_test(
            specimen, cell_pressure=1e3 * args.cell_pressure_kpa, membrane_thickness=1e-3 * args.thickness_mm
        )
        print(
            f"built in {time.time() - start:.0f} s: dt = {test.dt:.3e} s, critical steps {test.critical_dt}"
        )
        bar = tqdm(total=args.max_steps, unit="step")

        def progress(state, records):
            bar.update(len(records.step) * 100)
            bar.set_postfix(
                ufr=f"{records.unbalanced_force_ratio[-1, 0]:.4f}",
                platen_kpa=f"{1e-3 * records.platen_axial_stress[-1, 0]:.2f}",
                internal_radial_kpa=f"{1e-3 * records.love_weber_radial_stress[-1, 0]:.2f}",
            )

        state, records = test.consolidate(
            max_steps=args.max_steps,
            tolerance=args.tolerance,
            chunk_steps=1000,
            record_every=100,
            on_chunk=progress,
        )
        bar.close()
        penetration = test.max_penetration(state)
        np.savez(
            state_file,
            sphere=np.asarray(state.dem.position),
            radius=np.asarray(test.particles.radius),
            nodes=np.asarray(state.membrane.position),
            triangles=np.asarray(test.mesh.triangles),
            sphere_force=np.asarray(state.membrane.sphere_force),
            node_force=np.asarray(state.membrane.node_force),
            step=int(state.step),
            penetration=float(penetration),
        )
        last = {
            key: float(np.asarray(value)[-1, 0])
            for key, value in vars(records).items()
            if key != "wall_force" and key != "wall_position"
        }
        for key, value in last.items():
            print(f"{key:>28}: {value:.6g}")
    render(state_file, args.out, thickness, args.cell_pressure_kpa)


if __name__ == "__main__":
    main()
