"""The quick calibration's stop rule on synthetic per-press errors with a known answer."""

import math

import numpy as np
import pytest

from threedcal.evaluate.object_errors import mean_interval
from threedcal.stop_rule import (
    Improvement,
    decide,
    paired_improvement,
    rule_problems,
)


def test_improvement_and_bound_exact():
    # every press halves its error: the improvement is 50 %, with no spread the bound is it too
    result = paired_improvement([2.0, 4.0, 8.0], [1.0, 2.0, 4.0], 0.9)
    assert result.estimate == pytest.approx(0.5) and result.upper == pytest.approx(0.5)
    # log ratios 0.1, 0.2, 0.3: mean 0.2, sd 0.1, t(0.9; 2 dof) = 1.8856180831641267
    before = np.exp([0.1, 0.2, 0.3])
    result = paired_improvement(before, np.ones(3), 0.9)
    upper_log = 0.2 + 1.8856180831641267 * 0.1 / math.sqrt(3)
    assert result.estimate == pytest.approx(1 - math.exp(-0.2))
    assert result.upper == pytest.approx(1 - math.exp(-upper_log))
    assert result.presses == 3
    # one press: no spread to bound it with
    assert paired_improvement([2.0], [1.0], 0.9).upper == 1.0


def test_mean_interval_exact():
    # mean 2, sd 1, n 3: two-sided 90 % half width t(0.95; 2) * 1 / sqrt(3), t = 2.919985580355516
    mean, low, high = mean_interval([1.0, 2.0, 3.0], 0.9)
    half = 2.919985580355516 / math.sqrt(3)
    assert (mean, low, high) == pytest.approx((2.0, 2.0 - half, 2.0 + half))


def synthetic_round(true_improvement, presses, seed, paired_sd=0.1, press_sd=1.0):
    """Per-press errors of two models on the same presses: how hard a press is varies a lot
    (press_sd, log) and is shared by both; each score has its own small noise (paired_sd)."""
    rng = np.random.default_rng(seed)
    hardness = rng.normal(0.0, press_sd, presses)
    before = np.exp(hardness + rng.normal(0.0, paired_sd, presses))
    after = (1 - true_improvement) * np.exp(hardness + rng.normal(0.0, paired_sd, presses))
    return before, after


def test_a_true_20_percent_improvement_continues():
    for seed in range(20):
        result = paired_improvement(*synthetic_round(0.2, 10, seed), 0.9)
        assert decide(result, 0.05, at_cap=False).go_on, seed
        assert abs(result.estimate - 0.2) < 0.1


def test_no_improvement_stops_with_enough_presses():
    """0 % true improvement stops; presses 100x apart in difficulty do not hide it (paired)."""
    for seed in range(20):
        before, after = synthetic_round(0.0, 150, seed)
        assert np.ptp(np.log(before)) > 3  # the presses differ far more than the models do
        decision = decide(paired_improvement(before, after, 0.9), 0.05, at_cap=False)
        assert decision == decide(Improvement(0.0, 0.0, 150), 0.05, at_cap=False)
        assert not decision.go_on and decision.reason == "improvement below margin"


def test_stops_wrongly_at_the_stated_rate_when_the_truth_is_the_margin():
    """With the true improvement exactly at the margin the bound lies below it — a wrong stop —
    in 1 − confidence of rounds (the t bound is exact for normal log ratios)."""
    margin, confidence, trials = 0.05, 0.9, 4000
    stops = sum(
        paired_improvement(*synthetic_round(margin, 8, seed), confidence).upper < margin
        for seed in range(trials)
    )
    assert abs(stops / trials - (1 - confidence)) < 0.015


def test_decide_round_one_and_cap():
    assert decide(None, 0.05, at_cap=False).go_on
    assert decide(None, 0.05, at_cap=True).reason == "cap"
    going = Improvement(0.2, 0.3, 10)
    assert decide(going, 0.05, at_cap=True).reason == "cap"
    assert decide(Improvement(0.01, 0.04, 10), 0.05, at_cap=True).reason == (
        "improvement below margin"
    )


def test_bad_margin_or_confidence_named():
    assert rule_problems(0.05, 0.9) == []
    problems = rule_problems(1.5, 0.3)
    assert problems[0].startswith("quick.margin: 1.5") and problems[1].startswith(
        "quick.confidence: 0.3"
    )
    assert rule_problems(float("nan"), 1.0)[1].startswith("quick.confidence")
    with pytest.raises(ValueError, match="positive"):
        paired_improvement([1.0, 0.0], [1.0, 1.0], 0.9)


def test_infinite_or_missing_errors_are_refused_not_read_as_a_gain():
    """A diverged model's error (inf, NaN) is no evidence either way: refused, named."""
    import numpy as np
    import pytest

    from threedcal.stop_rule import paired_improvement

    good = np.array([1.0, 2.0, 3.0])
    for bad in (np.array([1.0, np.inf, 3.0]), np.array([1.0, np.nan, 3.0])):
        with pytest.raises(ValueError, match="positive and finite"):
            paired_improvement(bad, good, 0.9)
        with pytest.raises(ValueError, match="positive and finite"):
            paired_improvement(good, bad, 0.9)
