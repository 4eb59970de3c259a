"""membrax.io results, VTK series and checkpoints: exact round trips against the numbers written.

Records → xarray.Dataset → NetCDF3 → Dataset must give back the same float64 bits and dtypes; the CSV,
read back with numpy, the same numbers (floats are written with repr, which round-trips float64
exactly); the ParaView collections list exactly the steps written; checkpoints restore every leaf
bit-for-bit and survive an interrupted write.
"""

import json
import os
import xml.etree.ElementTree as ElementTree

import jax
import jax.numpy as jnp
import meshio
import numpy as np
import pytest
import xarray as xr

from membrax import io
from membrax import pytree as jdc

T = 7  # records per run in these tests


@jdc.dataclass
class Records:
    step: jnp.ndarray  # (T, 1) int64
    axial_strain: jnp.ndarray  # (T, 1)
    wall_force: jnp.ndarray  # (T, 6)
    converged: jnp.ndarray  # (T, 1) bool
    num_members: int = jdc.static_field()


def _records():
    rng = np.random.default_rng(42)
    axial = rng.uniform(0.0, 0.1, size=(T, 1))
    axial[3, 0] = np.nan  # a friction angle of an unloaded state is NaN: must survive
    axial[4, 0] = 5e-324  # subnormal
    return Records(
        step=jnp.asarray(np.arange(T, dtype=np.int64)[:, None] * 1000),
        axial_strain=jnp.asarray(axial),
        wall_force=jnp.asarray(rng.normal(scale=1e3, size=(T, 6))),
        converged=jnp.asarray((np.arange(T) % 2 == 0)[:, None]),
        num_members=1,
    )


ATTRS = {
    "cell_pressure": 15e3,
    "seed": 7,
    "label": "ballast, 15 kPa",
    "config": {"membrane": {"thickness": 0.002, "modulus": 1.4e6}, "sizes": [0.025, 0.04]},
    "membrane_on": True,
    "comment": None,
    "big_count": 2**40,
}
UNITS = {"axial_strain": "1", "wall_force": "N", "step": "1"}


def _dataset():
    return io.records_to_dataset(_records(), attrs=ATTRS, units=UNITS)


def test_records_to_dataset_layout():
    records = _records()
    ds = _dataset()
    # static field skipped; (T, 1) squeezed; (T, 6) 2-D; step is a coordinate
    assert list(ds.data_vars) == ["axial_strain", "wall_force", "converged"]
    assert list(ds.coords) == ["step"]
    assert ds["step"].dims == ("record",)
    assert ds["axial_strain"].dims == ("record",)
    assert ds["wall_force"].dims == ("record", "wall_force_component")
    assert ds.sizes == {"record": T, "wall_force_component": 6}
    assert ds["step"].dtype == np.int64 and ds["converged"].dtype == np.bool_
    np.testing.assert_array_equal(ds["step"].values, [0, 1000, 2000, 3000, 4000, 5000, 6000])
    np.testing.assert_array_equal(ds["axial_strain"].values, np.asarray(records.axial_strain)[:, 0])
    np.testing.assert_array_equal(ds["wall_force"].values, np.asarray(records.wall_force))
    np.testing.assert_array_equal(ds["converged"].values, [True, False, True, False, True, False, True])
    assert ds["wall_force"].attrs == {"units": "N"} and ds["axial_strain"].attrs == {"units": "1"}
    assert ds["converged"].attrs == {}
    assert io.dataset_attrs_to_python(ds) == ATTRS


def test_higher_rank_dims_and_errors():
    rng = np.random.default_rng(1)
    vec = rng.normal(size=(T, 3))
    cube = rng.normal(size=(T, 2, 4))
    ds = io.records_to_dataset({"v": vec, "c": cube, "n": np.arange(T)}, time_dim="t")
    assert ds["v"].dims == ("t", "v_component")
    assert ds["c"].dims == ("t", "c_dim1", "c_dim2")
    assert ds.sizes == {"t": T, "v_component": 3, "c_dim1": 2, "c_dim2": 4}
    np.testing.assert_array_equal(ds["c"].values, cube)
    assert "step" not in ds.coords

    with pytest.raises(ValueError, match=r"record 'b' has 5 entries.*'a' has 7"):
        io.records_to_dataset({"a": np.zeros(T), "b": np.zeros(5)})
    with pytest.raises(ValueError, match=r"record 'a' is a scalar"):
        io.records_to_dataset({"a": np.float64(1.0)})
    with pytest.raises(ValueError, match=r"units names 'nope'"):
        io.records_to_dataset({"a": np.zeros(T)}, units={"nope": "Pa"})


def test_netcdf_round_trip_exact(tmp_path):
    ds = _dataset()
    folder = tmp_path / "new" / "run"  # missing folders are created
    paths = io.write_results(ds, folder, stem="triax")
    assert paths == {"nc": folder / "triax.nc", "csv": folder / "triax.csv"}
    assert sorted(os.listdir(folder)) == ["triax.csv", "triax.nc"]  # no temporary files left

    back = io.read_results(paths["nc"])
    assert list(back.data_vars) == list(ds.data_vars) and list(back.coords) == ["step"]
    for name in ds.variables:
        assert back[name].dims == ds[name].dims
        assert back[name].dtype == ds[name].dtype, name  # int64 and bool restored (netCDF3 has neither)
        assert back[name].values.tobytes() == ds[name].values.tobytes(), name  # bit-exact, NaN included
        assert back[name].attrs == ds[name].attrs, name
    assert io.dataset_attrs_to_python(back) == ATTRS
    xr.testing.assert_identical(back, ds)

    # written again from what was read: same bytes (nothing drifts on a second round)
    again = io.write_results(back, tmp_path / "again", stem="triax")
    assert again["nc"].read_bytes() == paths["nc"].read_bytes()
    assert again["csv"].read_text() == paths["csv"].read_text()


def test_a_compressed_copy_reads_back_as_the_original(tmp_path):
    """A campaign's sweep kept compressed in a repository: the same dataset to the bit, the same bytes
    each time it is written (the gzip time stamp zeroed), smaller, and read by its magic bytes whatever
    its name."""
    import gzip

    paths = io.write_results(_dataset(), tmp_path / "run", stem="sweep")
    copy = io.write_compressed_copy(paths["nc"], tmp_path / "archive" / "group.nc.gz")
    assert gzip.decompress(copy.read_bytes()) == paths["nc"].read_bytes()
    xr.testing.assert_identical(io.read_results(copy), io.read_results(paths["nc"]))
    again = io.write_compressed_copy(paths["nc"], tmp_path / "again.nc.gz")
    assert again.read_bytes() == copy.read_bytes()
    assert copy.stat().st_size < paths["nc"].stat().st_size
    renamed = tmp_path / "plain_name.nc"
    renamed.write_bytes(copy.read_bytes())
    xr.testing.assert_identical(io.read_results(renamed), io.read_results(paths["nc"]))
    with pytest.raises(ValueError, match="not a NetCDF3 results file"):
        io.write_compressed_copy(paths["csv"], tmp_path / "bad.nc.gz")
    assert not (tmp_path / "bad.nc.gz").exists()


def test_csv_contents(tmp_path):
    records = _records()
    paths = io.write_results(_dataset(), tmp_path)
    text = paths["csv"].read_text()
    lines = text.splitlines()
    comments = [line for line in lines if line.startswith("#")]
    assert comments == [
        "# cell_pressure: 15000.0",
        "# seed: 7",
        "# label: ballast, 15 kPa",
        '# config: {"membrane": {"thickness": 0.002, "modulus": 1400000.0}, "sizes": [0.025, 0.04]}',
        "# membrane_on: true",
        "# comment: null",
        "# big_count: 1099511627776",
    ]
    header = lines[len(comments)].split(",")
    assert header == ["step", "axial_strain", *(f"wall_force_{k}" for k in range(6)), "converged"]
    assert len(lines) == len(comments) + 1 + T

    table = np.loadtxt(paths["csv"], delimiter=",", skiprows=len(comments) + 1, ndmin=2)
    assert table.shape == (T, 9)
    np.testing.assert_array_equal(table[:, 0], np.arange(T) * 1000.0)
    np.testing.assert_array_equal(table[:, 1], np.asarray(records.axial_strain)[:, 0])  # exact, NaN too
    np.testing.assert_array_equal(table[:, 2:8], np.asarray(records.wall_force))
    np.testing.assert_array_equal(table[:, 8], [1, 0, 1, 0, 1, 0, 1])
    row = lines[len(comments) + 4].split(",")  # record 3: the NaN
    assert row[0] == "3000" and row[1] == "nan" and row[8] == "0"
    assert lines[len(comments) + 5].split(",")[1] == "5e-324"


def test_vtk_series_pvd_and_resume(tmp_path):
    node = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    centres = np.array([[0.2, 0.2, 0.1], [0.7, 0.6, 0.1]])
    radius = np.array([0.05, 0.08])
    steps_times = [(0, 0.0), (500, 1.25e-3), (1000, 2.5e-3)]

    series = io.VTKSeries(tmp_path / "vtk", "run")
    for step, time in steps_times:
        shifted = node + np.array([0.0, 0.0, step * 1e-6])
        written = series.add(
            step,
            time,
            membrane=(shifted, triangles, {"indentation": np.full(4, step * 1e-7)}, {"stretch": np.ones(2)}),
            particles=(centres, radius, {"velocity": np.zeros((2, 3))}),
        )
        assert written == {
            "membrane": tmp_path / "vtk" / f"run_membrane_{step:09d}.vtu",
            "particles": tmp_path / "vtk" / f"run_particles_{step:09d}.vtu",
        }

    def pvd_entries(kind):
        root = ElementTree.parse(tmp_path / "vtk" / f"run_{kind}.pvd").getroot()
        assert root.tag == "VTKFile" and root.get("type") == "Collection" and root.get("version") == "0.1"
        (collection,) = list(root)
        assert collection.tag == "Collection"
        return [(d.get("timestep"), d.get("part"), d.get("file")) for d in collection]

    for kind in ("membrane", "particles"):
        assert pvd_entries(kind) == [
            ("0.0", "0", f"run_{kind}_000000000.vtu"),
            ("0.00125", "0", f"run_{kind}_000000500.vtu"),
            ("0.0025", "0", f"run_{kind}_000001000.vtu"),
        ]
    assert sorted(os.listdir(tmp_path / "vtk")) == sorted(
        [f"run_{k}_{s:09d}.vtu" for k in ("membrane", "particles") for s, _ in steps_times]
        + ["run_membrane.pvd", "run_particles.pvd"]
    )
    mesh = meshio.read(tmp_path / "vtk" / "run_membrane_000001000.vtu")
    np.testing.assert_allclose(mesh.points[:, 2], np.full(4, 1e-3), rtol=0, atol=1e-15)
    np.testing.assert_allclose(mesh.point_data["indentation"], np.full(4, 1e-4), rtol=0, atol=1e-18)

    # a new series object (a resumed run) reads the entries back and appends; membrane only this time
    resumed = io.VTKSeries(tmp_path / "vtk", "run")
    assert [(s, t) for s, t, _ in resumed.entries("particles")] == steps_times
    resumed.add(1500, 3.75e-3, membrane=(node, triangles))
    assert [e[2] for e in pvd_entries("membrane")] == [
        f"run_membrane_{s:09d}.vtu" for s in (0, 500, 1000, 1500)
    ]
    assert len(pvd_entries("particles")) == 3
    # an unlisted file left by a crash between the .vtu and the .pvd write
    (tmp_path / "vtk" / "run_particles_000002000.vtu").write_bytes(b"orphan")

    # resume from the checkpoint at step 500: later entries and files go
    truncated = io.VTKSeries(tmp_path / "vtk", "run", resume_step=500)
    for kind in ("membrane", "particles"):
        assert pvd_entries(kind) == [
            ("0.0", "0", f"run_{kind}_000000000.vtu"),
            ("0.00125", "0", f"run_{kind}_000000500.vtu"),
        ]
        assert [(s, t) for s, t, _ in truncated.entries(kind)] == [(0, 0.0), (500, 1.25e-3)]
    assert sorted(os.listdir(tmp_path / "vtk")) == sorted(
        [f"run_{k}_{s:09d}.vtu" for k in ("membrane", "particles") for s in (0, 500)]
        + ["run_membrane.pvd", "run_particles.pvd"]
    )
    assert io.read_pvd(tmp_path / "vtk" / "run_membrane.pvd") == [
        (0.0, "run_membrane_000000000.vtu"),
        (1.25e-3, "run_membrane_000000500.vtu"),
    ]

    # a failing write lists nothing and leaves no file
    with pytest.raises(ValueError, match="radius"):
        truncated.add(600, 1.5e-3, membrane=(node, triangles), particles=(centres, -radius))
    assert len(os.listdir(tmp_path / "vtk")) == 6
    assert [s for s, _, _ in truncated.entries("membrane")] == [0, 500]


@jdc.dataclass
class Inner:
    position: jnp.ndarray
    count: jnp.ndarray
    flags: jnp.ndarray
    size: int = jdc.static_field()


@jdc.dataclass
class Outer:
    inner: Inner
    springs: dict
    pair: tuple
    step: int
    dt: float
    raw_key: jnp.ndarray
    key: jnp.ndarray
    host_side: np.ndarray


def _state(position_rows=5, dtype=np.float64):
    rng = np.random.default_rng(3)
    position = rng.normal(size=(position_rows, 3)).astype(dtype)
    position[0, :] = [np.nan, -0.0, 5e-324]  # bits that a lossy copy would change
    inner = Inner(
        position=jnp.asarray(position),
        count=jnp.asarray(np.array([3, -1, 2**30, 0, 7][:position_rows], dtype=np.int32)),
        flags=jnp.asarray(np.array([True, False, True])),
        size=position_rows,
    )
    return Outer(
        inner=inner,
        springs={"tangential": jnp.asarray(rng.normal(size=(4, 3))), "age": jnp.asarray(np.arange(4))},
        pair=(jnp.asarray(np.float32(0.1)), jnp.asarray(np.array([1, 2], dtype=np.uint32))),
        step=123456,
        dt=1e-5 / 3.0,
        raw_key=jax.random.PRNGKey(11),
        key=jax.random.key(5),
        host_side=np.array([0.5, 0.25]),
    )


def _bits(leaf):
    if jax.dtypes.issubdtype(getattr(leaf, "dtype", np.float64), jax.dtypes.prng_key):
        return "key", str(jax.random.key_impl(leaf)), np.asarray(jax.random.key_data(leaf)).tobytes()
    array = np.asarray(leaf)
    return type(leaf).__name__, array.dtype.str, array.shape, array.tobytes()


def test_checkpoint_round_trip_bit_exact(tmp_path):
    state = _state()
    history = np.random.default_rng(0).normal(size=(T, 2))
    host = {
        "step": 4000,
        "chunks": [1, 2, 3],
        "settings": {"dt": 1e-5 / 3.0, "note": None},
        "history": history,
    }
    path = io.save_checkpoint(tmp_path / "ckpt" / "state.npz", state, host)
    assert path == tmp_path / "ckpt" / "state.npz" and os.listdir(tmp_path / "ckpt") == ["state.npz"]

    with np.load(path, allow_pickle=False) as npz:  # the documented layout, no pickles
        leaves = jax.tree_util.tree_leaves(state)
        assert sorted(npz.files) == sorted(
            [f"leaf_{i:05d}" for i in range(len(leaves))] + ["__meta__", "__host__", "host__history"]
        )
        meta = json.loads(str(npz["__meta__"][()]))
        assert meta["format"] == "membrax-checkpoint" and meta["num_leaves"] == len(leaves) == 12
        assert meta["leaves"][0] == {"path": ".inner.position", "shape": [5, 3], "dtype": "float64"}
        assert json.loads(str(npz["__host__"][()])) == {
            "step": 4000,
            "chunks": [1, 2, 3],
            "settings": {"dt": 1e-5 / 3.0, "note": None},
        }

    restored, host_back = io.load_checkpoint(path, like=_state())
    assert type(restored) is Outer and type(restored.inner) is Inner and restored.inner.size == 5
    original = jax.tree_util.tree_leaves(state)
    back = jax.tree_util.tree_leaves(restored)
    assert [_bits(a) for a in back] == [_bits(a) for a in original]
    assert type(restored.step) is int and restored.step == 123456
    assert type(restored.dt) is float and restored.dt == 1e-5 / 3.0
    assert isinstance(restored.host_side, np.ndarray) and isinstance(restored.inner.position, jax.Array)
    assert host_back.keys() == host.keys()
    assert host_back["step"] == 4000 and host_back["chunks"] == [1, 2, 3]
    assert host_back["settings"] == {"dt": 1e-5 / 3.0, "note": None}
    assert host_back["history"].dtype == np.float64
    assert host_back["history"].tobytes() == history.tobytes()

    # no host → None; an abstract template (jax.eval_shape) works too
    io.save_checkpoint(tmp_path / "bare.npz", {"x": jnp.asarray(np.arange(3.0))})
    bare, none = io.load_checkpoint(
        tmp_path / "bare.npz", like={"x": jax.ShapeDtypeStruct((3,), jnp.float64)}
    )
    assert none is None
    np.testing.assert_array_equal(np.asarray(bare["x"]), [0.0, 1.0, 2.0])


def test_checkpoint_template_mismatch(tmp_path):
    path = io.save_checkpoint(tmp_path / "state.npz", _state())
    with pytest.raises(
        ValueError, match=r"leaf \.inner\.position: shape \(5, 3\) dtype float64.*shape \(4, 3\)"
    ):
        io.load_checkpoint(path, like=_state(position_rows=4))
    with pytest.raises(ValueError, match=r"\.inner\.position.*dtype float32.*different configuration"):
        io.load_checkpoint(path, like=_state(dtype=np.float32))
    with pytest.raises(ValueError, match=r"leaf \['only'\]: shape \(5, 3\) dtype float64.*shape \(2,\)"):
        io.load_checkpoint(path, like={"only": jnp.asarray(np.zeros(2))})
    # same first leaf, fewer leaves: names the first leaf the template lacks
    with pytest.raises(
        ValueError,
        match=r"leaf \.inner\.count: in the checkpoint \(12 leaves\), not in the "
        r"template \(1 leaves\).*different configuration",
    ):
        io.load_checkpoint(path, like={"only": jnp.asarray(np.zeros((5, 3)))})


def test_interrupted_checkpoint_write_keeps_previous(tmp_path, monkeypatch):
    path = tmp_path / "state.npz"
    io.save_checkpoint(path, {"x": jnp.asarray(np.array([1.0, 2.0]))}, {"step": 1})
    before = path.read_bytes()

    def crash(src, dst):
        assert os.path.getsize(src) > 0  # the temporary file was fully written next to the target
        raise OSError("simulated crash before the rename")

    monkeypatch.setattr(io.files.os, "replace", crash)
    with pytest.raises(OSError, match="simulated crash"):
        io.save_checkpoint(path, {"x": jnp.asarray(np.array([3.0, 4.0]))}, {"step": 2})
    with pytest.raises(OSError, match="simulated crash"):
        io.write_results(io.records_to_dataset({"a": np.zeros(3)}), tmp_path)
    monkeypatch.undo()

    assert os.listdir(tmp_path) == ["state.npz"]  # no temporary file, no half-written results
    assert path.read_bytes() == before
    state, host = io.load_checkpoint(path, like={"x": jnp.asarray(np.zeros(2))})
    np.testing.assert_array_equal(np.asarray(state["x"]), [1.0, 2.0])
    assert host == {"step": 1}


def test_bad_paths_and_files(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    ds = io.records_to_dataset({"a": np.zeros(2)})
    with pytest.raises(ValueError, match=r"a_file' exists and is not a directory"):
        io.write_results(ds, a_file)
    with pytest.raises(ValueError, match=r"a_file' exists and is not a directory"):
        io.VTKSeries(a_file, "run")
    with pytest.raises(ValueError, match=r"a_file' exists and is not a directory"):
        io.save_checkpoint(a_file / "state.npz", {"x": jnp.asarray(np.zeros(1))})
    with pytest.raises(ValueError, match=r"a_file/sub' cannot be created"):
        io.save_checkpoint(a_file / "sub" / "state.npz", {"x": jnp.asarray(np.zeros(1))})
    with pytest.raises(ValueError, match=r"stem = 'a/b'"):
        io.write_results(ds, tmp_path, stem="a/b")

    like = {"x": jnp.asarray(np.zeros(2))}
    with pytest.raises(FileNotFoundError, match=r"missing\.npz' does not exist"):
        io.load_checkpoint(tmp_path / "missing.npz", like)
    with pytest.raises(ValueError, match=r"a_file' is not a checkpoint .npz.*save_checkpoint"):
        io.load_checkpoint(a_file, like)
    np.savez(tmp_path / "plain.npz", x=np.zeros(2))
    with pytest.raises(ValueError, match=r"plain\.npz' is an \.npz but not a membrax checkpoint"):
        io.load_checkpoint(tmp_path / "plain.npz", like)
    good = io.save_checkpoint(tmp_path / "good.npz", {"x": jnp.asarray(np.arange(200.0))})
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[:-300])
    with pytest.raises(ValueError, match=r"cut\.npz"):
        io.load_checkpoint(tmp_path / "cut.npz", {"x": jnp.asarray(np.zeros(200))})

    paths = io.write_results(ds, tmp_path)
    with pytest.raises(ValueError, match=r"results\.csv' is not a NetCDF3 results file \(that is the CSV"):
        io.read_results(paths["csv"])
    (tmp_path / "bad.pvd").write_text("<VTKFile><Collection>")
    with pytest.raises(ValueError, match=r"bad\.pvd' is not valid XML"):
        io.read_pvd(tmp_path / "bad.pvd")
