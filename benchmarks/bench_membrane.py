"""Membrane cost at paper size: energies, forces and node–sphere contact, float32 and float64.

The paper-size membrane (octagonal specimen, 25 mm spheres, 10 across, 25 layers; edge D/5 ≈ 33,000
triangles) wraps the specimen at t_m/2 outside the outline. For each dtype, in a fresh process, prints:

- membrane forces (−∇ of stretching + bending + pressure energy): compile time and evaluations/s;
- node–sphere contact forces (K = 3 candidate spheres per node, sphere sums over the slot incidence):
  evaluations/s;
- one candidate-list rebuild (every sphere, through the cell list of
  :func:`membrax.membrane.candidates.build_candidates`): ms;
- the full coupled step (DEM + membrane + node–sphere contacts + candidate updates,
  :mod:`membrax.membrane.coupled`) of the paper-size specimen consolidating at 10 kPa in a 5 mm membrane:
  steps/s and particle-steps/s (spheres + nodes);
- peak resident memory.

Rates are the best of three timed runs (after a compiling one): on a shared machine other work only
ever lengthens a run.

Each membrane step of the coupled simulation needs one membrane-force and one contact evaluation, so
their combined rate bounds the membrane part of the DEM + membrane step (target: ≥ 500 steps/s in
float32 for the whole step). The membrane-force rate includes bending (factor 1); the coupled step runs the
paper's pure membrane (factor 0), whose compiled kernel skips the hinges.

With ``--packing random`` the specimen is a random packing of the same spheres, 250 × 500 mm (about 1,740
spheres, compacted first, about 40 s, not timed): its membrane is a cylinder (target: coupled
steps/s within 1.5× of the FCC row's).

With ``--contact-model faces`` the coupled step's spheres meet the membrane's faces, edges and nodes
(:mod:`membrax.membrane.face_contact`, its compiled CPU kernel ``face_contact.cc``) instead of its nodes; the
other columns are the node law's. ``--candidate-capacity K`` sets the coupled step's node table width (the
test's default 3): face contact visits 3K slots per triangle and 2K per edge every step.

Run: ``python benchmarks/bench_membrane.py [--edges-per-diameter 5] [--packing random] [--contact-model faces]
[--candidate-capacity 3] [--dtypes float32]``;
with ``MEMBRAX_NATIVE=0`` the compiled CPU kernels (:mod:`membrax.native`) are off and every figure is
XLA's alone.
"""

import resource

from harness import benchmark_parser, benchmark_report, best_of, time_coupled_steps, timed


def measure(
    dtype: str,
    edges_per_diameter: float,
    repeats: int,
    packing: str = "fcc",
    contact_model: str = "nodes",
    candidate_capacity: int = 3,
) -> dict:
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from membrax import native
    from membrax.membrane import candidates as membrane_candidates
    from membrax.membrane import contact as membrane_contact
    from membrax.membrane import energies
    from membrax.spheres import fcc
    from membrax.triaxial import membrane_cell as membrane_triaxial

    diameter, thickness, modulus, pressure = 0.025, 0.005, 1.4e6, 1e4
    if packing == "random":  # paper-like: 250 × 500 mm, compacted without friction (not timed)
        from membrax.spheres.compaction import random_packing
        from membrax.spheres.grading import Grading

        specimen = random_packing(Grading.equal(diameter), 0.25, 0.5).specimen()
    else:
        specimen = fcc.fcc_specimen(diameter, 10, 25)
    # The coupled test's own mesh (a rounded prism on the FCC specimen, a cylinder on a random one)
    test = membrane_triaxial.membrane_test(
        specimen,
        cell_pressure=pressure,
        membrane_thickness=thickness,
        edges_per_diameter=edges_per_diameter,
        contact_model=contact_model,
        candidate_capacity=candidate_capacity,
    )
    mesh = test.mesh
    nodes = jnp.asarray(mesh.reference_position)

    def in_loop(force_fn):
        # Timed inside a fori_loop, as the coupled step will run it (no per-call dispatch).
        return jax.jit(lambda x: jax.lax.fori_loop(0, repeats, lambda _, y: y + 1e-12 * force_fn(y), x))

    def forces(x):
        return energies.nodal_forces(x, mesh, modulus, thickness, pressure)

    forces_once = jax.jit(forces)
    _, first = timed(forces_once, nodes)
    _, one = timed(forces_once, nodes)
    membrane_loop = in_loop(forces)
    timed(membrane_loop, nodes)
    total = best_of(membrane_loop, nodes)
    membrane_rate = repeats / total

    spheres = jnp.asarray(specimen.position)
    radius = jnp.asarray(specimen.radius)
    capacity = 3  # the coupled test's default K; at 10 kPa a node has at most 2 candidates
    grid = membrane_candidates.cell_grid(spheres, radius, 0.2 * diameter)
    build = jax.jit(
        lambda x: membrane_candidates.build_candidates(
            x, spheres, radius, thickness, 0.2 * diameter, capacity, grid=grid
        )
    )
    candidates, _ = timed(build, nodes)
    _, rebuild = timed(build, nodes + 1e-9)
    params = membrane_contact.MembraneContactParams.default()
    spring = jnp.zeros((3, nodes.shape[0], capacity), nodes.dtype)  # component-first, as the state carries it
    zeros_nodes = jnp.zeros_like(nodes)
    zeros_spheres = jnp.zeros_like(spheres)
    resting_spheres = membrane_contact.ContactSpheres(
        position=spheres, velocity=zeros_spheres, angular_velocity=zeros_spheres, radius=radius
    )
    contact = in_loop(
        lambda x: (
            membrane_contact.node_sphere_forces(
                membrane_contact.ContactNodes(position=x, velocity=zeros_nodes),
                resting_spheres,
                candidates.idx,
                spring,
                1e-5,
                params,
                thickness,
                sphere_slots=candidates.sphere_slots,
            ).node_force
        )
    )
    timed(contact, nodes)
    total_contact = best_of(contact, nodes)
    contact_rate = repeats / total_contact
    coupled_first, coupled_total = time_coupled_steps(test, repeats)
    coupled_rate = repeats / coupled_total
    return {
        "dtype": dtype,
        "kernels": "compiled" if native.available() else "JAX",
        "coupled_compile_s": coupled_first - coupled_total,
        "coupled_steps_per_s": coupled_rate,
        "coupled_particle_steps_per_s": coupled_rate * (specimen.position.shape[0] + int(nodes.shape[0])),
        "nodes": int(nodes.shape[0]),
        "triangles": int(mesh.triangles.shape[0]),
        "spheres": int(spheres.shape[0]),
        "cell_capacity": grid.cell_capacity,
        "capacity": capacity,
        "step_capacity": candidate_capacity,
        "max_candidates": int(candidates.max_count),
        "compile_s": first - one,
        "membrane_forces_per_s": membrane_rate,
        "contact_forces_per_s": contact_rate,
        "combined_per_s": 1.0 / (1.0 / membrane_rate + 1.0 / contact_rate),
        "rebuild_ms": 1e3 * rebuild,
        "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main():
    parser = benchmark_parser(__doc__)
    parser.add_argument("--edges-per-diameter", type=float, default=5.0)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument(
        "--packing",
        choices=("fcc", "random"),
        default="fcc",
        help="fcc: 10 across, 25 layers; random: 250 × 500 mm compacted (about 40 s, not timed)",
    )
    parser.add_argument(
        "--contact-model",
        choices=("nodes", "faces"),
        default="nodes",
        help="where the coupled step's spheres meet the membrane (the other columns: the node law's)",
    )
    parser.add_argument(
        "--candidate-capacity",
        type=int,
        default=3,
        help="K of the coupled step's node table (default 3; face contact visits 3K slots a triangle)",
    )

    def caption(args, first):
        return (
            f"membrane benchmark ({args.packing}, {args.contact_model} contact): {first['nodes']} nodes, "
            f"{first['triangles']} triangles, "
            f"{first['spheres']} spheres (cell list: {first['cell_capacity']} per cell), "
            f"K = {first['capacity']} (max candidates found {first['max_candidates']}), "
            f"the coupled step's K = {first['step_capacity']}; "
            f"CPU kernels: {first['kernels']}"
        )

    benchmark_report(
        __file__,
        parser,
        measure,
        caption,
        "compile s|membrane/s|contact/s|both/s|rebuild ms|step/s|particle-steps/s|peak MB",
        "{compile_s:>10.1f}{membrane_forces_per_s:>11.0f}{contact_forces_per_s:>10.0f}{combined_per_s:>8.0f}"
        "{rebuild_ms:>11.0f}{coupled_steps_per_s:>8.1f}{coupled_particle_steps_per_s:>17.3g}{peak_memory_mb:>9.0f}",
    )


if __name__ == "__main__":
    main()
