"""The damping artefact: what Cundall's local damping on absolute velocities adds to the platen stress.

Local damping, F − α|F| sign(u) (Cundall 1987), opposes each sphere's (and membrane node's) velocity u.
With ``DampingParams.frame = "absolute"`` u is the velocity itself, so a sphere carried by the closing
platens is dragged against the affine motion and the platens carry the drag; with ``"affine"`` (the
default) u is the velocity relative to the strain-controlled walls' affine field
(:func:`membrax.spheres.walls.affine_velocity`: the platens while shearing; servo-held walls count as at
rest) and only the rest of the motion is damped. This script measures both, at I = 1e-3 and 10 kPa, on:

- a rigid box (servo lateral walls, no membrane), both platens closing at ε̇H/2 each, and the top one
  alone at ε̇H;
- a membrane cell with a nearly vanishing membrane: 5 mm of 40 kPa latex, E_m t_m = 200 N/m, 1/35 of the
  paper's, the softest that holds 10 kPa well clear of the inflation limit over the windows between the
  spheres (0.42 of it, :func:`membrax.config.inflation_ratio`), both platens closing (the cell's default).

Each cell is consolidated once (every wall servo-held: the two frames are the same law there, bit for bit)
and sheared from that state in each frame to ``--strain`` (the platens ramped up to full
speed at 1 % strain in both cells); every figure is the mean over the records between ``--window`` and
``--strain`` of axial strain. Columns (stresses compression positive):

- ``σ1 bnd/LW−1 %``: the boundary axial stress over the Love–Weber (contact) stress of the spheres, less
  one: the platens' mean in the box, the ram's (external σ1, the mean of both platens) in the membrane cell;
- ``top σ1/LW−1 %``: the same for the top platen alone (what a load cell on the ram reads);
- ``σ3 bnd/LW−1 %``: the same radially: the lateral walls' in the box, the membrane's load on the spheres
  (internal σ3) in the membrane cell;
- ``Dsph σ1`` and ``Dsph σ3`` (% of σc): the spheres' damping stress, (1/V) Σ D_z (z − z_mid) and
  (1/2V) Σ (D_x (x − x_c) + D_y (y − y_c)), D = F_d − F each sphere's damping force at the record's state:
  by the spheres' balance of momentum it is the boundary stress's excess over the Love–Weber stress that
  the damping causes (in the box, ``σ1 bnd/LW−1`` times ``σ1 LW`` over σc, less inertia, ~I² of it);
- ``Dnode σ1`` and ``Dnode σ3`` (% of σc): the membrane nodes' damping forces, what they add to the ram
  (axially, (1/AH) Σ D_z (z − z_mid)) and to the internal σ3 (radially, −Σ D·r̂ over the right
  cylinder's lateral area, as :mod:`membrax.membrane.records` counts the membrane's load);
- ``(int−ext)σ1 %σc`` and ``(int−ext)σ3 %σc``: the membrane cell's internal minus external stresses, the
  targets a membrane correction is fitted on (:mod:`calibrate.datasets`).

Run: ``python examples/damping_artefact.py [--size small|paper] [--strain 0.02] [--window 0.01] [--x64]``
(small: 6 spheres across, 10 layers, about 2.5 min on 2 CPU cores; ``--size paper --cells rigid``, the
paper-size rigid box, 10 × 25, about 4 min).
"""

import argparse
import dataclasses
import functools
import time

SIZES = {"small": (6, 10), "paper": (10, 25)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=sorted(SIZES), default="small", help="specimen size")
    parser.add_argument("--strain", type=float, default=0.02, help="axial strain to shear to")
    parser.add_argument("--window", type=float, default=0.01, help="averaging starts at this axial strain")
    parser.add_argument("--inertial-number", type=float, default=1e-3)
    parser.add_argument("--cell-pressure-kpa", type=float, default=10.0)
    parser.add_argument("--x64", action="store_true", help="run in float64")
    parser.add_argument("--cells", default="rigid,membrane", help="comma-separated: rigid, membrane")
    args = parser.parse_args()

    import jax

    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from membrax import assemble
    from membrax.config import TriaxialConfig
    from membrax.defaults import DAMPING_FRAMES, LATEX_DENSITY, SHEAR_RAMP_STRAIN
    from membrax.driver import ChunkRunner
    from membrax.membrane import energies
    from membrax.membrane.coupled import contact_forces
    from membrax.membrane.mesh import free_node_mask
    from membrax.spheres import fcc
    from membrax.spheres.integrate import DampingParams, apply_damping, compute_forces
    from membrax.spheres.walls import BOTTOM, TOP, affine_velocity
    from membrax.triaxial import rigid

    across, layers = SIZES[args.size]
    cell_pressure = 1e3 * args.cell_pressure_kpa

    def damping_force(force, velocity, position, walls, mass, damping, member):
        """D = F_d − F, as the step applies it at this state (the frame's reference field)."""
        reference = affine_velocity(position, walls, member) if damping.frame == "affine" else None
        return apply_damping(force, velocity, mass, damping, member, reference) - force

    def moments(force, position, walls, centre):
        """First moments of damping forces: Σ D_z (z − z_mid), ½ Σ D·(x − c), −Σ D·r̂ in xy (N·m, N·m, N)."""
        z_mid = 0.5 * (walls.position[0, TOP] - walls.position[0, BOTTOM])
        radial = position[:, :2] - centre
        unit = radial / jnp.linalg.norm(radial, axis=1, keepdims=True)
        return jnp.stack(
            [
                jnp.sum(force[:, 2] * (position[:, 2] - z_mid)),
                0.5 * jnp.sum(force[:, :2] * radial),
                -jnp.sum(force[:, :2] * unit),
            ]
        )

    def with_record(test, record):
        """The test with a runner whose records are (the test's records, ``record(state, params)``)."""
        old = test.runner
        base = old.record_fn
        new = ChunkRunner(
            old.step_fn,
            old.neighbor_frame,
            lambda s, p: (base(s, p), record(s, p)),
            old.num_particles,
            old.capacity_growth,
            old.grow_membrane,
            old.dem_of,
            old.with_dem,
        )
        return dataclasses.replace(test, runner=new)

    def window_mean(strain, values):
        axial = np.asarray(strain)[:, 0]
        keep = (axial >= args.window) & (axial <= args.strain)
        return float(np.mean(np.asarray(values)[keep]))

    rows = []

    def shear(test, state, **loading):
        start = time.perf_counter()
        state, records = test.shear(
            state,
            target_axial_strain=args.strain,
            inertial_number=args.inertial_number,
            record_every_fine=50,
            record_every_coarse=50,
            fine_until_strain=args.strain,
            ramp_strain=SHEAR_RAMP_STRAIN,
            **loading,
        )
        return records, time.perf_counter() - start

    cells = args.cells.split(",")
    if "rigid" in cells:
        specimen = fcc.fcc_specimen(0.025, across, layers)
        base = rigid.rigid_wall_test(specimen, cell_pressure)
        consolidated, _ = base.consolidate()

        def rigid_record():
            def record(state, params):
                forces = compute_forces(state, base.particles, params, base.dt, wall_friction=False)
                member = base.particles.member
                force = damping_force(
                    forces.force,
                    state.velocity,
                    state.position,
                    state.walls,
                    base.particles.mass,
                    params.damping,
                    member,
                )
                return moments(force, state.position, state.walls, jnp.mean(state.position[:, :2], axis=0))

            return record

        for loading, symmetric in (("both platens", True), ("top platen", False)):
            for frame in DAMPING_FRAMES:
                damping = DampingParams.local(0.3, frame)
                test = with_record(
                    dataclasses.replace(base, params=base.params.set(damping=damping)), rigid_record()
                )
                (records, extra), seconds = shear(test, consolidated, symmetric=symmetric)
                volume = np.asarray(records.area) * np.asarray(records.height)
                mean = functools.partial(window_mean, records.axial_strain)
                rows.append(
                    {
                        "case": f"rigid box, {loading}",
                        "frame": frame,
                        "σ1 LW kPa": mean(records.love_weber_axial_stress) / 1e3,
                        "σ1 bnd/LW−1 %": 100
                        * (mean(records.wall_axial_stress) / mean(records.love_weber_axial_stress) - 1),
                        "top σ1/LW−1 %": 100
                        * (
                            mean(np.asarray(records.wall_force)[:, :, TOP] / np.asarray(records.area))
                            / mean(records.love_weber_axial_stress)
                            - 1
                        ),
                        "σ3 bnd/LW−1 %": 100
                        * (mean(records.wall_radial_stress) / mean(records.love_weber_radial_stress) - 1),
                        "Dsph σ1 %σc": 100 * mean(np.asarray(extra)[:, 0:1] / volume) / cell_pressure,
                        "Dsph σ3 %σc": 100 * mean(np.asarray(extra)[:, 1:2] / volume) / cell_pressure,
                        "seconds": seconds,
                    }
                )
                print_row(rows[-1], first=len(rows) == 1)

    if "membrane" in cells:
        config = TriaxialConfig(
            particles_across=across,
            layers=layers,
            cell_pressure_kpa=args.cell_pressure_kpa,
            membrane_thickness_mm=5.0,
            membrane_modulus_kpa=40.0,
            float64=args.x64,
        )
        base = assemble.build_test(config)
        consolidated, _ = base.consolidate()
        free = jnp.asarray(free_node_mask(base.mesh))
        node_mass_per_thickness = energies.lumped_mass(base.mesh, 1.0, LATEX_DENSITY)
        node_member = jnp.zeros(base.mesh.num_nodes, dtype=jnp.int32)

        def membrane_record(state, params):
            mp = params.membrane
            contact = contact_forces(state, base.particles, params, base.dt)
            spheres = state.dem
            sphere_force = compute_forces(spheres, base.particles, params.dem, base.dt, False).force
            sphere_force = sphere_force + contact.sphere_force
            centre = jnp.mean(state.membrane.clamp_position[0][:, :2], axis=0)  # the specimen's axis
            on_spheres = damping_force(
                sphere_force,
                spheres.velocity,
                spheres.position,
                spheres.walls,
                base.particles.mass,
                params.dem.damping,
                base.particles.member,
            )
            nodes = state.membrane
            internal = energies.nodal_forces(
                nodes.position,
                base.mesh,
                mp.modulus,
                mp.thickness,
                mp.cell_pressure,
                bending_factor=mp.bending_factor,
            )
            node_force = internal + contact.node_force
            on_nodes = damping_force(
                node_force,
                nodes.velocity,
                nodes.position,
                spheres.walls,
                mp.thickness * node_mass_per_thickness,
                params.dem.damping,
                node_member,
            )
            on_nodes = jnp.where(free[:, None], on_nodes, 0.0)
            return jnp.stack(
                [
                    moments(on_spheres, spheres.position, spheres.walls, centre),
                    moments(on_nodes, nodes.position, spheres.walls, centre),
                ]
            )

        for frame in DAMPING_FRAMES:
            damping = DampingParams.local(0.3, frame)
            params = base.params.set(dem=base.params.dem.set(damping=damping))
            test = with_record(dataclasses.replace(base, params=params), membrane_record)
            (records, extra), seconds = shear(test, consolidated)
            extra = np.asarray(extra)
            volume = np.asarray(records.volume)
            area = np.asarray(records.platen_area)
            height = np.asarray(records.height)
            lateral = 2.0 * np.sqrt(np.pi * area) * height
            mean = functools.partial(window_mean, records.axial_strain)
            external_1, internal_1 = mean(records.external_axial_stress), mean(records.internal_axial_stress)
            external_3, internal_3 = (
                mean(records.external_radial_stress),
                mean(records.internal_radial_stress),
            )
            # The top platen's ram alone: the external σ1 times its share of the two platens' mean ram force.
            ram = np.asarray(records.platen_ram_force)
            top_1 = mean(np.asarray(records.external_axial_stress) * ram[:, :, TOP] / np.mean(ram, axis=2))
            rows.append(
                {
                    "case": "membrane, 200 N/m, both",
                    "frame": frame,
                    "σ1 LW kPa": mean(records.love_weber_axial_stress) / 1e3,
                    "σ1 bnd/LW−1 %": 100 * (external_1 / mean(records.love_weber_axial_stress) - 1),
                    "top σ1/LW−1 %": 100 * (top_1 / mean(records.love_weber_axial_stress) - 1),
                    "σ3 bnd/LW−1 %": 100 * (internal_3 / mean(records.love_weber_radial_stress) - 1),
                    "Dsph σ1 %σc": 100 * mean(extra[:, 0, 0:1] / volume) / cell_pressure,
                    "Dsph σ3 %σc": 100 * mean(extra[:, 0, 1:2] / volume) / cell_pressure,
                    "Dnode σ1 %σc": 100 * mean(extra[:, 1, 0:1] / (area * height)) / cell_pressure,
                    "Dnode σ3 %σc": 100 * mean(extra[:, 1, 2:3] / lateral) / cell_pressure,
                    "(int−ext)σ1 %σc": 100 * (internal_1 - external_1) / cell_pressure,
                    "(int−ext)σ3 %σc": 100 * (internal_3 - external_3) / cell_pressure,
                    "seconds": seconds,
                }
            )
            print_row(rows[-1], first=len(rows) == 1)


COLUMNS = (
    "case",
    "frame",
    "σ1 LW kPa",
    "σ1 bnd/LW−1 %",
    "top σ1/LW−1 %",
    "σ3 bnd/LW−1 %",
    "Dsph σ1 %σc",
    "Dsph σ3 %σc",
    "Dnode σ1 %σc",
    "Dnode σ3 %σc",
    "(int−ext)σ1 %σc",
    "(int−ext)σ3 %σc",
    "seconds",
)


def print_row(row, first=False):
    """One row of the table (the header first): cases and frames left-aligned, numbers right."""
    widths = {"case": 26, "frame": 9}
    if first:
        print("  ".join(f"{name:<{widths.get(name, 15)}}" for name in COLUMNS))
    cells = []
    for name in COLUMNS:
        value = row.get(name)
        width = widths.get(name, 15)
        if isinstance(value, str):
            cells.append(f"{value:<{width}}")
        elif value is None:
            cells.append(f"{'—':>{width}}")
        else:
            cells.append(f"{value:>{width}.{0 if name == 'seconds' else 2}f}")
    print("  ".join(cells), flush=True)


if __name__ == "__main__":
    main()
