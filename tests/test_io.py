"""membrax.io: VTU round trips through meshio against the written numbers and hand-derived fields.

Units: m, N. Every round trip reads the file back with ``meshio.read`` and compares points, cells and
fields with what was written (1e-12), the counts with the mesh/specimen sizes, and the derived fields with
their hand values (diameter = 2R, triangle areas from the file = the mesh's rest areas).
"""

import math

import meshio
import numpy as np
import pytest

from membrax import io
from membrax.membrane.mesh import cylinder_mesh
from membrax.spheres import fcc

RADIUS = 0.13
HEIGHT = 0.2
EDGE = 0.04


@pytest.fixture(scope="module")
def mesh():
    return cylinder_mesh(RADIUS, HEIGHT, EDGE)


@pytest.fixture(scope="module")
def specimen():
    return fcc.fcc_specimen(particle_diameter=0.025, width_spheres=4, height_layers=3)


def _membrane_fields(mesh):
    position = np.asarray(mesh.reference_position)
    num_nodes, num_triangles = position.shape[0], mesh.triangles.shape[0]
    rng = np.random.default_rng(0)
    point_data = {
        "contact_force": rng.normal(size=(num_nodes, 3)),
        "indentation": rng.uniform(0.0, 1e-3, size=num_nodes),
        "on_ring": np.arange(num_nodes) < 10,
    }
    cell_data = {"stretch": 1.0 + rng.uniform(0.0, 0.1, size=num_triangles)}
    return position, point_data, cell_data


def test_membrane_round_trip(tmp_path, mesh):
    position, point_data, cell_data = _membrane_fields(mesh)
    path = tmp_path / "membrane.vtu"
    # jax arrays straight from the mesh (converted inside)
    io.write_membrane_vtk(path, mesh.reference_position, mesh.triangles, point_data, cell_data)
    back = meshio.read(path)

    # counts: n_θ = round(2πR/a) nodes per ring, round(H/(a√3/2)) + 1 rings, 2·n_θ triangles per row
    n_theta = round(2 * math.pi * RADIUS / EDGE)
    rows = round(HEIGHT / (EDGE * math.sqrt(3) / 2))
    assert back.points.shape == (n_theta * (rows + 1), 3)
    assert len(back.cells) == 1 and back.cells[0].type == "triangle"
    assert back.cells[0].data.shape == (2 * n_theta * rows, 3)

    np.testing.assert_allclose(back.points, position, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.cells[0].data, np.asarray(mesh.triangles))
    for name in ("contact_force", "indentation"):
        np.testing.assert_allclose(back.point_data[name], point_data[name], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.point_data["on_ring"], point_data["on_ring"].astype(np.uint8))
    np.testing.assert_allclose(back.cell_data["stretch"][0], cell_data["stretch"], rtol=0, atol=1e-12)

    # the geometry in the file is the mesh's: triangle areas ½|(b − a) × (c − a)| = rest areas
    a, b, c = (back.points[back.cells[0].data[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    np.testing.assert_allclose(area, np.asarray(mesh.reference_area), rtol=1e-12)


def test_particles_round_trip(tmp_path, specimen):
    # W = 4 octagon: 12 spheres in the even layers, 9 in the odd one (hand count, see test_plots)
    assert specimen.num_particles == 12 + 9 + 12
    position = np.asarray(specimen.position)
    n = position.shape[0]
    velocity = np.column_stack([np.zeros(n), np.zeros(n), -0.01 * np.ones(n)])
    force = np.linspace(-1.0, 1.0, 3 * n).reshape(n, 3)
    path = tmp_path / "particles.vtu"
    io.write_particles_vtk(path, specimen.position, specimen.radius, {"velocity": velocity, "force": force})
    back = meshio.read(path)

    assert back.points.shape == (33, 3)
    assert len(back.cells) == 1 and back.cells[0].type == "vertex"
    np.testing.assert_array_equal(back.cells[0].data[:, 0], np.arange(33))
    np.testing.assert_allclose(back.points, position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.point_data["radius"], np.full(33, 0.0125), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.point_data["diameter"], np.full(33, 0.025), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.point_data["velocity"], velocity, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.point_data["force"], force, rtol=0, atol=1e-12)
    # total force written = Σ of the linspace 0..3n−1 mapped to [−1, 1]: symmetric, so 0
    assert abs(back.point_data["force"].sum()) < 1e-12


def test_particles_scalar_radius(tmp_path):
    path = tmp_path / "one.vtu"
    io.write_particles_vtk(path, np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.2]]), 0.02)
    back = meshio.read(path)
    np.testing.assert_allclose(back.point_data["diameter"], [0.04, 0.04], rtol=0, atol=1e-15)


def test_membrane_bad_fields(tmp_path, mesh):
    position, triangles = mesh.reference_position, mesh.triangles
    num_nodes, num_triangles = position.shape[0], triangles.shape[0]
    nan_nodes = np.ones(num_nodes)
    nan_nodes[3] = np.nan
    inf_cells = np.ones(num_triangles)
    inf_cells[4] = np.inf
    path = tmp_path / "bad.vtu"
    cases = [
        ({"indentation": np.zeros(5)}, None, rf"'indentation' has shape \(5,\); expected \({num_nodes},\)"),
        ({"contact_force": np.zeros((num_nodes, 2))}, None, r"'contact_force' has shape \(.*, 2\)"),
        ({"indentation": nan_nodes}, None, "'indentation' has 1 NaN or infinite"),
        (None, {"stretch": np.zeros(num_nodes)}, rf"'stretch' has shape.*expected \({num_triangles},\)"),
        (None, {"stretch": inf_cells}, "'stretch' has 1 NaN or infinite"),
        ({"": np.zeros(num_nodes)}, None, "non-empty"),
    ]
    for point_data, cell_data, pattern in cases:
        with pytest.raises(ValueError, match=pattern):
            io.write_membrane_vtk(path, position, triangles, point_data, cell_data)
    assert not path.exists()


def test_membrane_bad_geometry(tmp_path, mesh):
    position = np.asarray(mesh.reference_position)
    triangles = np.asarray(mesh.triangles).copy()
    path = tmp_path / "bad.vtu"
    out_of_range = triangles.copy()
    out_of_range[7, 1] = position.shape[0]
    with pytest.raises(ValueError, match=r"triangles\[7\].*outside \[0, "):
        io.write_membrane_vtk(path, position, out_of_range)
    negative = triangles.copy()
    negative[0, 0] = -1
    with pytest.raises(ValueError, match=r"triangles\[0\]"):
        io.write_membrane_vtk(path, position, negative)
    with pytest.raises(ValueError, match="triangles has dtype"):
        io.write_membrane_vtk(path, position, triangles.astype(float))
    nan_position = position.copy()
    nan_position[2, 2] = np.nan
    with pytest.raises(ValueError, match="node_position has 1 NaN"):
        io.write_membrane_vtk(path, nan_position, triangles)
    with pytest.raises(ValueError, match=r"node_position has shape \(.*, 2\)"):
        io.write_membrane_vtk(path, position[:, :2], triangles)
    with pytest.raises(ValueError, match=r"\.vtu"):
        io.write_membrane_vtk(tmp_path / "membrane.vtk", position, triangles)
    assert list(tmp_path.iterdir()) == []


def test_particles_bad_inputs(tmp_path, specimen):
    position = np.asarray(specimen.position)
    radius = np.asarray(specimen.radius)
    path = tmp_path / "bad.vtu"
    with pytest.raises(ValueError, match="radius has shape"):
        io.write_particles_vtk(path, position, radius[:-1])
    with pytest.raises(ValueError, match="every radius must be > 0"):
        io.write_particles_vtk(path, position, -radius)
    with pytest.raises(ValueError, match="'diameter' is reserved"):
        io.write_particles_vtk(path, position, radius, {"diameter": 2 * radius})
    bad_velocity = np.zeros((position.shape[0], 3))
    bad_velocity[5, 0] = np.inf
    with pytest.raises(ValueError, match="'velocity' has 1 NaN or infinite"):
        io.write_particles_vtk(path, position, radius, {"velocity": bad_velocity})
    with pytest.raises(ValueError, match=r"'force' has shape \(32, 3\)"):
        io.write_particles_vtk(path, position, radius, {"force": np.zeros((32, 3))})
    assert list(tmp_path.iterdir()) == []
