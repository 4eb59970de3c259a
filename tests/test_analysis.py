"""membrax.triaxial.analysis and the test figures of membrax.plots against hand calculations on synthetic
records.

No simulation: the records are numpy series shaped like a membrane triaxial test at 10 kPa (SI units,
compression positive), dense below 1 % axial strain and coarser after, as the drivers record them.
"""

import math

import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest
from matplotlib.figure import Figure

from membrax import paper, plots, theory
from membrax.triaxial import analysis

CELL = 10e3  # Pa
DENSE_STEP = 6e-5  # window/2 = 0.0025 is 41.7 steps: no record sits on a window edge
COARSE_STEP = 7e-4  # 3.6 steps
DENSE = np.arange(167) * DENSE_STEP  # 0 … 0.996 %
COARSE = 0.01 + np.arange(100) * COARSE_STEP  # 1 % … 7.93 %
AXIAL = np.concatenate([DENSE, COARSE])


def make_records(axial=AXIAL):
    """Records of a dilating specimen whose membrane adds stresses; also the planted series (dict)."""
    axial = np.asarray(axial, dtype=np.float64)
    volumetric = 0.3 * axial - 8.0 * axial**2  # contracts, then dilates
    radial = 1.0 - np.sqrt((1.0 - volumetric) / (1.0 - axial))
    ratio_external = 4.0 + 1.5 * np.exp(-(((axial - 0.06) / 0.01) ** 2)) - 10.0 * axial
    external_axial = CELL * ratio_external
    additional_axial = 4.0e3 - 30e3 * axial
    additional_radial = 1.8e3 - 40e3 * radial
    records = {
        "step": np.arange(axial.size) * 100.0,
        "time": np.arange(axial.size) * 1e-3,
        "axial_strain": axial,
        "volumetric_strain": volumetric,
        "radial_strain": radial,
        "external_axial_stress": external_axial,
        "external_radial_stress": np.full_like(axial, CELL),
        "internal_axial_stress": external_axial + additional_axial,
        "internal_radial_stress": CELL + additional_radial,
        "love_weber_axial_stress": external_axial + 0.5 * additional_axial,
        "love_weber_radial_stress": CELL + 0.5 * additional_radial,
    }
    return records


def mohr_coulomb_deg(major, minor):
    return np.degrees(np.arcsin((major - minor) / (major + minor)))


# ---------------------------------------------------------------------------------------------------------
# strain_ratio_change
# ---------------------------------------------------------------------------------------------------------


def interior(axial, window):
    """Records whose whole window lies inside one uniformly spaced stretch (so it is symmetric)."""
    half = 0.5 * window
    margin = 1e-12
    in_dense = (axial - half > DENSE[0] + margin) & (axial + half < DENSE[-1] - margin)
    in_coarse = (axial - half > COARSE[0] + margin) & (axial + half < COARSE[-1] - margin)
    return in_dense | in_coarse


def test_strain_ratio_change_is_exact_for_a_quadratic_in_symmetric_windows():
    a, b = -0.4, 3.0
    radial = a * AXIAL + b * AXIAL**2
    slope = analysis.strain_ratio_change(AXIAL, radial, window=0.005)
    inside = interior(AXIAL, 0.005)
    assert inside[:167].sum() == 83 and inside[167:].sum() == 92  # both spacings are exercised
    np.testing.assert_allclose(slope[inside], a + 2.0 * b * AXIAL[inside], rtol=0.0, atol=1e-10)
    # Record order does not matter: the result follows the records.
    order = np.random.default_rng(0).permutation(AXIAL.size)
    shuffled = analysis.strain_ratio_change(AXIAL[order], radial[order], window=0.005)
    np.testing.assert_allclose(shuffled, slope[order], rtol=0.0, atol=1e-12)
    # JAX input gives the same numbers.
    from_jax = analysis.strain_ratio_change(jnp.asarray(AXIAL), jnp.asarray(radial), window=0.005)
    np.testing.assert_allclose(from_jax, slope, rtol=0.0, atol=1e-12)


def test_strain_ratio_change_is_the_window_regression_on_irregular_records():
    rng = np.random.default_rng(1)
    axial = np.sort(rng.uniform(0.0, 0.05, 300))
    radial = -0.3 * axial + 2.0 * axial**2 + 1e-5 * rng.standard_normal(axial.size)
    window = 0.004
    slope = analysis.strain_ratio_change(axial, radial, window=window)
    expected = np.full(axial.size, np.nan)
    for i, x in enumerate(axial):
        near = np.abs(axial - x) <= 0.5 * window
        if near.sum() >= 3:
            expected[i] = np.polyfit(axial[near], radial[near], 1)[0]
    assert np.isfinite(expected).all()
    np.testing.assert_allclose(slope, expected, rtol=1e-9, atol=1e-12)
    # Away from the ends it is close to the derivative −0.3 + 4 εa (skewness and noise only).
    middle = (axial > 0.005) & (axial < 0.045)
    assert np.max(np.abs(slope[middle] - (-0.3 + 4.0 * axial[middle]))) < 0.05


def test_strain_ratio_change_nan_where_the_window_is_sparse_or_flat():
    axial = np.array([0.0, 0.01, 0.02, 0.0201, 0.0202, 0.0203, 0.05, 0.1, np.nan])
    radial = -0.25 * axial
    slope = analysis.strain_ratio_change(axial, radial, window=0.005)
    assert np.isnan(slope[[0, 1, 6, 7, 8]]).all()  # alone in their windows, or not finite
    np.testing.assert_allclose(slope[2:6], -0.25, rtol=0.0, atol=1e-12)
    two = analysis.strain_ratio_change([0.0, 0.001, 0.1], [0.0, -0.001, -0.1], window=0.005)
    assert np.isnan(two).all()  # two records per window at most
    flat = analysis.strain_ratio_change(np.zeros(5), np.arange(5.0), window=0.005)
    assert np.isnan(flat).all()  # no spread in εa
    nan_radial = analysis.strain_ratio_change(
        AXIAL[:20], np.where(np.arange(20) == 10, np.nan, 0.1 * AXIAL[:20])
    )
    assert np.isnan(nan_radial[10])
    np.testing.assert_allclose(np.delete(nan_radial, 10), 0.1, rtol=0.0, atol=1e-12)
    with pytest.raises(ValueError, match="window"):
        analysis.strain_ratio_change(AXIAL, AXIAL, window=0.0)
    with pytest.raises(ValueError, match="records"):
        analysis.strain_ratio_change(AXIAL, AXIAL[:-1])


# ---------------------------------------------------------------------------------------------------------
# derived_quantities, initial_state, peak, largest_overestimate, summary_table
# ---------------------------------------------------------------------------------------------------------


def test_derived_quantities_match_hand_calculations():
    records = {
        "axial_strain": np.array([0.0, 0.001, 0.002, 0.003, 0.004]),
        "radial_strain": np.array([0.0, -0.0005, -0.001, -0.0015, -0.002]),
        "external_axial_stress": np.array([30e3, 10.7e3, 0.0, 20e3, 30e3]),
        "external_radial_stress": np.array([10e3, 10e3, 10e3, 10e3, 0.0]),
        "internal_axial_stress": np.array([33e3, 14.6e3, 5e3, -1e3, 30e3]),
        "internal_radial_stress": np.array([11e3, 11.8e3, 10e3, 10e3, 10e3]),
    }
    derived = analysis.derived_quantities(records)
    np.testing.assert_allclose(derived["additional_axial_stress"], [3e3, 3.9e3, 5e3, -21e3, 0.0], atol=1e-9)
    np.testing.assert_allclose(derived["additional_radial_stress"], [1e3, 1.8e3, 0.0, 0.0, 10e3], atol=1e-9)
    np.testing.assert_allclose(derived["axial_stress_ratio"], [1.1, 14.6 / 10.7, np.nan, -0.05, 1.0])
    np.testing.assert_allclose(derived["radial_stress_ratio"], [1.1, 1.18, 1.0, 1.0, np.nan])
    # σ1 = 30 kPa, σ3 = 10 kPa: sin φ' = 20/40, φ' = 30°; NaN where a stress is not positive.
    assert derived["external_friction_angle_deg"][0] == pytest.approx(30.0, abs=1e-12)
    expected_external = [
        30.0,
        math.degrees(math.asin(0.7 / 20.7)),
        np.nan,
        mohr_coulomb_deg(20.0, 10.0),
        np.nan,
    ]
    expected_internal = [
        mohr_coulomb_deg(33.0, 11.0),
        math.degrees(math.asin(2.8 / 26.4)),
        mohr_coulomb_deg(5.0, 10.0),  # σ1 < σ3 gives a negative angle, not NaN
        np.nan,
        mohr_coulomb_deg(30.0, 10.0),
    ]
    np.testing.assert_allclose(derived["external_friction_angle_deg"], expected_external, rtol=1e-12)
    np.testing.assert_allclose(derived["internal_friction_angle_deg"], expected_internal, rtol=1e-12)
    # The angle is theory's, not a copy.
    np.testing.assert_allclose(
        derived["internal_friction_angle_deg"][0], theory.mobilised_friction_angle_deg(33e3, 11e3), rtol=1e-14
    )
    assert "love_weber_friction_angle_deg" not in derived  # optional series absent
    np.testing.assert_allclose(derived["strain_ratio_change"], -0.5, rtol=0.0, atol=1e-12)
    assert set(derived) == {
        "additional_axial_stress",
        "additional_radial_stress",
        "axial_stress_ratio",
        "radial_stress_ratio",
        "external_friction_angle_deg",
        "internal_friction_angle_deg",
        "strain_ratio_change",
    }


def test_records_may_be_jax_arrays_or_an_xarray_dataset_with_a_trailing_axis():
    xr = pytest.importorskip("xarray")
    records = make_records()
    as_numpy = analysis.derived_quantities(records)
    as_jax = analysis.derived_quantities({k: jnp.asarray(v) for k, v in records.items()})
    dataset = xr.Dataset({k: (("record", "one"), v[:, None]) for k, v in records.items()})
    as_xarray = analysis.derived_quantities(dataset)
    assert analysis.record(dataset, "axial_strain").shape == (AXIAL.size,)
    for key, value in as_numpy.items():
        np.testing.assert_allclose(as_jax[key], value, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(as_xarray[key], value, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(
        as_numpy["love_weber_friction_angle_deg"],
        mohr_coulomb_deg(records["love_weber_axial_stress"], records["love_weber_radial_stress"]),
        rtol=1e-12,
    )
    with pytest.raises(KeyError, match="internal_axial_stress"):
        analysis.derived_quantities({k: v for k, v in records.items() if k != "internal_axial_stress"})
    with pytest.raises(ValueError, match="1-D"):
        analysis.record({"step": np.zeros((3, 2))}, "step")


def test_initial_state_converts_pa_to_kpa():
    records = make_records()
    state = analysis.initial_state(records)
    assert state["index"] == 0 and state["axial_strain"] == 0.0
    assert state["sigma3_external_kpa"] == pytest.approx(10.0, rel=1e-14)
    assert state["sigma3_internal_kpa"] == pytest.approx(11.8, rel=1e-14)  # 10 + 1.8 kPa at εr = 0
    assert state["sigma1_external_kpa"] == pytest.approx(10.0 * (4.0 + 1.5 * math.exp(-36.0)), rel=1e-14)
    assert state["sigma1_internal_kpa"] == pytest.approx(state["sigma1_external_kpa"] + 4.0, rel=1e-14)
    last = analysis.initial_state(records, index=-1)
    assert last["index"] == AXIAL.size - 1
    assert last["sigma3_internal_kpa"] == pytest.approx(
        records["internal_radial_stress"][-1] / 1e3, rel=1e-14
    )


def test_peak_finds_the_planted_maxima():
    axial = np.linspace(0.0, 0.1, 101)
    external_ratio = 3.0 + np.where(np.arange(101) == 37, 1.0, 0.0) + 0.5 * axial
    internal_ratio = 3.0 + np.where(np.arange(101) == 4, 0.8, 0.0)
    records = {
        "axial_strain": axial,
        "radial_strain": -0.5 * axial,
        "external_axial_stress": CELL * external_ratio,
        "external_radial_stress": np.full(101, CELL),
        "internal_axial_stress": 1.2 * CELL * internal_ratio,
        "internal_radial_stress": np.full(101, 1.2 * CELL),
    }
    records["external_axial_stress"][60] = np.nan  # a NaN record is skipped
    result = analysis.peak(records)
    assert result["peak_external_index"] == 37 and result["peak_internal_index"] == 4
    assert result["peak_external_axial_strain"] == pytest.approx(0.037, rel=1e-12)
    assert result["peak_internal_axial_strain"] == pytest.approx(0.004, rel=1e-12)
    sine = lambda r: (r - 1.0) / (r + 1.0)  # noqa: E731
    assert result["peak_external_friction_angle_deg"] == pytest.approx(
        math.degrees(math.asin(sine(4.0 + 0.5 * 0.037))), rel=1e-12
    )
    assert result["peak_internal_friction_angle_deg"] == pytest.approx(
        math.degrees(math.asin(sine(3.8))), rel=1e-12
    )
    records["internal_axial_stress"] = np.zeros(101)  # φ' undefined everywhere
    empty = analysis.peak(records)
    assert empty["peak_internal_index"] is None and np.isnan(empty["peak_internal_friction_angle_deg"])


def test_largest_overestimate_finds_the_planted_maximum_beyond_min_strain():
    records = make_records()
    derived = analysis.derived_quantities(records)
    internal_phi = derived["internal_friction_angle_deg"]
    difference = np.full(AXIAL.size, 0.5)
    difference[30] = 6.0  # at 0.18 % strain, excluded by min_strain = 0.03
    k = 167 + 50  # 4.5 % strain
    difference[k] = 3.7
    major_over_minor = (1.0 + np.sin(np.radians(internal_phi + difference))) / (
        1.0 - np.sin(np.radians(internal_phi + difference))
    )
    records["external_axial_stress"] = CELL * major_over_minor
    result = analysis.largest_overestimate(records, min_strain=0.03)
    assert result["overestimate_index"] == k
    assert result["overestimate_axial_strain"] == pytest.approx(0.045, rel=1e-12)
    assert result["overestimate_deg"] == pytest.approx(3.7, abs=1e-9)
    everywhere = analysis.largest_overestimate(records)
    assert everywhere["overestimate_index"] == 30
    assert everywhere["overestimate_deg"] == pytest.approx(6.0, abs=1e-9)
    beyond = analysis.largest_overestimate(records, min_strain=1.0)
    assert beyond["overestimate_index"] is None and np.isnan(beyond["overestimate_deg"])


def test_summary_table_puts_the_run_beside_the_paper():
    records = make_records()
    table = analysis.summary_table(records, paper=paper.PAPER_10KPA_5MM)
    rows = [line.split("|")[1:-1] for line in table.strip().splitlines()]
    assert [cell.strip() for cell in rows[0]] == ["Quantity", "This run", "Paper"]
    assert len(rows) == 2 + 10
    by_label = {cells[0].strip(): [cell.strip() for cell in cells[1:]] for cells in rows[2:]}
    assert by_label["Initial σ3 internal (kPa) [Table 3]"] == ["11.80", "11.80"]
    assert by_label["Initial σ1 internal (kPa) [Table 3]"][1] == "14.60"
    assert by_label["Peak φ' external (°) [Table 2]"][1] == "41.10"
    assert by_label["Peak φ' internal (°) [Table 2]"][1] == "40.20"
    assert by_label["Largest φ' external − internal (°) [Fig. 5]"][1] == "4.00"
    assert by_label["Axial strain of the largest difference (%) [Fig. 5]"][1] == "–"
    peak = analysis.peak(records)
    assert float(by_label["Peak φ' external (°) [Table 2]"][0]) == pytest.approx(
        peak["peak_external_friction_angle_deg"], abs=0.005
    )
    assert float(by_label["Axial strain at peak φ' external (%) [§5.2]"][0]) == pytest.approx(
        100.0 * peak["peak_external_axial_strain"], abs=0.005
    )
    plain = analysis.summary_table(records)
    assert plain.splitlines()[0] == "| Quantity | This run |"
    assert paper.PAPER_10KPA_5MM["sigma1_external_kpa"] == 10.7


# ---------------------------------------------------------------------------------------------------------
# Figures (membrax.plots)
# ---------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def records_and_derived():
    records = make_records()
    return records, analysis.derived_quantities(records)


def assert_line(line, x, y):
    np.testing.assert_allclose(line.get_xdata(), x, rtol=1e-14, atol=0.0)
    np.testing.assert_allclose(line.get_ydata(), y, rtol=1e-14, atol=1e-14)


def test_plot_friction_angles_draws_external_internal_and_love_weber(records_and_derived):
    records, derived = records_and_derived
    figure = plots.plot_friction_angles(records)
    assert isinstance(figure, Figure)
    (ax,) = figure.axes
    assert len(ax.lines) == 3
    x = AXIAL * 100.0
    assert_line(ax.lines[0], x, mohr_coulomb_deg(records["external_axial_stress"], CELL))
    assert_line(
        ax.lines[1], x, mohr_coulomb_deg(records["internal_axial_stress"], records["internal_radial_stress"])
    )
    assert_line(ax.lines[2], x, derived["love_weber_friction_angle_deg"])
    assert ax.lines[2].get_linewidth() < ax.lines[0].get_linewidth()


def test_plot_additional_stresses_in_kpa(records_and_derived):
    records, derived = records_and_derived
    figure = plots.plot_additional_stresses(records, derived)
    (ax,) = figure.axes
    assert len(ax.lines) == 2
    radial_kpa = (1.8e3 - 40e3 * records["radial_strain"]) / 1e3
    axial_kpa = (4.0e3 - 30e3 * AXIAL) / 1e3
    np.testing.assert_allclose(ax.lines[0].get_ydata(), radial_kpa, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ax.lines[1].get_ydata(), axial_kpa, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ax.lines[0].get_xdata(), AXIAL * 100.0, rtol=1e-14)


def test_plot_axial_ratio_and_strain_ratio_uses_twin_axes(records_and_derived):
    records, derived = records_and_derived
    figure = plots.plot_axial_ratio_and_strain_ratio(records)
    left, right = figure.axes
    assert len(left.lines) == 1 and len(right.lines) == 1
    x = AXIAL * 100.0
    assert_line(left.lines[0], x, records["internal_axial_stress"] / records["external_axial_stress"])
    assert_line(right.lines[0], x, derived["strain_ratio_change"])
    assert np.isfinite(derived["strain_ratio_change"]).all()


def test_plot_radial_ratio_and_radial_strain_in_percent(records_and_derived):
    records, _ = records_and_derived
    figure = plots.plot_radial_ratio_and_radial_strain(records)
    left, right = figure.axes
    x = AXIAL * 100.0
    assert_line(left.lines[0], x, records["internal_radial_stress"] / CELL)
    assert_line(right.lines[0], x, records["radial_strain"] * 100.0)
    assert right.lines[0].get_ydata()[-1] < 0.0  # bulging, compression positive


def test_save_test_figures_writes_four_pngs(tmp_path, records_and_derived):
    records, _ = records_and_derived
    paths = plots.save_test_figures(records, tmp_path / "figures")
    names = [path.name for path in paths]
    assert names == [
        "fig5_friction.png",
        "fig6_additional_stress.png",
        "fig7_axial_ratio.png",
        "fig8_radial_ratio.png",
    ]
    for path in paths:
        assert path.stat().st_size > 1000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(paths) == 4


def _window_slopes_by_loop(axial, radial, window):
    """The regression of each record's window, one window at a time (the definition, O(records × window))."""
    slope = np.full(axial.shape, np.nan)
    for i, x in enumerate(axial):
        near = np.isfinite(axial) & np.isfinite(radial) & (np.abs(axial - x) <= 0.5 * window)
        if near.sum() >= 3 and np.ptp(axial[near]) > 0.0 and np.isfinite(radial[i]):
            dx = axial[near] - axial[near].mean()
            slope[i] = np.dot(dx, radial[near] - radial[near].mean()) / np.dot(dx, dx)
    return slope


def test_the_sliding_window_equals_each_window_s_own_regression():
    """The O(records) update against the definition: the shipped example record, and a long irregular
    record with repeated strains, a gap wider than the window and a NaN; to 1e-12 of the slopes' scale."""
    from calibrate import evaluate

    record = evaluate.read_example_record()[0]
    rng = np.random.default_rng(7)
    axial = np.sort(np.concatenate([rng.uniform(0.0, 0.02, 3000), rng.uniform(0.03, 0.1, 2000)]))
    axial[100:110] = axial[100]  # a logger holding its value
    radial = -0.3 * axial + 2.0 * axial**2 + 1e-5 * rng.standard_normal(axial.size)
    radial[2500] = np.nan
    for x, y in ((record.axial_strain, record.radial_strain), (axial, radial)):
        for window in (0.002, 0.005):
            fast = analysis.strain_ratio_change(x, y, window=window)
            slow = _window_slopes_by_loop(np.asarray(x), np.asarray(y), window)
            np.testing.assert_array_equal(np.isfinite(fast), np.isfinite(slow))
            finite = np.isfinite(slow)
            scale = np.abs(slow[finite]).max()
            np.testing.assert_allclose(fast[finite], slow[finite], rtol=0.0, atol=1e-12 * scale)
