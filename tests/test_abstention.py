"""calibrate.abstention: the factor toward no correction, on cross-validated predictions built by hand.

The "cross-validated predictions" here are written down rather than fitted, so that each region's
candidates have closed forms: the least-squares shrinkage w* = clip(Σ_c ⟨p t⟩_c / Σ_c ⟨p²⟩_c, 0, 1) and the
errors (RMS over cases of each case's mean square) of no correction, the correction and w* refitted
without each case. The rule takes the candidate (1, w*, 0) that errs least there.
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
    # E_m t_m/(σc D) 1.5 and 1.9, region [1, 2): σ1 predicted with the wrong sign; σ3 3 and 1.5 times
    (1.5, A, -A, 3.0 * A),
    (1.9, B, -B, 1.5 * B),
    # 5 and 6, region [4, 8): exact
    (5.0, C, C, C),
    (6.0, 2.0 * C, 2.0 * C, 2.0 * C),
    # 20 and 30, region [16, 32): half the target (w* = 2, clipped to 1: not amplified)
    (20.0, C, 0.5 * C, 0.5 * C),
    (30.0, C, 0.5 * C, 0.5 * C),
    # 70 and 100, region [64, 128): twice, and exact: a w* that fits in sample but not out of it
    (70.0, A, 2.0 * A, 2.0 * A),
    (100.0, B, B, B),
]


def test_the_rule_abstains_where_the_cross_validated_correction_hurts_and_only_there():
    table, axial, radial = _table(CASES)
    rule = abstention.fit_rule(table, axial, radial)
    regions = {(r["low"], r["high"]): r for r in rule["regions"]}
    assert sorted(regions) == [(1.0, 2.0), (4.0, 8.0), (16.0, 32.0), (64.0, 128.0)]  # octaves with a case
    low = regions[(1.0, 2.0)]
    assert low["cases"] == 2
    # σ1 of the wrong sign: Σpt < 0, w* = 0, and withdrawn; errs by 2t against none's t
    assert low["axial"]["weight"] == 0.0 and low["axial"]["shrinkage"] == 0.0
    assert low["axial"]["none_rms"] == pytest.approx(0.1, rel=1e-12)
    assert low["axial"]["fitted_rms"] == pytest.approx(0.2, rel=1e-12)
    assert low["axial"]["rms"] == pytest.approx(0.1, rel=1e-12)
    # σ3, each case once: w* = (3a + 1.5a)/(9a + 2.25a) = 0.4 (each reading once: 15/31.5 = 0.476)
    radial = low["radial"]
    assert radial["shrinkage"] == pytest.approx(0.4, rel=1e-12)
    # fitted: (2t)² and (0.5t)², mean square 2.125a; w* in sample: (0.2t)² and (0.4t)², 0.1a
    assert radial["fitted_rms"] == pytest.approx(math.sqrt(2.125 * 0.01), rel=1e-12)
    assert radial["shrunk_rms"] == pytest.approx(math.sqrt(0.1 * 0.01), rel=1e-12)
    # held out: A with B's w* (1.5/2.25 = 2/3) errs by (2t − t)², B with A's (3/9 = 1/3) by (0.5t − t)²
    assert radial["held_out_rms"] == pytest.approx(math.sqrt(0.625 * 0.01), rel=1e-12)
    # 0.079 against none 0.1 and fitted 0.146: shrunk, with that error for the band
    assert radial["weight"] == pytest.approx(0.4, rel=1e-12)
    assert radial["rms"] == pytest.approx(math.sqrt(0.625 * 0.01), rel=1e-12)
    # elsewhere kept: exact (w = 1), and half the target (w* = 2) not amplified beyond 1
    for key in ((4.0, 8.0), (16.0, 32.0), (64.0, 128.0)):
        for target in abstention.TARGETS:
            assert regions[key][target]["weight"] == 1.0, (key, target)
    # [64, 128): w* = (2a + a)/(4a + a) = 0.6 cuts the error in sample (√0.1a against √0.5a) but
    # out of sample errs by (a + a/4)/2 > a/2: the shrinkage is noise there and is not taken
    high = regions[(64.0, 128.0)]["radial"]
    assert high["shrinkage"] == pytest.approx(0.6, rel=1e-12)
    assert high["shrunk_rms"] < high["fitted_rms"] == pytest.approx(math.sqrt(0.5 * 0.01), rel=1e-12)
    assert high["held_out_rms"] == pytest.approx(math.sqrt(0.625 * 0.01), rel=1e-12)
    # never worse than none, by construction: the chosen factor's error on unseen cases is the least
    for region in rule["regions"]:
        for target in abstention.TARGETS:
            scores = region[target]
            assert scores["rms"] == min(scores["none_rms"], scores["fitted_rms"], scores["held_out_rms"])


def test_a_record_takes_its_region_s_factors_or_the_nearest_region_s():
    table, axial, radial = _table(CASES)
    rule = abstention.fit_rule(table, axial, radial)
    assert abstention.record_shrink(rule, np.full(5, 1.2))[:2] == (0.0, pytest.approx(0.4))
    # below every region: the nearest, [1, 2); 10 lies between [4, 8) and [16, 32), nearer 8 (in logs)
    assert abstention.record_shrink(rule, [0.3, 0.3])[:2] == (0.0, pytest.approx(0.4))
    assert abstention.record_shrink(rule, [10.0])[2]["low"] == 4.0
    # per record: the median reading decides (one noisy reading across an edge does not)
    assert abstention.record_shrink(rule, [1.9, 1.95, 2.05])[:2] == (0.0, pytest.approx(0.4))
    # no rule (a correction written before rules existed), or no finite reading: nothing shrunk
    assert abstention.record_shrink(None, [1.5]) == (1.0, 1.0, None)
    assert abstention.record_shrink(rule, [np.nan]) == (1.0, 1.0, None)


def test_predictions_of_another_length_are_refused():
    table, axial, radial = _table(CASES)
    with pytest.raises(ValueError, match="one cross-validated prediction per row"):
        abstention.fit_rule(table, axial[:-1], radial)
