"""calibrate.abstention: the factor toward no correction, on cross-validated predictions built by hand.

The "cross-validated predictions" here are written down rather than fitted, so that each region's
candidates have closed forms: the least-squares shrinkage w* = clip(Σ_c ⟨p t⟩_c / Σ_c ⟨p²⟩_c, 0, 1) and the
errors (RMS over cases of each case's mean square) of no correction, the correction and w* refitted
without each case. The rule takes no correction unless a candidate (1, w*) beats it by more than one
standard error of the cases' paired gains, then the one that errs least.
"""

import math

import numpy as np
import pytest

from calibrate import abstention, datasets


def _table(cases):
    """A table of ``cases``: (E_m t_m/(σc D), targets, axial prediction, radial prediction) each."""
    columns, axial, radial, case, predictions = [], [], [], [], ([], [])
    for number, (stiffness, target, axial_prediction, radial_prediction) in enumerate(cases):
        rows = len(target)
        columns.append(np.full(rows, float(stiffness)))
        axial.append(np.asarray(target, dtype=float))
        radial.append(np.asarray(target, dtype=float))
        case.append(np.full(rows, number))
        predictions[0].append(np.asarray(axial_prediction, dtype=float))
        predictions[1].append(np.asarray(radial_prediction, dtype=float))
    n = sum(len(c) for c in case)
    inputs = {name: np.zeros(n) for name in datasets.INPUTS}
    inputs["stiffness_ratio"] = np.concatenate(columns)
    table = datasets.FittingTable(
        inputs, np.concatenate(axial), np.concatenate(radial), np.concatenate(case), np.zeros(n, dtype=bool)
    )
    return table, np.concatenate(predictions[0]), np.concatenate(predictions[1])


# Targets of mean square a = 0.01 in every case; case A has two readings, B six, so that counting each
# reading once and each case once differ.
A = np.array([0.1, -0.1])
B = np.array([0.1, -0.1, 0.1, -0.1, 0.1, -0.1])
C = np.array([0.2, 0.3, 0.1])
CASES = [
    # E_m t_m/(σc D) 1.5, 1.7 and 1.9, region [1, 2): σ1 predicted with the wrong sign; σ3 3, 1.5 and 1.5
    # times the target
    (1.5, A, -A, 3.0 * A),
    (1.7, B, -B, 1.5 * B),
    (1.9, B, -B, 1.5 * B),
    # 5 and 6, region [4, 8): exact
    (5.0, C, C, C),
    (6.0, 2.0 * C, 2.0 * C, 2.0 * C),
    # 9, 11 and 13, region [8, 16): exact, half and 2.5 times the target: better than none on average, by
    # less than its scatter
    (9.0, A, A, A),
    (11.0, B, 0.5 * B, 0.5 * B),
    (13.0, A, 2.5 * A, 2.5 * A),
    # 20 and 30, region [16, 32): half the target (w* = 2, clipped to 1: not amplified)
    (20.0, C, 0.5 * C, 0.5 * C),
    (30.0, C, 0.5 * C, 0.5 * C),
    # 70, 80 and 100, region [64, 128): twice, and exact twice: a w* that fits in sample but not out of it
    (70.0, A, 2.0 * A, 2.0 * A),
    (80.0, B, B, B),
    (100.0, B, B, B),
]
a = 0.01


def test_the_rule_abstains_where_the_cross_validated_correction_hurts_and_only_there():
    table, axial, radial = _table(CASES)
    rule = abstention.fit_rule(table, axial, radial)
    regions = {(r["low"], r["high"]): r for r in rule["regions"]}
    assert sorted(regions) == [(1.0, 2.0), (4.0, 8.0), (8.0, 16.0), (16.0, 32.0), (64.0, 128.0)]
    low = regions[(1.0, 2.0)]
    assert low["cases"] == 3
    # σ1 of the wrong sign: Σpt < 0, w* = 0, and withdrawn; errs by 2t against none's t
    assert low["axial"]["weight"] == 0.0 and low["axial"]["shrinkage"] == 0.0
    assert low["axial"]["none_rms"] == pytest.approx(0.1, rel=1e-12)
    assert low["axial"]["fitted_rms"] == pytest.approx(0.2, rel=1e-12)
    assert low["axial"]["rms"] == pytest.approx(0.1, rel=1e-12)
    # σ3, each case once: w* = (3a + 1.5a + 1.5a)/(9a + 2.25a + 2.25a) = 4/9 (each reading once: 21/36)
    radial = low["radial"]
    assert radial["shrinkage"] == pytest.approx(4.0 / 9.0, rel=1e-12)
    # fitted: (2t)², (0.5t)², (0.5t)²: mean square 1.5a; w* in sample: 4/3 t, 2/3 t, 2/3 t: (1/9)a each
    assert radial["fitted_rms"] == pytest.approx(math.sqrt(1.5 * a), rel=1e-12)
    assert radial["shrunk_rms"] == pytest.approx(math.sqrt(a / 9.0), rel=1e-12)
    # held out: A with the B cases' w* (3/4.5 = 2/3) errs by (2t − t)² = a; each B with A and the other
    # B's, (3 + 1.5)/(9 + 2.25) = 0.4, by (0.6t − t)² = 0.16a: mean square 0.44a
    assert radial["held_out_rms"] == pytest.approx(math.sqrt(0.44 * a), rel=1e-12)
    # gains on none per case 0, 0.84a and 0.84a: mean 0.56a, standard error 0.28a
    gains = np.array([0.0, 0.84 * a, 0.84 * a])
    assert radial["held_out_gain"] == pytest.approx(gains.mean(), rel=1e-12)
    assert radial["held_out_gain_se"] == pytest.approx(gains.std(ddof=1) / math.sqrt(3), rel=1e-12)
    assert radial["held_out_gain"] > radial["held_out_gain_se"]  # 0.56a against 0.28a
    # so shrunk, with that error for the band
    assert radial["weight"] == pytest.approx(4.0 / 9.0, rel=1e-12)
    assert radial["rms"] == pytest.approx(math.sqrt(0.44 * a), rel=1e-12)
    # kept: exact (w = 1), and half the target (w* = 2) not amplified beyond 1
    for key in ((4.0, 8.0), (16.0, 32.0), (64.0, 128.0)):
        for target in abstention.TARGETS:
            assert regions[key][target]["weight"] == 1.0, (key, target)
    # [8, 16): the correction errs 0, 0.25a and 2.25a against none's a: RMS √(0.83a) < √a, so the least
    # error would take it, but its gains a, 0.75a, −1.25a (mean a/6) lie within one standard error
    # (0.71a) of nothing: no correction
    middle = regions[(8.0, 16.0)]["axial"]
    assert middle["fitted_rms"] == pytest.approx(math.sqrt(2.5 * a / 3.0), rel=1e-12)
    assert middle["fitted_rms"] < middle["none_rms"]
    gains = np.array([a, 0.75 * a, -1.25 * a])
    assert middle["fitted_gain"] == pytest.approx(gains.mean(), rel=1e-12)
    assert middle["fitted_gain_se"] == pytest.approx(gains.std(ddof=1) / math.sqrt(3), rel=1e-12)
    assert middle["held_out_gain"] < 0.0  # w* refitted without each case: worse than none
    assert middle["weight"] == 0.0 and middle["rms"] == middle["none_rms"]
    # [64, 128): w* = (2a + a + a)/(4a + a + a) = 2/3 cuts the error in sample (√(a/9) against √(a/3)) but
    # out of sample errs by (a + 0.16a + 0.16a)/3 = 0.44a > a/3: the shrinkage is noise there and is not taken
    high = regions[(64.0, 128.0)]["radial"]
    assert high["shrinkage"] == pytest.approx(2.0 / 3.0, rel=1e-12)
    assert high["fitted_rms"] == pytest.approx(math.sqrt(a / 3.0), rel=1e-12)
    assert high["shrunk_rms"] == pytest.approx(math.sqrt(a / 9.0), rel=1e-12)
    assert high["held_out_rms"] == pytest.approx(math.sqrt(0.44 * a), rel=1e-12)
    # never worse than none, by construction: the chosen factor's error on unseen cases
    for region in rule["regions"]:
        for target in abstention.TARGETS:
            scores = region[target]
            chosen = {1.0: scores["fitted_rms"], 0.0: scores["none_rms"]}.get(
                scores["weight"], scores["held_out_rms"]
            )
            assert scores["rms"] == chosen <= scores["none_rms"]


def test_a_region_of_one_case_abstains_for_want_of_a_standard_error():
    table, axial, radial = _table([(1.5, A, A, A), (5.0, C, C, C), (6.0, C, C, C)])
    rule = abstention.fit_rule(table, axial, radial)
    lone = rule["regions"][0]
    assert (lone["low"], lone["cases"]) == (1.0, 1)
    assert lone["axial"]["fitted_rms"] == 0.0 and lone["axial"]["fitted_gain_se"] == math.inf
    assert lone["axial"]["weight"] == 0.0 and lone["radial"]["weight"] == 0.0
    # two exact cases: gains with no scatter, kept
    assert rule["regions"][1]["axial"]["weight"] == 1.0


def test_a_record_takes_its_region_s_factors_or_the_nearest_region_s():
    table, axial, radial = _table(CASES)
    rule = abstention.fit_rule(table, axial, radial)
    assert abstention.record_shrink(rule, np.full(5, 1.2))[:2] == (0.0, pytest.approx(4.0 / 9.0))
    # below every region: the nearest, [1, 2); 40 lies between [16, 32) and [64, 128), nearer 32 (in logs)
    assert abstention.record_shrink(rule, [0.3, 0.3])[:2] == (0.0, pytest.approx(4.0 / 9.0))
    assert abstention.record_shrink(rule, [40.0])[2]["low"] == 16.0
    # per record: the median reading decides (one noisy reading across an edge does not)
    assert abstention.record_shrink(rule, [1.9, 1.95, 2.05])[:2] == (0.0, pytest.approx(4.0 / 9.0))
    # no rule (a correction written before rules existed), or no finite reading: nothing shrunk
    assert abstention.record_shrink(None, [1.5]) == (1.0, 1.0, None)
    assert abstention.record_shrink(rule, [np.nan]) == (1.0, 1.0, None)


def test_predictions_of_another_length_are_refused():
    table, axial, radial = _table(CASES)
    with pytest.raises(ValueError, match="one cross-validated prediction per row"):
        abstention.fit_rule(table, axial[:-1], radial)
