"""calibrate.series: a series corrected at once, its envelopes against hand values, its sheet and files."""

import math

import numpy as np
import pytest

from calibrate import evaluate, series

COHESION, FRICTION = 5e3, 40.0  # the synthetic series' envelope: c' = 5 kPa, φ' = 40°
PRESSURES = (25e3, 50e3, 100e3)


def _failure_stress(cell_pressure):
    """σ1 at failure on c', φ': σ1 = σ3 (1 + sin φ)/(1 − sin φ) + 2 c cos φ/(1 − sin φ)."""
    sine = math.sin(math.radians(FRICTION))
    return cell_pressure * (1 + sine) / (1 - sine) + 2 * COHESION * math.cos(math.radians(FRICTION)) / (
        1 - sine
    )


def _write_record(path, cell_pressure):
    """A drained record whose deviator peaks at 5 % strain on the envelope, then softens by 10 %."""
    strain = np.linspace(0.0, 0.10, 101)
    peak = _failure_stress(cell_pressure) - cell_pressure
    deviator = np.where(
        strain <= 0.05, peak * np.sin(np.pi * strain / 0.10), peak * (1 - 2 * (strain - 0.05))
    )
    volumetric = 0.3 * strain - 4.0 * strain**2
    return evaluate.write_lab_csv(path, strain, volumetric, deviator, cell_pressure, fmt="%.12g")


def _sheet(tmp_path, extra=""):
    for pressure in PRESSURES:
        _write_record(tmp_path / f"t{pressure / 1e3:g}.csv", pressure)
    text = (
        "specimen_diameter_mm = 150\nparticle_size_mm = 16\nmembrane_thickness_mm = 4\n"
        "membrane_modulus_kpa = 2000\n" + extra
    )
    for pressure in PRESSURES:
        text += f'\n[[test]]\nrecord = "t{pressure / 1e3:g}.csv"\n'
    path = tmp_path / "series.toml"
    path.write_text(text)
    return path


def test_the_uncorrected_envelope_of_three_records_on_a_known_line_is_that_line(tmp_path):
    """c' = 5 kPa, φ' = 40° recovered to 1e-6 from the peaks; their secant φ' against σ3 fitted by hand."""
    result = series.correct_series(series.read_series_sheet(_sheet(tmp_path)))
    line = result.envelopes["uncorrected"]
    assert line.friction_angle == pytest.approx(FRICTION, abs=1e-6)
    assert line.cohesion == pytest.approx(COHESION, rel=1e-6)
    assert line.points == 3 and line.cohesion_std == pytest.approx(0.0, abs=1e-6)
    peaks = result.peaks["uncorrected"]
    np.testing.assert_allclose(peaks[:, 0], [_failure_stress(p) for p in PRESSURES], rtol=1e-9)
    np.testing.assert_allclose(peaks[:, 1], PRESSURES, rtol=1e-12)
    # the curved envelope: φ'_s = arcsin((σ1 − σ3)/(σ1 + σ3)) on log10(σ3/p_a), a straight line by numpy
    secant = np.degrees(np.arcsin((peaks[:, 0] - peaks[:, 1]) / (peaks[:, 0] + peaks[:, 1])))
    slope, intercept = np.polyfit(np.log10(np.array(PRESSURES) / series.ATMOSPHERIC_PRESSURE), secant, 1)
    curve = result.curved["uncorrected"]
    assert curve.phi0 == pytest.approx(intercept, abs=1e-9) and curve.delta_phi == pytest.approx(
        -slope, abs=1e-9
    )
    assert curve.delta_phi > 0.0  # a cohesion makes the secant angle fall with pressure
    # φ' at 5 % is the peak; the corrections lower (classical) or shift (fitted) every peak
    np.testing.assert_allclose(result.at_strains["uncorrected"][:, 2], peaks[:, 2], atol=1e-9)
    for method in ("astm", "henkel_gilbert", "kuerbis_vaid"):
        assert np.all(result.peaks[method][:, 2] < peaks[:, 2] + 1e-9), method


def test_the_envelope_s_standard_errors_are_the_regression_s_by_the_delta_method():
    """Three scattered peaks: the errors equal a numerical Jacobian of (a, m) → (c', φ') on the covariance."""
    sigma_3 = np.array([20e3, 50e3, 90e3])
    sigma_1 = np.array([105e3, 235e3, 430e3])
    line = series.mohr_coulomb_envelope(sigma_1, sigma_3)
    s, t = (sigma_1 + sigma_3) / 2, (sigma_1 - sigma_3) / 2
    design = np.stack([np.ones(3), s], 1)
    theta = np.linalg.solve(design.T @ design, design.T @ t)
    residual = t - design @ theta
    covariance = residual @ residual / 1 * np.linalg.inv(design.T @ design)

    def transform(a, m):
        return np.array([a / math.sqrt(1 - m * m), math.degrees(math.asin(m))])

    steps = (1.0, 1e-7)
    jacobian = np.stack(
        [
            (transform(*(theta + h * e)) - transform(*(theta - h * e))) / (2 * h)
            for h, e in zip(steps, np.eye(2), strict=True)
        ],
        axis=1,
    )
    expected = np.sqrt(np.diag(jacobian @ covariance @ jacobian.T))
    assert (line.cohesion, line.friction_angle) == pytest.approx(tuple(transform(*theta)), rel=1e-12)
    assert (line.cohesion_std, line.friction_angle_std) == pytest.approx(tuple(expected), rel=1e-5)
    two = series.mohr_coulomb_envelope(sigma_1[:2], sigma_3[:2])
    assert math.isfinite(two.friction_angle) and math.isnan(two.friction_angle_std)  # no degrees of freedom
    assert math.isnan(series.mohr_coulomb_envelope(sigma_1[:1], sigma_3[:1]).cohesion)


def test_a_series_sheet_is_read_with_shared_and_own_fields_and_refused_with_the_fix(tmp_path):
    path = _sheet(tmp_path, extra="void_ratio = 0.7\n")
    text = path.read_text().replace(
        'record = "t100.csv"\n', 'record = "t100.csv"\nmembrane_thickness_mm = 2\n'
    )
    path.write_text(text)
    tests = series.read_series_sheet(path)
    assert [t.name for t in tests] == ["t25", "t50", "t100"]
    assert [t.specimen.membrane_thickness for t in tests] == [4e-3, 4e-3, 2e-3]
    assert tests[0].specimen.solid_fraction == pytest.approx(1 / 1.7)
    assert tests[0].record == (tmp_path / "t25.csv").resolve()
    for bad, words in (
        ("particle_size = 16\n", "unknown key(s) ['particle_size']"),
        ('[[test]]\nrecord = "missing.csv"\n', "no record at"),
        ("[[test]]\nsheet = 1\n", "no record; give record"),
        ("membrane_modulus_kpa = 2\n", "membrane_modulus_kpa"),
    ):
        broken = tmp_path / "broken.toml"
        base = path.read_text()
        if bad.startswith("membrane_modulus_kpa"):
            base = base.replace("membrane_modulus_kpa = 2000\n", "")
            bad = '[[test]]\nrecord = "t25.csv"\nmembrane_modulus_kpa = 2\n'
        broken.write_text(bad + base if not bad.startswith("[[") else base + "\n" + bad)
        with pytest.raises(
            (ValueError, FileNotFoundError),
            match=words.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]"),
        ):
            series.read_series_sheet(broken)
    (tmp_path / "bad.toml").write_text("specimen_diameter_mm = = 3\n")
    with pytest.raises(ValueError, match="line 1"):
        series.read_series_sheet(tmp_path / "bad.toml")


def test_membrax_correct_writes_a_series_report_whose_numbers_are_the_series(tmp_path, capsys):
    from membrax import cli

    path = _sheet(tmp_path)
    out = tmp_path / "report"
    assert cli.main(["correct", "--series", str(path), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "c' 5.0 kPa, φ' 40.00°" in printed
    envelopes = np.genfromtxt(out / "envelopes.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    row = envelopes[envelopes["method"] == "uncorrected"][0]
    assert row["cohesion_kPa"] == pytest.approx(5.0, rel=1e-5) and row["friction_angle_deg"] == pytest.approx(
        40.0
    )
    html = (out / "series.html").read_text()
    assert '<img id="figure"' in html and "data:image/png;base64," in html and "t25" in html
    assert (out / "series.png").stat().st_size > 20_000
    assert sorted(p.name for p in out.glob("*_corrected.csv")) == [
        "t100_corrected.csv",
        "t25_corrected.csv",
        "t50_corrected.csv",
    ]
    # the same files given on the command line with shared options make the same envelope
    argv = [
        "correct",
        *(str(tmp_path / f"t{p / 1e3:g}.csv") for p in PRESSURES),
        "--out",
        str(tmp_path / "files"),
    ]
    argv += ["--specimen-diameter-mm", "150", "--particle-size-mm", "16", "--membrane-thickness-mm", "4"]
    assert cli.main([*argv, "--membrane-modulus-kpa", "2000"]) == 0
    capsys.readouterr()
    assert (tmp_path / "files" / "envelopes.csv").read_text() == (out / "envelopes.csv").read_text()


def test_on_the_shipped_example_series_the_membrane_s_apparent_cohesion_is_removed_in_part():
    """The example series' internal stresses (the records' extra columns: σ1 and the received σ3, the
    shipped correction's target) carry c' 0.6 ± 0.3 kPa; the external ones, uncorrected, 2.8 kPa: the
    membrane's apparent cohesion, beyond the internal envelope's scatter. Every correction brings c' toward
    the internal one."""
    from importlib import resources
    from pathlib import Path

    from calibrate import evaluate

    folder = Path(str(resources.files("calibrate") / "data" / "example_series"))
    result = series.correct_series(series.read_series_sheet(folder / "series.toml"))
    peaks = []
    for test in result.tests:
        columns = evaluate.csv_columns(test.record)
        sigma_1 = 1e3 * columns["internal_sigma_1"]
        sigma_3 = 1e3 * columns["internal_sigma_3_received"]
        best = int(np.nanargmax((sigma_1 - sigma_3) / (sigma_1 + sigma_3)))
        peaks.append((sigma_1[best], sigma_3[best]))
    internal = series.mohr_coulomb_envelope(*np.array(peaks).T)
    uncorrected = result.envelopes["uncorrected"].cohesion
    assert uncorrected - internal.cohesion > 3.0 * internal.cohesion_std  # the membrane's apparent cohesion
    for method in ("astm", "henkel_gilbert", "kuerbis_vaid", "fitted"):
        remaining = abs(result.envelopes[method].cohesion - internal.cohesion)
        assert remaining < abs(uncorrected - internal.cohesion), method
