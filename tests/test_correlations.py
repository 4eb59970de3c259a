"""The paper's correlations (calibrate.correlations): regressions, jackknife and verdicts by hand."""

import math

import numpy as np
import pytest

from calibrate import correlations
from calibrate.datasets import FittingTable


def test_a_line_with_noise_orthogonal_to_x_has_the_slope_and_r2_by_hand():
    # x = (−1, 0, 1) per member, y = x + δ (1, −2, 1): the noise is orthogonal to 1 and x, so the slope is
    # exactly 1, the intercept 0 and R² = Sxx / (Sxx + Σe²) = 2m / (2m + 6 m δ²).
    members, delta = 4, 0.3
    x = np.tile([-1.0, 0.0, 1.0], members)
    y = x + delta * np.tile([1.0, -2.0, 1.0], members)
    case = np.repeat(np.arange(members), 3)
    line = correlations.regression(x, y, case)
    assert line["slope"] == pytest.approx(1.0, abs=1e-12)
    assert line["intercept"] == pytest.approx(0.0, abs=1e-12)
    assert line["r2"] == pytest.approx(2.0 / (2.0 + 6.0 * delta**2), abs=1e-12)
    assert line["slope_se"] == pytest.approx(0.0, abs=1e-12)  # every member alike: no spread
    assert (line["records"], line["members"]) == (12, 4)


def test_leave_one_case_out_error_by_hand():
    # y = x + c_case with c = (d, −d, 0): a line fitted on two members has slope 1 and the mean of their
    # offsets, so the held-out residuals are −1.5 d, +1.5 d and 0: RMS √1.5 d over equal members.
    d = 0.2
    x = np.tile([0.0, 1.0, 2.0, 3.0], 3)
    offsets = np.repeat([d, -d, 0.0], 4)
    case = np.repeat([0, 1, 2], 4)
    line = correlations.regression(x, x + offsets, case)
    assert line["loco_rms"] == pytest.approx(math.sqrt(1.5) * d, abs=1e-12)
    assert line["slope"] == pytest.approx(1.0, abs=1e-12)


def test_the_jackknife_standard_error_by_hand():
    # Member c has y = k_c x on x = (1, 2): with members k = (1, 2, 3) (equal x), leaving one out gives the
    # mean slope of the other two (least squares through equal x sets): (2.5, 2, 1.5); mean 2, so
    # se² = (2/3)·(0.25 + 0 + 0.25) = 1/3.
    x = np.tile([1.0, 2.0], 3)
    k = np.repeat([1.0, 2.0, 3.0], 2)
    case = np.repeat([0, 1, 2], 2)
    line = correlations.regression(x, k * x, case)
    assert line["slope_se"] == pytest.approx(math.sqrt(1.0 / 3.0), abs=1e-12)


def test_non_finite_records_are_left_out_and_too_few_refused():
    x = np.array([0.0, 1.0, np.nan, 2.0])
    y = np.array([1.0, 3.0, 100.0, 5.0])
    line = correlations.regression(x, y, np.zeros(4, int))
    assert line["slope"] == pytest.approx(2.0) and line["records"] == 3
    assert math.isnan(line["slope_se"])  # one member: no jackknife
    with pytest.raises(ValueError, match="at least 3 records"):
        correlations.regression([1.0, 1.0, 1.0], [0.0, 1.0, 2.0], [0, 1, 2])


def _table(slope_axial, slope_radial, initial_axial, members=4, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    x = np.tile(np.linspace(-1.0, -0.3, 20), members)
    h = np.tile(np.linspace(0.0, 0.5, 20), members)
    case = np.repeat(np.arange(members), 20)
    initial = np.tile(np.r_[True, np.zeros(19, bool)], members)
    axial = slope_axial * x + noise * rng.standard_normal(x.size)
    axial[initial] = initial_axial + 0.01 * np.arange(members)
    radial = slope_radial * h + 0.1 + noise * rng.standard_normal(x.size)
    x[initial] = np.nan  # no strain ratio at zero strain: the first records stay out of the axial line
    inputs = {"strain_ratio_change": x, "hoop_ratio": h}
    return FittingTable(inputs, axial, radial, case, initial)


def test_verdicts_follow_their_rules(tmp_path):
    reference = correlations.paper_correlations(_table(0.5, 1.0, 0.3, noise=0.01))
    same = correlations.paper_correlations(_table(0.5, 1.0, 0.25, noise=0.01, seed=1))
    other = correlations.paper_correlations(_table(0.9, 1.0, 0.25, noise=0.01, seed=2))
    flipped = correlations.paper_correlations(_table(-0.5, 1.0, -0.3, noise=0.01, seed=3))
    noisy = correlations.paper_correlations(_table(0.5, 1.0, 0.25, noise=0.3, seed=4))
    assert correlations.verdicts(same, reference)["axial"][0] == "holds"
    assert correlations.verdicts(same, reference)["initial_axial"][0] == "holds"
    assert correlations.verdicts(same, reference)["initial_radial"][0] == "holds"  # r = 0.1 + h, h = 0 there
    assert correlations.verdicts(other, reference)["axial"][0] == "holds with other coefficients"
    assert correlations.verdicts(flipped, reference)["axial"][0] == "fails"
    assert correlations.verdicts(flipped, reference)["initial_axial"][0] == "fails"
    # R² of slope 0.5 over x spread 0.7 against noise 0.3: well below 0.25.
    assert noisy["axial"]["r2"] < correlations.FAIL_R2
    assert correlations.verdicts(noisy, reference)["axial"][0] == "fails"
    written = correlations.write_correlations(
        {"FCC": _table(0.5, 1.0, 0.3, noise=0.01), "random": _table(0.9, 1.0, 0.25, noise=0.01, seed=2)},
        tmp_path,
    )
    text = written["files"]["correlations.md"].read_text()
    assert (
        "random, Δσ_a/σc follows the change of strain ratio dε_r/dε_a: **holds with other coefficients**"
        in text
    )
    assert written["files"]["correlations.png"].stat().st_size > 10_000


def test_a_family_on_its_own_is_judged_by_its_fit_and_its_initial_stresses():
    alone = correlations.verdicts(correlations.paper_correlations(_table(0.5, 1.0, 0.3, noise=0.01)))
    assert (
        alone["axial"][0] == "holds"
        and alone["radial"][0] == "holds"
        and alone["initial_axial"][0] == "holds"
    )
    negative = correlations.verdicts(correlations.paper_correlations(_table(0.5, 1.0, -0.3, noise=0.01)))
    assert negative["initial_axial"][0] == "fails"  # the paper's initial Δσ_a is positive (its Table 3)
