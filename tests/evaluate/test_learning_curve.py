"""The ablation's learning curve (threedcal.evaluate.learning_curve) and its words
(threedcal.evaluate.ablation_reading): exact power laws recovered, the bootstrap interval's coverage,
the edge cases' stated answers, bad input named, and the TOST and the curve compared."""

import math

import numpy as np
import pandas as pd
import pytest

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import contrast, spatial_blocks
from threedcal.evaluate.ablation_reading import (
    curve_sentence,
    curve_summary,
    read_validation_errors,
    readings_compared,
)
from threedcal.evaluate.curve_bootstrap import crossings, expanded_tail, resample_means
from threedcal.evaluate.learning_curve import (
    FITTED,
    FLAT,
    NOT_FITTED,
    curve_table,
    fit_learning_curve,
    learning_curve,
)
from threedcal.evaluate.learning_curve_figure import learning_curve_figure
from threedcal.evaluate.power_law_fit import crossing, fit_curves

POINTS = {1: 12, 5: 61, 10: 122, 20: 244, 40: 488, 80: 976}
A, B, C = 1.0e-3, 0.3e-3, 0.6  # MSE(n) = A + B (n / 976)^-C
MARGIN = 0.10


def power_law(points, a=A, b=B, c=C):
    return a + b * (np.asarray(points, float) / POINTS[80]) ** -c


def true_answer(a=A, b=B, c=C, margin=MARGIN):
    """n* of the curve: a + b x^-c = (1 + margin)(a + b) at x = n* / 976."""
    return POINTS[80] * (1 + margin * (a + b) / b) ** (-1 / c)


def block_means(rng, replicates, blocks, means, sd=0.03, sd_gel=0.2):
    """P -> (R, K) block means: mean x the gel's hard places (every P) x a replicate's seed (every
    P) x the fraction's own replicate, block and residual noise."""
    gel = np.exp(sd_gel * rng.standard_normal(blocks))
    seed = 1 + sd * rng.standard_normal(replicates)
    out = {}
    for p, mean in means.items():
        own = (
            1
            + sd * rng.standard_normal((replicates, 1))
            + sd * rng.standard_normal((1, blocks))
            + sd * rng.standard_normal((replicates, blocks))
        )
        out[p] = mean * gel[None, :] * seed[:, None] * own
    return out


def study(means, replicates=3, seed=0, noise=0.2, factors=None):
    """validation_mse.csv of a study on a DIGIT-sized gel (12 x 16 mm, a 0.5 mm grid, a fifth of it
    for validation) whose fraction P has mean MSE `means[P]`: a shared smooth field (the gel's hard
    places) x lognormal per-coordinate noise x `factors[(P, r)]` (a replicate's own offset)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(0, 12, 0.5), np.arange(0, 16, 0.5))
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    xy = grid[np.sort(rng.choice(len(grid), len(grid) // 5, replace=False))]
    field = np.exp(0.3 * np.sin(xy[:, 0] / 2) * np.cos(xy[:, 1] / 3))
    rows = []
    for p, mean in means.items():
        for r in range(replicates):
            factor = (factors or {}).get((p, r), 1.0) * (1 + 0.01 * rng.standard_normal())
            mse = mean * factor * field * rng.lognormal(-(noise**2) / 2, noise, len(xy))
            rows.append(
                pd.DataFrame(
                    {"P": p, "replicate": r, "point": np.arange(len(xy)), "mse": mse}
                ).assign(x_mm=xy[:, 0], y_mm=xy[:, 1])
            )
    table = pd.concat(rows, ignore_index=True)
    return table, spatial_blocks(table, 5.2)


# ---------------------------------------------------------------------------------------------
# The fit


def test_an_exact_power_law_gives_back_its_parameters_and_crossing():
    x = np.array(list(POINTS.values())) / POINTS[80]
    fit = fit_curves(x, power_law(list(POINTS.values()))[None], 1e-5)
    assert fit.a[0] == pytest.approx(A, rel=1e-5)
    assert fit.b[0] == pytest.approx(B, rel=1e-5)
    assert fit.c[0] == pytest.approx(C, rel=1e-5)
    assert crossing(fit, MARGIN)[0] * POINTS[80] == pytest.approx(true_answer(), rel=1e-5)
    # closed form: the curve at n* is (1 + margin) times the curve at P = 80 %
    assert power_law(true_answer()) == pytest.approx(1.1 * power_law(POINTS[80]), rel=1e-12)


@pytest.mark.parametrize("a, b, c", [(0.0, 1.0, 0.5), (2.0, 0.1, 2.5), (1.0, 1.0, 0.05)])
def test_exact_curves_across_the_parameter_range(a, b, c):
    """No asymptote (a = 0, the edge of the constraint), a steep step, a near-logarithmic curve."""
    x = np.array(list(POINTS.values())) / POINTS[80]
    fit = fit_curves(x, power_law(list(POINTS.values()), a, b, c)[None], 1e-3)
    np.testing.assert_allclose([fit.a[0], fit.b[0], fit.c[0]], [a, b, c], rtol=1e-4, atol=1e-5)


def test_noisy_power_law_study_recovers_its_crossing_within_its_interval():
    means = {p: power_law(n) for p, n in POINTS.items()}
    table, blocks = study(means, replicates=4, seed=3)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200, seed=1)
    assert curve.status == FITTED
    assert curve.answer == pytest.approx(true_answer(), rel=0.08)
    assert curve.answer_low <= true_answer() <= curve.answer_high
    assert curve.parameters["c"][0] == pytest.approx(C, rel=0.2)
    assert curve.answer_low < curve.answer < curve.answer_high
    assert curve.dof == 3 and curve.replicates == 4 and curve.blocks == 4


def test_the_bootstrap_interval_covers_the_truth_at_about_its_nominal_rate():
    """Studies of 8 replicates on 6 blocks drawn from a known curve: the 90 % interval covers the
    true crossing in about 90 % of them (120 studies: 3 standard errors is +-8 %)."""
    means = {p: power_law(n) for p, n in POINTS.items()}
    rng = np.random.default_rng(0)
    studies = np.stack([np.stack(list(block_means(rng, 8, 6, means).values())) for _ in range(120)])
    points = np.array(list(POINTS.values()), float)
    found = crossings(studies, points, POINTS[80], MARGIN, 0.90, 150, rng)
    covered = (found.low <= true_answer()) & (true_answer() <= found.high)
    assert 0.82 <= covered.mean() <= 0.98
    assert np.median(found.answer) == pytest.approx(true_answer(), rel=0.02)


@pytest.mark.parametrize("replicates, blocks", [(3, 4), (8, 6), (1, 6)])
def test_the_bootstrap_spread_of_a_mean_is_its_variance_components(replicates, blocks):
    """The rescaled draws of one fraction's block means vary as the two-way random-effects model
    says its grand mean does, (MS_R + MS_K - MS_E) / (R K) (contrast's), not three times its
    interaction as plain resampling of rows and columns would; their mean is the table's."""
    rng = np.random.default_rng(replicates)
    means = (
        1
        + 0.5 * rng.standard_normal((replicates, 1))
        + 0.3 * rng.standard_normal((1, blocks))
        + 0.2 * rng.standard_normal((replicates, blocks))
    )
    draws = 40_000
    pick_r = rng.integers(replicates, size=(draws, replicates))
    pick_k = rng.integers(blocks, size=(draws, blocks))
    drawn = resample_means(means[None], pick_r, pick_k)[:, 0]
    _, se, _ = contrast(means, np.zeros_like(means), 0.0)
    assert drawn.var() == pytest.approx(float(se) ** 2, rel=0.03)
    assert drawn.mean() == pytest.approx(means.mean(), abs=3 * float(se) / math.sqrt(draws))


def test_the_interval_widens_for_few_degrees_of_freedom():
    assert expanded_tail(0.90, math.inf) == pytest.approx(0.05)
    assert expanded_tail(0.90, 1000) == pytest.approx(0.05, abs=1e-3)
    # Student's t on 3 df puts 5 % beyond 2.353: the normal's tail there is 0.93 %
    assert expanded_tail(0.90, 3) == pytest.approx(0.00931, abs=1e-4)


def test_the_same_inputs_give_the_same_bytes_and_the_seed_moves_them():
    means = {p: power_law(n) for p, n in POINTS.items()}
    table, blocks = study(means)
    first = curve_table(learning_curve(table, blocks, POINTS, bootstrap=200, seed=5))
    again = curve_table(learning_curve(table, blocks, POINTS, bootstrap=200, seed=5))
    other = curve_table(learning_curve(table, blocks, POINTS, bootstrap=200, seed=6))
    assert first.to_csv(index=False) == again.to_csv(index=False)
    assert first.to_csv(index=False) != other.to_csv(index=False)


# ---------------------------------------------------------------------------------------------
# Edge cases


def test_a_flat_curve_answers_at_or_below_the_smallest_fraction():
    table, blocks = study(dict.fromkeys(POINTS, 1e-3), seed=1)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.status == FLAT
    assert curve.answer == 12 and curve.answer_low == 12 and curve.low_censored
    line = curve_sentence(curve)
    assert line.startswith("learning curve: at or below 12 points (P = 1 %, the smallest")
    assert "not extrapolated below it" in line
    assert curve_summary(curve_table(curve)).startswith(
        "at or below 12 points (90 % interval at or below 12 to"
    )


def test_a_curve_that_only_reaches_the_margin_past_every_smaller_fraction():
    """MSE proportional to 1/n: only n > 976 / 1.1 is within 10 %; no fraction below P = 80 %
    measured is: the number interpolates between P = 40 and 80 %, and the sentence says so."""
    means = {p: 1e-3 * POINTS[80] / n for p, n in POINTS.items()}
    table, blocks = study(means, seed=2, noise=0.05)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.status == FITTED
    assert 488 < curve.answer < 976
    assert curve.answer == pytest.approx(976 / 1.1, rel=0.05)
    line = curve_sentence(curve)
    assert "between P = 40 % (488) and P = 80 % (976)" in line
    assert "no fraction measured below P = 80 % is within the margin" in line


def test_a_rising_curve_is_flat_at_best():
    """Smaller fractions better than P = 80 %: a, b >= 0 leaves a flat fit (b = 0), the answer at
    or below the smallest fraction, and the misfit named."""
    means = {p: 1e-3 * (1 + 0.1 * np.log(n)) for p, n in POINTS.items()}
    table, blocks = study(means, seed=4, noise=0.05)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.status == FLAT and curve.parameters["b"][0] == 0
    assert "misses the fractions' means by more than their spread" in curve_sentence(curve)


def test_two_fractions_are_not_fitted_and_say_why():
    table, blocks = study({20: 1.1e-3, 80: 1e-3})
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.status == NOT_FITTED and math.isnan(curve.answer)
    assert curve_sentence(curve) == (
        "learning curve not fitted: a curve of three parameters needs 3 or more fractions of "
        "different point counts; this study has P = 20, 80 %"
    )
    written = curve_table(curve)
    assert written.loc[0, "note"].startswith("not fitted: a curve of three parameters")
    assert curve_summary(written).startswith("not fitted (a curve of three parameters")
    reading = read_validation_errors(table, blocks, POINTS, bootstrap=200)
    assert reading.comparison is None and len(reading.text.splitlines()) == 2
    assert readings_compared(reading.tests, curve, POINTS) is None


def test_three_fractions_fit_exactly_with_no_degrees_of_freedom_left():
    means = {p: power_law(POINTS[p]) for p in (5, 20, 80)}
    curve = fit_learning_curve(
        block_means(np.random.default_rng(0), 3, 4, means, sd=1e-6, sd_gel=0), POINTS, bootstrap=100
    )
    assert curve.dof == 0 and math.isnan(curve.lack_of_fit_p)
    assert curve.answer == pytest.approx(true_answer(), rel=1e-3)


def test_one_replicate_fits_and_says_its_interval_lacks_the_training_noise():
    means = {p: power_law(n) for p, n in POINTS.items()}
    table, blocks = study(means, replicates=1, seed=5)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.status == FITTED and curve.replicates == 1
    assert curve.answer_low <= curve.answer <= curve.answer_high
    assert "one replicate: the interval holds the spatial sampling only" in curve_sentence(curve)


def test_one_noisy_fraction_does_not_erase_the_answer():
    """P = 40 %'s third replicate 40 % worse (a training stopped short): its TOST cannot show
    equivalence and the fixed sequence stops there; the curve still answers near the truth, and
    the recommendation says why the two differ, with P = 40 %'s replicate spread."""
    means = {p: power_law(n) for p, n in POINTS.items()}
    table, blocks = study(means, seed=6, factors={(40, 2): 1.4})
    reading = read_validation_errors(table, blocks, POINTS, bootstrap=200, seed=2)
    equivalence = reading.tests[reading.tests["family"] == "equivalence"].set_index("P")
    assert not equivalence.loc[40, "significant"]
    assert reading.recommendation.startswith("probe at least 976 points (P = 80 %)")
    curve = reading.curve
    assert curve.answer == pytest.approx(true_answer(), rel=0.1)
    assert curve.answer_low <= true_answer() <= curve.answer_high
    forty = curve.fractions.set_index("P").loc[40]
    assert forty["weight"] < 0.2 * curve.fractions["weight"].max()
    assert reading.comparison.startswith(
        f"the readings differ: the TOST says 976 points (P = 80 %), the curve "
        f"{int(curve.answer)} (90 % interval"
    )
    assert "the TOST of P = 40 % is too wide to show equivalence" in reading.comparison
    assert "its 3 replicates' mean MSE spread from" in reading.comparison
    assert "the curve, fitted on every fraction" in reading.comparison
    assert reading.text.splitlines() == [
        reading.recommendation,
        reading.curve_line,
        reading.comparison,
    ]


def test_readings_agree_when_the_tost_names_the_curves_fraction():
    means = {1: 3e-3, 5: 1.6e-3, 10: 1.25e-3, 20: 1.03e-3, 40: 1.01e-3, 80: 1e-3}
    table, blocks = study(means, seed=7, noise=0.05)
    reading = read_validation_errors(table, blocks, POINTS, bootstrap=200)
    assert reading.recommendation.startswith("probe at least 244 points: P = 20 %")
    assert reading.comparison.startswith(
        "the two readings agree: the TOST says 244 points (P = 20 %)"
    )


def test_when_the_curve_asks_for_more_than_the_tost_it_says_why():
    """A sharp knee (P = 10 % at +160 %, P = 20 % at +4.5 %) that no power law follows: the TOST
    shows P = 20 % equivalent on its own data, the curve through every fraction puts it past the
    margin, and the line says so, and that P = 20 %'s own test is then the better guide."""
    means = {1: 1.0e-2, 5: 4.0e-3, 10: 2.6e-3, 20: 1.04e-3, 40: 1.05e-3, 80: 1e-3}
    table, blocks = study(means, seed=8, noise=0.03)
    reading = read_validation_errors(table, blocks, POINTS, bootstrap=200)
    assert reading.recommendation.startswith("probe at least 244 points: P = 20 %")
    assert reading.curve.answer_low > POINTS[20]
    assert reading.comparison.startswith("the readings differ: the TOST says 244 points")
    assert "the TOST shows P = 20 % equivalent on its own data" in reading.comparison
    assert "past the margin: its neighbours pull the curve above P = 20 %'s own mean" in (
        reading.comparison
    )
    assert reading.comparison.endswith(
        "but a power law does not describe these fractions (chi-squared p < 0.0001), so "
        "P = 20 %'s own test is the better guide"
    )


def test_fractions_before_the_power_law_holds_are_left_out():
    """A power law from P = 5 % on, P = 1 % far better than it predicts (the small-data region,
    where a model of 12 points falls back on its initial weights): the fit through every fraction
    misses, the fit from P = 5 % does not, and the answer is read from it."""
    means = {p: power_law(n) for p, n in POINTS.items()}
    means[1] = 2.0e-3
    table, blocks = study(means, seed=11, noise=0.05)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.left_out == [1] and curve.smallest_points == 61
    assert curve.answer == pytest.approx(true_answer(), rel=0.1)
    line = curve_sentence(curve)
    assert "fitted on P = 5, 10, 20, 40, 80 %" in line
    assert "P = 1 % left out: a power law through it misses the larger fractions' means" in line
    written = curve_table(curve).set_index("quantity")
    assert written.loc["fitted_from", "P"] == 5
    left = curve_table(curve).query("quantity == 'weight' and P == 1")
    assert left["note"].iloc[0].endswith("left out of the fit: before the power law holds")


def test_a_single_outlying_fraction_is_not_cut_away_with_the_small_ones():
    """P = 20 % lucky (+4 % where the curve says +23 %): leaving out P = 1 and 5 % does not mend
    the misfit, so every fraction stays in the fit, the answer stays near the truth, and the
    misfit is named."""
    means = {p: power_law(n, b=0.3e-3, c=0.5) for p, n in POINTS.items()}
    means[20] = 1.04 * means[80]
    table, blocks = study(means, seed=8, noise=0.05)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    assert curve.left_out == []
    assert curve.answer == pytest.approx(true_answer(b=0.3e-3, c=0.5), rel=0.1)
    assert "misses the fractions' means by more than their spread" in curve_sentence(curve)


# ---------------------------------------------------------------------------------------------
# Bad input


@pytest.mark.parametrize("column", ["P", "point", "mse"])
def test_a_missing_column_is_named(column):
    table, blocks = study(dict.fromkeys(POINTS, 1e-3))
    with pytest.raises(ConfigError, match=f"validation table lacks column '{column}'"):
        learning_curve(table.drop(columns=column), blocks, POINTS)


@pytest.mark.parametrize("value", [np.nan, np.inf, -1e-3])
def test_an_mse_that_is_not_a_finite_number_at_or_above_zero_is_named(value):
    table, blocks = study(dict.fromkeys(POINTS, 1e-3))
    row = table.index[(table["P"] == 40) & (table["replicate"] == 2)][7]
    table.loc[row, "mse"] = value
    with pytest.raises(ConfigError) as error:
        learning_curve(table, blocks, POINTS)
    assert f"P=40, replicate 2, point {table.loc[row, 'point']}" in str(error.value)
    assert "not a finite number >= 0 (1 such value(s) in the table)" in str(error.value)
    with pytest.raises(ConfigError, match="P=40, replicate 2"):
        read_validation_errors(table, blocks, POINTS)


def test_a_fraction_without_its_points_or_the_reference_is_named():
    table, blocks = study(dict.fromkeys(POINTS, 1e-3))
    with pytest.raises(ConfigError, match=r"points probed unknown for P = \[5\]"):
        learning_curve(table, blocks, {p: n for p, n in POINTS.items() if p != 5})
    without = table[table["P"] != 80]
    with pytest.raises(ConfigError, match="needs the reference fraction P=80"):
        learning_curve(without, blocks, POINTS)
    with pytest.raises(ConfigError, match="margin must be between 0 and 1"):
        learning_curve(table, blocks, POINTS, margin=1.5)


def test_zero_error_everywhere_is_not_fitted():
    table, blocks = study(dict.fromkeys(POINTS, 1e-3))
    curve = learning_curve(table.assign(mse=0.0), blocks, POINTS, bootstrap=100)
    assert curve.status == NOT_FITTED and "is zero" in curve.reason


# ---------------------------------------------------------------------------------------------
# Outputs


def test_learning_curve_csv_holds_the_answer_parameters_and_each_fraction(tmp_path):
    means = {p: power_law(n) for p, n in POINTS.items()}
    table, blocks = study(means, seed=9)
    curve = learning_curve(table, blocks, POINTS, bootstrap=200)
    written = curve_table(curve)
    written.to_csv(tmp_path / "learning_curve.csv", index=False, float_format="%.6g")
    read = pd.read_csv(tmp_path / "learning_curve.csv")
    rows = read.set_index("quantity")
    assert rows.loc["points_within_margin", "value"] == curve.answer
    assert rows.loc["points_within_margin", "note"] == FITTED
    assert rows.loc["level", "value"] == 0.9 and rows.loc["margin", "points"] == 976
    assert set(rows.index) >= {"a", "b", "c", "chi2", "design"}
    observed = read[read["quantity"] == "observed_mse"].set_index("P")
    assert list(observed.index) == sorted(POINTS)
    assert (observed["low"] <= observed["value"]).all()
    fitted = read[read["quantity"] == "fitted_mse"].set_index("P")
    np.testing.assert_allclose(fitted["value"], curve.predict(fitted["points"]), rtol=1e-5)
    weights = read[read["quantity"] == "weight"]["value"]
    assert weights.sum() == pytest.approx(1.0, abs=1e-5)
    low, high = int(curve.answer_low), int(curve.answer_high)
    assert curve_summary(read) == f"{int(curve.answer)} points (90 % interval {low} to {high})"


def test_the_figure_draws_each_kind_of_curve(tmp_path):
    means = {p: power_law(n) for p, n in POINTS.items()}
    cases = {
        "fitted": study(means, seed=10),
        "flat": study(dict.fromkeys(POINTS, 1e-3), seed=10),
        "not_fitted": study({20: 1.1e-3, 80: 1e-3}, seed=10),
    }
    for name, (table, blocks) in cases.items():
        curve = learning_curve(table, blocks, POINTS, bootstrap=50)
        learning_curve_figure(curve, tmp_path / f"{name}.png", name)
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000
