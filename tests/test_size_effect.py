"""The size effect a report quotes (calibrate.size_effect) against hand calculations on a small table.

Each test checks numbers by hand: the specimen part is internal − element per σc, averaged over the
membranes; between two diameter ratios it is linear in D/D_s; outside the table's ratios nothing is
extrapolated; the shipped table's own rows give back their differences.
"""

import pytest

from calibrate.size_effect import boundary_split_rows, size_effect_lines, size_effect_note, size_effects


def _row(cell, ratio, pressure, peak, late, thickness=""):
    key = "lw" if cell == "periodic" else "int"
    return {
        "state": "dense",
        "cell": cell,
        "d_over_ds": str(ratio),
        "pressure_kpa": str(pressure),
        "thickness_mm": str(thickness),
        f"peak_{key}": str(peak),
        f"late_{key}": str(late),
    }


ROWS = [
    _row("periodic", 0, 10, 28.0, 22.0),
    _row("periodic", 0, 100, 27.0, 23.0),
    _row("membrane", 6, 10, 32.0, 30.0, 2),
    _row("membrane", 6, 10, 34.0, 30.0, 5),  # mean over the membranes: 33 → +5 at the peak
    _row("membrane", 6, 100, 29.0, 26.0, 2),
    _row("membrane", 12, 10, 30.0, 25.0, 2),
    _row("membrane", 12, 100, 28.0, 24.0, 2),
    _row("membrane", 8, 40, 30.0, 25.0, 2),  # no element at 40 kPa: left out
]


def test_the_specimen_part_is_internal_minus_element_averaged_over_membranes():
    effects = size_effects("dense", ROWS)
    assert [e.diameter_ratio for e in effects] == [6.0, 12.0]
    six, twelve = effects
    assert six.cell_pressures_kpa == (10.0, 100.0)
    assert six.peak_deg == pytest.approx((5.0, 2.0))  # (32 + 34)/2 − 28; 29 − 27
    assert six.late_deg == pytest.approx((8.0, 3.0))
    assert twelve.peak_deg == pytest.approx((2.0, 1.0))
    assert size_effects("loose", ROWS) == []


def test_between_ratios_the_note_is_linear_in_the_boundary_share_and_outside_it_says_none():
    # D_s/D = 8: D/D_s = 1/8 lies (1/6 − 1/8)/(1/6 − 1/12) = 1/2 of the way from 6 to 12.
    note = size_effect_note(8.0, "dense", ROWS)
    assert "+1.5 to +3.5° from the boundary-free element's at the peak" in note  # (2+1)/2, (5+2)/2
    assert "+2.0 to +5.5° late" in note  # (1+3)/2, (3+8)/2
    assert "σc 10–100 kPa" in note
    exact = size_effect_note(6.0, "dense", ROWS)
    assert "+2.0 to +5.0° from" in exact
    assert "none simulated at D_s/D = 20" in size_effect_note(20.0, "dense", ROWS)
    assert "no loose rows" in size_effect_note(8.0, "loose", ROWS)


def test_the_shipped_table_gives_back_its_own_differences():
    rows = boundary_split_rows()
    element = {
        float(r["pressure_kpa"]): float(r["peak_lw"])
        for r in rows
        if r["state"] == "dense" and r["cell"] == "periodic"
    }
    membrane = [
        r for r in rows if r["state"] == "dense" and r["cell"] == "membrane" and float(r["d_over_ds"]) == 6
    ]
    assert element and membrane
    effect = next(e for e in size_effects("dense") if e.diameter_ratio == 6.0)
    for pressure, part in zip(effect.cell_pressures_kpa, effect.peak_deg, strict=True):
        internal = [float(r["peak_int"]) for r in membrane if float(r["pressure_kpa"]) == pressure]
        assert part == pytest.approx(sum(internal) / len(internal) - element[pressure], abs=1e-9)


def test_the_report_quotes_every_state_with_an_element_dense_first():
    lines = size_effect_lines(8.0, ROWS)
    assert len(lines) == 1 and lines[0] == size_effect_note(8.0, "dense", ROWS)
    loose = [{**row, "state": "loose"} for row in ROWS]
    both = size_effect_lines(8.0, ROWS + loose)
    assert [line.split(",")[1].strip() for line in both] == ["dense", "loose"]


def test_the_shipped_ballast_rows_sit_at_the_ratio_membrax_correct_computes():
    """The ballast group's D is its d50 (the particle size ``membrax correct`` takes), not its largest sieve.

    By hand: the g6 mould is 150 mm and the grading's d50 is 16.14 mm (``characteristic_size_mm``), so
    D_s/D = 9.295 (6 largest sieves of 25 mm across). The shipped example record (a g6 member: 150.5 mm
    after consolidation, d50 16.14 mm, D_s/D = 9.325, 0.3 % above the mould's) is quoted the ballast rows'
    own internal − element peak φ', averaged over the membranes, at each σc.
    """
    from calibrate.designs import LAB_CALIBRATION, specimen_fields
    from membrax.config import TriaxialConfig, characteristic_size_mm, config_to_dict

    g6 = config_to_dict(TriaxialConfig(**specimen_fields(LAB_CALIBRATION["g6_s0"][0])))
    ratio = g6["specimen_diameter_mm"] / characteristic_size_mm(g6)
    assert ratio == pytest.approx(150.0 / 16.1376, rel=1e-4)
    rows = [r for r in boundary_split_rows() if r["state"] == "ballast"]
    membrane = [r for r in rows if r["cell"] == "membrane"]
    assert membrane and all(float(r["d_over_ds"]) == pytest.approx(ratio, abs=1e-4) for r in membrane)
    element = {float(r["pressure_kpa"]): float(r["peak_lw"]) for r in rows if r["cell"] == "periodic"}
    parts = []
    for pressure, peak in element.items():
        internal = [float(r["peak_int"]) for r in membrane if float(r["pressure_kpa"]) == pressure]
        parts.append(sum(internal) / len(internal) - peak)
    note = next(line for line in size_effect_lines(150.5 / 16.14) if "ballast" in line)
    assert f"{min(parts):+.1f} to {max(parts):+.1f}° from the boundary-free element's at the peak" in note
    assert "at D_s/D = 9.32" in note


def test_a_ratio_within_the_nominal_tolerance_of_the_table_s_end_takes_the_end_and_beyond_it_none():
    from calibrate.size_effect import NOMINAL_DIAMETER_TOLERANCE

    inside = 12.0 * (1.0 + 0.9 * NOMINAL_DIAMETER_TOLERANCE)
    assert "+1.0 to +2.0° from" in size_effect_note(inside, "dense", ROWS)  # the D_s/D = 12 rows
    assert "none simulated" in size_effect_note(
        12.0 * (1.0 + 1.1 * NOMINAL_DIAMETER_TOLERANCE), "dense", ROWS
    )
    assert "none simulated" in size_effect_note(6.0 * (1.0 - 1.1 * NOMINAL_DIAMETER_TOLERANCE), "dense", ROWS)
    assert "+2.0 to +5.0° from" in size_effect_note(
        6.0 * (1.0 - 0.9 * NOMINAL_DIAMETER_TOLERANCE), "dense", ROWS
    )
