"""membrax.paper (the paper's Tables 2 and 3 and Fig. 9) against the printed tables and hand calculations.

No simulation: each case's records are four hand-made records (SI units, compression positive) whose
stresses scale with the cell pressure, so the peak φ' and the initial stresses are known in closed form.
"""

import csv
import math

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest
import xarray as xr
from matplotlib.figure import Figure

from membrax import paper, plots, sweep, theory
from membrax.config import TriaxialConfig

AXIAL = np.array([0.0, 0.01, 0.02, 0.03])
# Stresses over the cell pressure, per record: R_ext = 3, 4, 3.5, 3.2 and R_int = 3, 3.75, 50/13, 40/13.
EXTERNAL_AXIAL = np.array([3.0, 4.0, 3.5, 3.2])
INTERNAL_AXIAL = np.array([3.6, 4.5, 5.0, 4.0])
INTERNAL_RADIAL = np.array([1.2, 1.2, 1.3, 1.3])
# Peak φ' by hand, sin φ' = (R − 1)/(R + 1): external at R = 4, internal at R = 50/13.
PEAK_EXTERNAL_DEG = math.degrees(math.asin(3.0 / 5.0))  # 36.8699°
PEAK_INTERNAL_DEG = math.degrees(math.asin(37.0 / 63.0))  # (50/13 − 1)/(50/13 + 1) = 37/63, 35.966°


def make_records(pressure_kpa):
    """Records of one case at ``pressure_kpa``: the ratios above times the cell pressure, in Pa."""
    cell = pressure_kpa * 1e3
    return {
        "axial_strain": AXIAL,
        "radial_strain": -0.5 * AXIAL,
        "external_axial_stress": cell * EXTERNAL_AXIAL,
        "external_radial_stress": np.full(AXIAL.shape, cell),
        "internal_axial_stress": cell * INTERNAL_AXIAL,
        "internal_radial_stress": cell * INTERNAL_RADIAL,
    }


# Out of order on purpose; 10/3 mm is the paper's 3.33 mm case and 20 kPa is not in the paper's grid.
CASES = [(20.0, 5.0), (10.0, 5.0), (40.0, 2.5), (10.0, 10.0 / 3.0)]
ORDER = [(40.0, 2.5), (10.0, 10.0 / 3.0), (10.0, 5.0), (20.0, 5.0)]  # by thickness, then pressure


@pytest.fixture
def results():
    return {case: make_records(case[0]) for case in CASES}


# ---------------------------------------------------------------------------------------------------------
# The paper's numbers
# ---------------------------------------------------------------------------------------------------------


def test_paper_tables_cover_the_grid_and_match_the_printed_rows():
    grid = {(p, t) for p in (10.0, 40.0, 100.0) for t in (2.5, 3.33, 5.0)}
    assert set(paper.PAPER_TABLE_2) == grid and set(paper.PAPER_TABLE_3) == grid
    assert paper.PAPER_CELL_PRESSURES_KPA == (10.0, 40.0, 100.0)
    assert paper.PAPER_THICKNESSES_MM == (2.5, 3.33, 5.0)
    # Table 2 rows "10 2.5 | 40.3 40.0", "100 3.3 | 39.4 40.1", "40 5 | 40.2 40.2".
    for key, external, internal in [
        ((10.0, 2.5), 40.3, 40.0),
        ((100.0, 3.33), 39.4, 40.1),
        ((40.0, 5.0), 40.2, 40.2),
    ]:
        assert paper.PAPER_TABLE_2[key] == {
            "peak_external_friction_angle_deg": external,
            "peak_internal_friction_angle_deg": internal,
        }
    # Table 3 rows "100 2.5 | 100 109.4 101.1 117.7", "40 3.3 | 40 44.4 40.9 50.2",
    # "100 5.0 | 100 110.6 101.1 123.4" (σ3 ext, σ3 int, σ1 ext, σ1 int, kPa).
    for key, values in [
        ((100.0, 2.5), (100.0, 109.4, 101.1, 117.7)),
        ((40.0, 3.33), (40.0, 44.4, 40.9, 50.2)),
        ((100.0, 5.0), (100.0, 110.6, 101.1, 123.4)),
    ]:
        row = paper.PAPER_TABLE_3[key]
        assert (
            row["sigma3_external_kpa"],
            row["sigma3_internal_kpa"],
            row["sigma1_external_kpa"],
            row["sigma1_internal_kpa"],
        ) == values
    # The external σ3 is the cell pressure in every row of Table 3.
    assert all(row["sigma3_external_kpa"] == key[0] for key, row in paper.PAPER_TABLE_3.items())


def test_paper_10kpa_5mm_agrees_with_the_tables():
    case = {**paper.PAPER_TABLE_2[10.0, 5.0], **paper.PAPER_TABLE_3[10.0, 5.0]}
    assert case == {key: paper.PAPER_10KPA_5MM[key] for key in case}
    assert case["peak_external_friction_angle_deg"] == 41.1 and case["sigma1_internal_kpa"] == 14.6
    assert paper.PAPER_10KPA_5MM["overestimate_deg"] == 4.0  # §5.2: "by up to 4°"


def test_the_papers_fixed_parameters_are_the_configuration_defaults():
    """The paper's §3 and Table 1: 25 mm spheres, 10 across (a 250 mm specimen) and 25 layers, 25°
    interparticle friction, a 1400 kPa latex membrane; Table 1's grid is every sweep's default."""
    assert (paper.PARTICLE_DIAMETER_MM, paper.SPECIMEN_DIAMETER_MM) == (25.0, 250.0)
    assert (paper.MEMBRANE_MODULUS_KPA, paper.INTERPARTICLE_FRICTION_DEG) == (1400.0, 25.0)
    config = TriaxialConfig()
    assert (config.particles_across, config.layers) == (10, 25)
    assert config.particle_diameter_mm == paper.PARTICLE_DIAMETER_MM
    assert config.membrane_modulus_kpa == paper.MEMBRANE_MODULUS_KPA
    assert config.friction_angle_deg == config.membrane_friction_angle_deg == paper.INTERPARTICLE_FRICTION_DEG
    assert sweep.DEFAULT_GRID is paper.TABLE_1_GRID
    assert paper.TABLE_1_GRID == {
        "cell_pressure_kpa": paper.PAPER_CELL_PRESSURES_KPA,
        "membrane_thickness_mm": paper.PAPER_THICKNESSES_MM,
    }


def test_paper_key_matches_within_half_a_hundredth():
    assert paper.paper_key(10, 10 / 3) == (10.0, 3.33)
    assert paper.paper_key(100.004, 4.996) == (100.0, 5.0)
    assert paper.paper_key(20.0, 5.0) is None
    assert paper.paper_key(10.0, 3.34) is None


# ---------------------------------------------------------------------------------------------------------
# Tables 2 and 3
# ---------------------------------------------------------------------------------------------------------


def test_table_2_against_hand_calculation(results):
    rows = paper.table_2(results)
    assert [(row["cell_pressure_kpa"], row["membrane_thickness_mm"]) for row in rows] == ORDER
    assert list(rows[0]) == [
        "cell_pressure_kpa",
        "membrane_thickness_mm",
        "peak_external_friction_angle_deg",
        "paper_peak_external_friction_angle_deg",
        "difference_peak_external_friction_angle_deg",
        "peak_internal_friction_angle_deg",
        "paper_peak_internal_friction_angle_deg",
        "difference_peak_internal_friction_angle_deg",
    ]
    assert PEAK_EXTERNAL_DEG == pytest.approx(36.8699, abs=1e-4)
    # Paper's Table 2 for (40, 2.5), (10, 3.3), (10, 5); none for 20 kPa.
    paper_values = [(39.8, 40.3), (40.6, 40.1), (41.1, 40.2), (math.nan, math.nan)]
    for row, (external, internal) in zip(rows, paper_values, strict=True):
        assert row["peak_external_friction_angle_deg"] == pytest.approx(PEAK_EXTERNAL_DEG, abs=1e-9)
        assert row["peak_internal_friction_angle_deg"] == pytest.approx(PEAK_INTERNAL_DEG, abs=1e-9)
        np.testing.assert_array_equal(
            [row["paper_peak_external_friction_angle_deg"], row["paper_peak_internal_friction_angle_deg"]],
            [external, internal],
        )
        np.testing.assert_allclose(
            [
                row["difference_peak_external_friction_angle_deg"],
                row["difference_peak_internal_friction_angle_deg"],
            ],
            [PEAK_EXTERNAL_DEG - external, PEAK_INTERNAL_DEG - internal],
            rtol=0.0,
            atol=1e-9,
        )
    assert rows[2]["difference_peak_external_friction_angle_deg"] == pytest.approx(36.8699 - 41.1, abs=1e-4)


def test_table_3_against_hand_calculation(results):
    rows = paper.table_3(results)
    assert [(row["cell_pressure_kpa"], row["membrane_thickness_mm"]) for row in rows] == ORDER
    names = [
        "sigma3_external_kpa",
        "sigma3_internal_kpa",
        "sigma1_external_kpa",
        "sigma1_internal_kpa",
        "additional_sigma3_kpa",
        "additional_sigma1_kpa",
    ]
    assert list(rows[0]) == ["cell_pressure_kpa", "membrane_thickness_mm"] + [
        f"{prefix}{name}" for name in names for prefix in ("", "paper_", "difference_")
    ]
    for row in rows:
        p = row["cell_pressure_kpa"]
        # First record: σ3 = p, 1.2 p; σ1 = 3 p, 3.6 p; Δσ3 = 0.2 p, Δσ1 = 0.6 p (kPa).
        np.testing.assert_allclose(
            [row[name] for name in names], [p, 1.2 * p, 3.0 * p, 3.6 * p, 0.2 * p, 0.6 * p], rtol=1e-12
        )
    # 10 kPa, 5 mm against the paper's row "10 5.0 | 10 11.8 10.7 14.6".
    row = rows[2]
    paper_row = [10.0, 11.8, 10.7, 14.6, 11.8 - 10.0, 14.6 - 10.7]
    np.testing.assert_allclose([row[f"paper_{name}"] for name in names], paper_row, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(
        [row[f"difference_{name}"] for name in names],
        [10.0 - 10.0, 12.0 - 11.8, 30.0 - 10.7, 36.0 - 14.6, 2.0 - 1.8, 6.0 - 3.9],
        rtol=0.0,
        atol=1e-9,
    )
    # 10 kPa and 10/3 mm is the paper's "10 3.3 | 10 11.5 10.9 13.9" row; 20 kPa is not in the paper.
    assert rows[1]["paper_sigma1_internal_kpa"] == 13.9
    assert rows[1]["paper_additional_sigma1_kpa"] == pytest.approx(3.0, abs=1e-12)
    assert all(
        math.isnan(rows[3][f"{prefix}{name}"]) for name in names for prefix in ("paper_", "difference_")
    )


def test_table_3_through_the_boundary_sphere_centres_scales_sigma3_by_r_over_r_minus_R(results):
    """σ3,c = σ3,int r/(r − R), r = √(A/π): with A = π (0.125 m)² and R = 0.0125 m the factor is 10/9, so
    Δσ3 = 1.2 p · 10/9 − p = p/3 in every case; the paper's column is its Δσ3."""
    area = math.pi * 0.125**2
    with_area = {
        key: {**records, "platen_area": np.full(AXIAL.shape, area)} for key, records in results.items()
    }
    rows = paper.table_3(with_area, particle_radius=0.0125)
    name = "additional_sigma3_centres_kpa"
    assert list(rows[0])[-3:] == [name, f"paper_{name}", f"difference_{name}"]
    for row in rows:
        assert row[name] == pytest.approx(row["cell_pressure_kpa"] / 3.0, rel=1e-12)
        assert row[f"paper_{name}"] == row["paper_additional_sigma3_kpa"] or math.isnan(row[f"paper_{name}"])
    assert rows[2][f"paper_{name}"] == pytest.approx(11.8 - 10.0, abs=1e-12)
    assert list(paper.table_3(with_area)[0]) == list(paper.table_3(results)[0])  # no radius, no column
    with pytest.raises(ValueError, match="particle_radius"):
        paper.table_3(with_area, particle_radius=0.2)


def test_tables_read_an_xarray_dataset_like_a_dict(results):
    datasets = {
        key: xr.Dataset({name: ("record", values) for name, values in records.items()})
        for key, records in results.items()
    }
    for from_dataset, from_dict in zip(paper.table_2(datasets), paper.table_2(results), strict=True):
        assert list(from_dataset) == list(from_dict)
        np.testing.assert_array_equal(list(from_dataset.values()), list(from_dict.values()))
    rows = paper.table_3(datasets)
    assert rows[0]["sigma1_internal_kpa"] == pytest.approx(3.6 * 40.0, rel=1e-12)


def test_write_tables_csv_reads_back_and_markdown_has_one_row_per_case(results, tmp_path):
    folder = tmp_path / "new" / "tables"
    paths = paper.write_tables(results, folder)
    assert set(paths) == {"table2.csv", "table2.md", "table3.csv", "table3.md"}
    for number, rows in (("2", paper.table_2(results)), ("3", paper.table_3(results))):
        with open(paths[f"table{number}.csv"], newline="") as handle:
            read = list(csv.DictReader(handle))
        assert list(read[0]) == list(rows[0])
        np.testing.assert_array_equal(
            [[float(value) for value in line.values()] for line in read],
            [list(row.values()) for row in rows],
        )
        loaded = np.loadtxt(paths[f"table{number}.csv"], delimiter=",", skiprows=1)
        assert loaded.shape == (len(CASES), len(rows[0]))
        assert loaded[2, 0] == 10.0 and loaded[2, 1] == 5.0

        markdown = paths[f"table{number}.md"].read_text().splitlines()
        table = [line for line in markdown if line.startswith("|")]
        assert len(table) == 2 + len(CASES)  # header, separator, one row per case
        cells = [cell.strip() for cell in table[-1].strip("|").split("|")]
        assert len(cells) == len(rows[0])
        assert cells[:2] == ["20.00", "5.00"] and "–" in cells  # 20 kPa: no paper value
    table2 = paths["table2.md"].read_text()
    assert "| 10.00 | 5.00 | 36.87 | 41.10 | -4.23 | 35.97 | 40.20 | -4.23 |" in table2
    assert "Peak φ' external (°)" in table2
    table3 = paths["table3.md"].read_text()
    assert "| 10.00 | 3.33 | 10.00 | 10.00 | 0.00 | 12.00 | 11.50 | 0.50 |" in table3


def test_write_tables_refuses_a_file_as_folder(results, tmp_path):
    target = tmp_path / "table.txt"
    target.write_text("x")
    with pytest.raises(ValueError, match="not a directory"):
        paper.write_tables(results, target)
    assert target.read_text() == "x"


# ---------------------------------------------------------------------------------------------------------
# Fig. 9
# ---------------------------------------------------------------------------------------------------------


def test_fig9_data_indentation_is_the_theory_and_stress_ratio_by_hand(results):
    data = paper.fig9_data(results)
    assert list(data) == [2.5, 10.0 / 3.0, 5.0]
    np.testing.assert_array_equal(data[5.0]["cell_pressure_kpa"], [10.0, 20.0])
    for thickness, series in data.items():
        expected = theory.molenkamp_luger_indentation_ratio(
            theory.FCC_VOID_RATIO, 25.0, thickness, series["cell_pressure_kpa"], 1400.0, 0.275
        )
        np.testing.assert_allclose(series["indentation_ratio"], expected, rtol=1e-12)
        # −(σ1,int/σ1,ext − 1) at the first record = −(3.6/3 − 1).
        np.testing.assert_allclose(
            series["negative_relative_axial_stress_ratio"], -(3.6 / 3.0 - 1.0), rtol=1e-12
        )
    # Eq. 2 by hand at 10 kPa, 5 mm: C (1 + e)^(4/9) (D/t_m)^(1/3) (σ'/E_m)^(1/3), FCC e = 1/(π/(3√2)) − 1.
    e = 3.0 * math.sqrt(2.0) / math.pi - 1.0
    by_hand = 0.275 * (1.0 + e) ** (4.0 / 9.0) * (25.0 / 5.0) ** (1.0 / 3.0) * (10.0 / 1400.0) ** (1.0 / 3.0)
    assert data[5.0]["indentation_ratio"][0] == pytest.approx(by_hand, rel=1e-12)
    assert by_hand == pytest.approx(0.1035, abs=1e-4)  # `membrax theory` prints 0.1035* for 10 kPa, 5 mm
    assert not data[5.0]["indentation_ratio_valid"][0]  # α/D < 0.2: outside Molenkamp & Luger's range
    # Another sphere diameter and modulus: α/D ∝ (D/E_m)^(1/3) at fixed t_m and σc.
    other = paper.fig9_data(results, particle_diameter_mm=12.5, membrane_modulus_kpa=2800.0)
    np.testing.assert_allclose(
        other[5.0]["indentation_ratio"], data[5.0]["indentation_ratio"] / 4.0 ** (1 / 3)
    )
    # C scales α/D linearly.
    np.testing.assert_allclose(
        paper.fig9_data(results, c=0.4)[5.0]["indentation_ratio"],
        data[5.0]["indentation_ratio"] * 0.4 / 0.275,
    )


def test_paper_fig9_data_from_table_3():
    data = paper.paper_fig9_data()
    assert list(data) == [2.5, 3.33, 5.0]
    np.testing.assert_array_equal(data[5.0]["cell_pressure_kpa"], [10.0, 40.0, 100.0])
    # Table 3, 5 mm: σ1 ext/int 10.7/14.6, 41.0/52.1, 101.1/123.4 kPa.
    np.testing.assert_allclose(
        data[5.0]["negative_relative_axial_stress_ratio"],
        [-(14.6 / 10.7 - 1.0), -(52.1 / 41.0 - 1.0), -(123.4 / 101.1 - 1.0)],
        rtol=1e-12,
    )
    assert data[5.0]["negative_relative_axial_stress_ratio"][0] == pytest.approx(-0.3645, abs=1e-4)
    # The paper's bullets: at 10 kPa the thickest membrane has the lowest α/D and the greatest stress ratio
    # (Table 3: 13.5/10.6, 13.9/10.9, 14.6/10.7).
    at_10 = [data[t]["negative_relative_axial_stress_ratio"][0] for t in (2.5, 3.33, 5.0)]
    np.testing.assert_allclose(at_10, [-(13.5 / 10.6 - 1.0), -(13.9 / 10.9 - 1.0), -(14.6 / 10.7 - 1.0)])
    assert at_10[2] < min(at_10[:2])
    indentation_at_10 = [data[t]["indentation_ratio"][0] for t in (2.5, 3.33, 5.0)]
    assert indentation_at_10 == sorted(indentation_at_10, reverse=True)
    # α/D ∝ σ'^(1/3): 40 and 100 kPa give (4)^(1/3) and (10)^(1/3) times the 10 kPa value.
    np.testing.assert_allclose(
        data[2.5]["indentation_ratio"] / data[2.5]["indentation_ratio"][0],
        np.cbrt([1.0, 4.0, 10.0]),
        rtol=1e-12,
    )


def test_plot_fig9_draws_three_thicknesses_by_three_pressures():
    ours = paper.paper_fig9_data()  # paper-shaped data stands for ours: 3 thicknesses × 3 pressures
    reference = paper.paper_fig9_data()
    figure = plots.plot_fig9(ours, paper=reference)
    assert isinstance(figure, Figure)
    ax, twin = figure.axes
    assert len(ax.lines) == 3 and len(twin.lines) == 6
    for k, thickness in enumerate((2.5, 3.33, 5.0)):
        np.testing.assert_array_equal(ax.lines[k].get_xdata(), [10.0, 40.0, 100.0])
        np.testing.assert_allclose(ax.lines[k].get_ydata(), ours[thickness]["indentation_ratio"])
        for line in (twin.lines[k], twin.lines[3 + k]):
            np.testing.assert_allclose(
                line.get_ydata(), reference[thickness]["negative_relative_axial_stress_ratio"]
            )
        assert twin.lines[k].get_markerfacecolor() == "none"  # ours open
        assert twin.lines[3 + k].get_markerfacecolor() != "none"  # paper filled
    assert twin.lines[2].get_ydata()[0] == pytest.approx(-(14.6 / 10.7 - 1.0), rel=1e-12)
    assert ax.get_xscale() == "log"
    assert sum(len(line.get_xdata()) for line in ax.lines + twin.lines) == 2 * 3 * 3 + 3 * 3
    assert len(plots.plot_fig9(ours).axes[1].lines) == 3  # without the paper


def test_save_fig9_writes_a_png(results, tmp_path):
    path = plots.save_fig9(paper.fig9_data(results), tmp_path / "figs", paper=paper.paper_fig9_data())
    assert path == tmp_path / "figs" / "fig9_indentation.png"
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


# ---------------------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("results", "match"),
    [
        ({}, "results is empty"),
        ([((10.0, 5.0), None)], "results is a list"),
        ({10.0: make_records(10.0)}, "not a \\(cell_pressure_kpa, membrane_thickness_mm\\) pair"),
        ({(10.0, 5.0, 1.0): make_records(10.0)}, "not a \\(cell_pressure_kpa"),
        ({"10,5": make_records(10.0)}, "not a \\(cell_pressure_kpa"),
        ({("10", 5.0): make_records(10.0)}, "cell_pressure_kpa '10' is not a number"),
        ({(10.0, True): make_records(10.0)}, "membrane_thickness_mm True is not a number"),
        ({(-10.0, 5.0): make_records(10.0)}, "cell_pressure_kpa = -10.0 is not a positive finite"),
        ({(10.0, math.nan): make_records(10.0)}, "membrane_thickness_mm = nan is not a positive finite"),
        ({(10.0, math.inf): make_records(10.0)}, "membrane_thickness_mm = inf"),
        ({(10.0, 5.0): [1.0, 2.0]}, "results\\[\\(10, 5\\)\\] is a list"),
    ],
)
def test_bad_results_raise(results, match):
    for function in (paper.table_2, paper.table_3, paper.fig9_data):
        with pytest.raises(ValueError, match=match):
            function(results)


def test_missing_or_empty_series_raise(tmp_path):
    records = make_records(10.0)
    del records["internal_axial_stress"]
    with pytest.raises(ValueError, match="results\\[\\(10, 5\\)\\] has no series 'internal_axial_stress'"):
        paper.table_2({(10.0, 5.0): records})
    empty = {name: np.zeros(0) for name in paper.REQUIRED_SERIES}
    with pytest.raises(ValueError, match="at least one"):
        paper.table_3({(10.0, 5.0): empty})
    short = make_records(10.0)
    short["axial_strain"] = AXIAL[:2]
    with pytest.raises(ValueError, match="the same number"):
        paper.fig9_data({(40.0, 2.5): make_records(40.0), (10.0, 5.0): short})
    with pytest.raises(ValueError, match="results is empty"):
        paper.write_tables({}, tmp_path)
    assert list(tmp_path.iterdir()) == []  # nothing written
    assert len(paper.REQUIRED_SERIES) == 5


# ---------------------------------------------------------------------------------------------------------
# Tables over several specimens per case (random packings)
# ---------------------------------------------------------------------------------------------------------


def _scaled_peak(records, factor):
    """The records with the external axial stress scaled by ``factor`` (a different specimen)."""
    return {**records, "external_axial_stress": factor * records["external_axial_stress"]}


def test_spread_tables_give_mean_sd_min_max_over_specimens_by_hand(tmp_path):
    # Three specimens of two cases: the external peak ratio R = 4 f for f = 1, 1.1, 1.25, so φ'_ext peak
    # = asin((4f − 1)/(4f + 1)); the initial σ1,ext = 3 f σc.
    factors = (1.0, 1.1, 1.25)
    cases = [(10.0, 5.0), (40.0, 2.5)]
    by_seed = {
        seed: {case: _scaled_peak(make_records(case[0]), f) for case in cases}
        for seed, f in enumerate(factors)
    }
    reference = {(10.0, 5.0): make_records(10.0)}  # a lattice with f = 1 for one case only
    tables = paper.spread_tables(by_seed, reference=reference)
    peaks = np.degrees(np.arcsin([(4 * f - 1) / (4 * f + 1) for f in factors]))
    mean = peaks.sum() / 3
    sd = math.sqrt(((peaks - mean) ** 2).sum() / 2)
    rows = tables["table2"]
    assert [(r["cell_pressure_kpa"], r["membrane_thickness_mm"]) for r in rows] == [(40.0, 2.5), (10.0, 5.0)]
    for row in rows:
        assert row["specimens"] == 3
        assert row["peak_external_friction_angle_deg_mean"] == pytest.approx(mean, abs=1e-12)
        assert row["peak_external_friction_angle_deg_sd"] == pytest.approx(sd, abs=1e-12)
        assert row["peak_external_friction_angle_deg_min"] == pytest.approx(peaks[0], abs=1e-12)
        assert row["peak_external_friction_angle_deg_max"] == pytest.approx(peaks[2], abs=1e-12)
        # The internal stresses are the same in every specimen: no spread.
        assert row["peak_internal_friction_angle_deg_sd"] == 0.0
    assert rows[1]["reference_peak_external_friction_angle_deg"] == pytest.approx(
        PEAK_EXTERNAL_DEG, abs=1e-12
    )
    assert math.isnan(rows[0]["reference_peak_external_friction_angle_deg"])
    assert rows[1]["paper_peak_external_friction_angle_deg"] == 41.1  # the paper's (10, 5)
    sigma1 = [3.0 * f * 10.0 for f in factors]  # kPa
    row3 = tables["table3"][1]
    assert row3["sigma1_external_kpa_mean"] == pytest.approx(np.mean(sigma1), abs=1e-9)
    assert row3["sigma1_external_kpa_sd"] == pytest.approx(np.std(sigma1, ddof=1), abs=1e-9)
    # Δσ1 = σ1,int − σ1,ext = (3.6 − 3 f) σc per specimen.
    assert row3["additional_sigma1_kpa_min"] == pytest.approx((3.6 - 3.0 * 1.25) * 10.0, abs=1e-9)
    paths = paper.write_spread_tables(by_seed, tmp_path, reference=reference)
    with open(paths["random_table2.csv"]) as handle:
        read = list(csv.DictReader(handle))
    assert float(read[1]["peak_external_friction_angle_deg_sd"]) == pytest.approx(sd, abs=1e-12)
    markdown = paths["random_table2.md"].read_text()
    assert f"{mean:.2f} ± {sd:.2f} ({peaks[0]:.2f}…{peaks[2]:.2f})" in markdown


def test_spread_tables_of_one_specimen_have_no_sd_and_an_empty_mapping_is_refused():
    tables = paper.spread_tables({0: {(10.0, 5.0): make_records(10.0)}})
    row = tables["table2"][0]
    assert row["specimens"] == 1 and math.isnan(row["peak_external_friction_angle_deg_sd"])
    assert row["peak_external_friction_angle_deg_mean"] == pytest.approx(PEAK_EXTERNAL_DEG, abs=1e-12)
    with pytest.raises(ValueError, match="specimen label"):
        paper.spread_tables({})
