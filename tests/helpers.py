"""Shared test utilities: per-dtype tolerances, central finite differences for gradient checks, and the
small membrane test the derivative checks share."""

import numpy as np

from membrax.config import PERIODIC_SMOKE_CONFIG, TriaxialConfig

#: The small specimen of the run tests (test_run, test_sweep) and the derivative checks: 4 × 4 × 5 spheres,
#: float64.
SMALL_SPECIMEN = dict(particles_across=4, layers=5, float64=True)

#: The derivative checks' test (test_sensitivity, test_gradients): the small specimen, a membrane of edge
#: D/2, 10 kPa, 5 mm.
SMALL_MEMBRANE_TEST = TriaxialConfig(
    **SMALL_SPECIMEN, membrane_edges_per_diameter=2.0, cell_pressure_kpa=10.0, membrane_thickness_mm=5.0
)

#: The small periodic element of the run tests (test_periodic, test_periodic_batch): 64 equal spheres (the
#: fewest), 40 kPa, I = 5e-3, to 1 % in two recording phases, 500-step chunks, a checkpoint after each.
SMALL_ELEMENT = {
    **{key: value for key, value in PERIODIC_SMOKE_CONFIG.items() if key != "name"},
    "checkpoint_every_chunks": 1,
}

#: Round-off tolerances per dtype (jax-md's ``test_util`` is the model): ``ROUNDOFF`` for a few operations
#: (a sum of forces, a ratio), ``ACCUMULATED`` for quantities through thousands of explicit steps.
ROUNDOFF = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-12}
ACCUMULATED = {np.dtype(np.float32): 1e-3, np.dtype(np.float64): 1e-9}


def tolerance(dtype, table=ROUNDOFF) -> float:
    """The relative tolerance of ``table`` for ``dtype`` (an array's dtype or a dtype name)."""
    return table[np.dtype(dtype)]


def central_difference(function, args, index, relative_step=1e-6):
    """d function / d args[index] by central differences, with a step relative to the argument."""
    args = [float(a) for a in args]
    step = relative_step * max(abs(args[index]), 1e-3)
    plus = list(args)
    minus = list(args)
    plus[index] += step
    minus[index] -= step
    return (float(function(*plus)) - float(function(*minus))) / (2.0 * step)


def assert_close(actual, expected, rtol=1e-4, atol=0.0, what=""):
    """np.testing.assert_allclose with a message."""
    np.testing.assert_allclose(np.asarray(actual, dtype=float), expected, rtol=rtol, atol=atol, err_msg=what)


def clamped_cylinder_parts(radius: float, height: float, edge: float, box: float = 2.0):
    """A membrane cylinder between two fixed platens with two small spheres inside that touch nothing.

    Returns (mesh, sphere positions, particles, neighbour frame, walls): the parts the clamped-cylinder tests
    (test_membrane_dem, test_membrane_laws) build their coupled step from; ``box`` is the frame's half-width
    in radii.
    """
    import jax.numpy as jnp

    from membrax.membrane.mesh import cylinder_mesh
    from membrax.spheres.integrate import make_particles
    from membrax.spheres.neighbors import pair_neighbor_fn
    from membrax.spheres.walls import triaxial_walls

    mesh = cylinder_mesh(radius, height, edge)
    spheres = jnp.asarray([[-0.3 * radius, 0.0, 0.5 * height], [0.3 * radius, 0.0, 0.5 * height]])
    particles = make_particles(jnp.full(2, 0.1 * radius), 2650.0)
    frame = pair_neighbor_fn(
        np.full(3, -box * radius), np.array([box, box, height / radius + 1.0]) * radius, 0.2 * radius, 0.02, 0
    )
    walls = triaxial_walls(np.zeros((0, 2)), np.zeros(0), height)
    walls = walls.set(servo=jnp.zeros(walls.servo.shape, bool))
    return mesh, spheres, particles, frame, walls
