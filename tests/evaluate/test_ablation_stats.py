"""The ablation's statistics (threedcal.evaluate.ablation, .power): the paper's tests exactly, the
paired spatial-block test's false-positive rate, the TOST, the recommendation and the power table."""

import itertools
import math
import warnings

import numpy as np
import pandas as pd
import pytest
import statsmodels.formula.api as smf
from scipy import stats

from threedcal.errors import ConfigError
from threedcal.evaluate import ablation_figure
from threedcal.evaluate.ablation import (
    _equivalence_conclusion,
    ablation_tests,
    block_means,
    contrast,
    difference_test,
    holm,
    independent_contrast,
    paper_family,
    ratio_interval,
    spatial_blocks,
    tost,
)
from threedcal.evaluate.ablation_figure import AXIS_RATIO, interval_on_axis
from threedcal.evaluate.ablation_reading import recommend
from threedcal.evaluate.power import (
    correlation,
    fit_correlation,
    needed_design,
    power_table,
    variance_components,
)

# ---------------------------------------------------------------------------------------------
# Synthetic per-coordinate errors: a validation share of a 0.5 mm grid on a DIGIT-sized gel, each
# model's MSE at a coordinate = mean + replicate offset + a field every model shares + the model's
# own spatially correlated field (exponential correlation of known range, with a nugget).
GRID_MM, WIDTH_MM, HEIGHT_MM = 0.5, 12.0, 16.0
DISC_MM = 5.2  # 2 x 1.5 contact radii of a 2 mm ball pressed 1 mm: the scoring disc's diameter
RANGE_MM, NUGGET = 1.5, 0.3


def validation_coordinates(seed=0, fraction=0.2):
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(0, WIDTH_MM, GRID_MM), np.arange(0, HEIGHT_MM, GRID_MM))
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    return grid[np.sort(rng.choice(len(grid), int(fraction * len(grid)), replace=False))]


def field_factor(xy, range_mm=RANGE_MM, nugget=NUGGET):
    distance = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    return np.linalg.cholesky(correlation(distance, range_mm, nugget) + 1e-9 * np.eye(len(xy)))


def simulate(xy, draws, replicates, means, sd_replicate, sd_shared, sd_model, seed):
    """{P: (draws, replicates, n)} per-coordinate MSE of every model in `means` (P -> mean)."""
    rng = np.random.default_rng(seed)
    factor = field_factor(xy)
    n = len(xy)
    shared = (factor @ rng.standard_normal((n, draws))).T[:, None, :]
    out = {}
    for p, mean in means.items():
        own = np.einsum("ij,drj->dri", factor, rng.standard_normal((draws, replicates, n)))
        offset = rng.standard_normal((draws, replicates, 1))
        out[p] = mean + sd_replicate * offset + sd_shared * shared + sd_model * own
    return out


def as_table(xy, models, draw=0):
    rows = []
    for p, values in models.items():
        for r, mse in enumerate(values[draw]):
            rows.append(
                pd.DataFrame(
                    {"P": p, "replicate": r, "point": np.arange(len(xy)), "mse": mse}
                ).assign(x_mm=xy[:, 0], y_mm=xy[:, 1])
            )
    return pd.concat(rows, ignore_index=True)


def block_matrix(xy, block_mm=DISC_MM):
    frame = pd.DataFrame({"point": np.arange(len(xy)), "x_mm": xy[:, 0], "y_mm": xy[:, 1]})
    blocks = spatial_blocks(frame, block_mm).to_numpy()
    members = np.zeros((len(xy), blocks.max() + 1))
    members[np.arange(len(xy)), blocks] = 1
    return members / members.sum(axis=0)


# ---------------------------------------------------------------------------------------------
# The paper's family


def hand_table():
    ref = [0.10, 0.12, 0.11, 0.13]
    worse = [0.30, 0.25, 0.28, 0.20]
    rows = [("80", ref), ("5", worse)]
    frames = [
        pd.DataFrame({"P": int(p), "replicate": 0, "point": range(4), "mse": v}) for p, v in rows
    ]
    return pd.concat(frames, ignore_index=True), np.array(ref), np.array(worse)


def test_paper_family_reproduces_a_hand_computed_case_exactly():
    table, ref, worse = hand_table()
    result = paper_family(table).set_index("test")
    # Student's t with P = 80 first: pooled variance, n1 + n2 - 2 degrees of freedom
    pooled = ((ref.var(ddof=1) + worse.var(ddof=1)) / 2) * (1 / 4 + 1 / 4)
    t = (ref.mean() - worse.mean()) / math.sqrt(pooled)
    assert result.loc["t", "statistic"] == pytest.approx(t, rel=1e-12)
    assert result.loc["t", "statistic"] < 0  # the paper's sign: negative when P is worse
    assert result.loc["t", "df"] == 6
    assert result.loc["t", "p_raw"] == pytest.approx(2 * stats.t.sf(abs(t), 6), rel=1e-12)
    # Mann-Whitney U of P = 80: pairs where the reference is larger; exact two-sided p by
    # enumerating every way to split the 8 values into two groups of 4
    u = sum(a > b for a in ref for b in worse)
    assert result.loc["mannwhitney", "statistic"] == u == 0
    values = np.concatenate([ref, worse])
    us = [
        sum(values[i] > values[j] for i in chosen for j in set(range(8)) - set(chosen))
        for chosen in itertools.combinations(range(8), 4)
    ]
    centre = 4 * 4 / 2
    p_exact = np.mean([abs(x - centre) >= abs(u - centre) for x in us])
    assert result.loc["mannwhitney", "p_raw"] == pytest.approx(p_exact, rel=1e-12)
    # One comparison: Bonferroni leaves it; 2/70 = 0.029 is not significant at alpha = 0.01
    assert result.loc["mannwhitney", "p_adjusted"] == result.loc["mannwhitney", "p_raw"]
    assert not result.loc["mannwhitney", "significant"]
    assert result.loc["t", "significant"] and result.loc["t", "conclusion"] == "worse"


def test_paper_family_bonferroni_is_over_the_comparisons_of_each_test_per_replicate():
    rng = np.random.default_rng(3)
    frames = [
        pd.DataFrame({"P": p, "replicate": r, "point": range(40), "mse": rng.normal(1, 0.1, 40)})
        for p in (1, 5, 10, 20, 40, 80)
        for r in range(2)
    ]
    result = paper_family(pd.concat(frames))
    assert len(result) == 5 * 2 * 2  # five P < 80, two tests, two replicates
    assert set(result["correction"]) == {"bonferroni x5"}
    np.testing.assert_allclose(result["p_adjusted"], np.minimum(1, 5 * result["p_raw"]))
    assert sorted(result["replicate"].unique()) == [0, 1]


# ---------------------------------------------------------------------------------------------
# The paired family


def test_paired_test_holds_alpha_under_spatial_correlation_where_the_independent_test_does_not():
    xy = validation_coordinates()
    draws, alpha = 2000, 0.01
    models = simulate(
        xy, draws, 3, {5: 1.0, 80: 1.0}, sd_replicate=0.05, sd_shared=0.3, sd_model=0.2, seed=7
    )
    members = block_matrix(xy)
    means = {p: v @ members for p, v in models.items()}  # (draws, R, K) block means
    _, _, p_paired = difference_test(means[5], means[80])
    paired_rate = float(np.mean(p_paired < alpha))
    independent = stats.ttest_ind(models[80][:, 0], models[5][:, 0], axis=1).pvalue
    independent_rate = float(np.mean(independent < alpha))
    assert abs(paired_rate - alpha) <= 0.01, paired_rate
    assert independent_rate > alpha + 0.1, independent_rate


def test_paired_test_finds_a_known_effect_and_its_interval_covers_the_true_ratio():
    xy = validation_coordinates(seed=1)
    draws, alpha = 1000, 0.01
    models = simulate(
        xy, draws, 5, {5: 1.6, 80: 1.0}, sd_replicate=0.05, sd_shared=0.3, sd_model=0.2, seed=8
    )
    members = block_matrix(xy)
    means = {p: v @ members for p, v in models.items()}
    t, _, p = difference_test(means[5], means[80])
    assert np.mean((p < alpha) & (t > 0)) > 0.8
    # The interval holds the true ratio 1.6 as often as its level says: the contrast at the true
    # ratio is rejected at the rate alpha (test-interval duality)
    estimate, se, df = contrast(means[5], means[80], 1.6)
    rejected = 2 * stats.t.sf(np.abs(estimate / se), df) < alpha
    assert abs(np.mean(rejected) - alpha) <= 0.01


def test_contrast_matches_the_two_way_anova_by_hand():
    d = np.array([[1.0, 2.0, 3.0], [2.0, 3.0, 7.0]])  # replicates x blocks
    estimate, se, df = contrast(d, np.zeros_like(d))
    grand, rows, cols = d.mean(), d.mean(1), d.mean(0)
    ms_r = 3 * rows.var(ddof=1)
    ms_k = 2 * cols.var(ddof=1)
    ms_e = ((d - rows[:, None] - cols[None] + grand) ** 2).sum() / 2
    variance = ms_r + ms_k - ms_e
    assert estimate == pytest.approx(grand)
    assert se == pytest.approx(math.sqrt(variance / 6))
    assert df == pytest.approx(variance**2 / (ms_r**2 / 1 + ms_k**2 / 2 + ms_e**2 / 2))
    # One replicate: a one-sample t over blocks
    one = d[:1]
    estimate, se, df = contrast(one, np.zeros_like(one))
    assert se == pytest.approx(one.std(ddof=1) / math.sqrt(3)) and df == 2


def test_independent_contrast_matches_its_formula_by_hand():
    s = np.array([[1.0, 2.0, 4.0, 3.0], [2.0, 4.0, 5.0, 6.0], [0.5, 1.0, 3.0, 3.5]])
    f = np.array([[1.0, 1.5, 3.0, 2.0], [1.5, 2.5, 3.5, 3.0]])
    theta, blocks = 0.8, 4
    u = s.mean(0) - theta * f.mean(0)
    variance, shares = u.var(ddof=1) / blocks, [(u.var(ddof=1) / blocks, 3.0)]
    for x, weight in ((s, 1.0), (f, theta**2)):
        r = x.shape[0]
        rows, cols = x.mean(1), x.mean(0)
        ms_r = blocks * rows.var(ddof=1)
        ms_e = ((x - rows[:, None] - cols[None] + x.mean()) ** 2).sum() / ((r - 1) * 3)
        assert ms_r > ms_e  # both replicate terms count in this table
        c = weight / (blocks * r)
        variance += c * (ms_r - ms_e)
        shares += [(c * ms_r, r - 1.0), (-c * ms_e, (r - 1.0) * 3)]
    estimate, se, df = independent_contrast(s, f, theta)
    assert estimate == pytest.approx(s.mean() - theta * f.mean())
    assert se == pytest.approx(math.sqrt(variance))
    assert df == pytest.approx(variance**2 / sum(v**2 / d for v, d in shares))


def test_independent_contrast_with_one_run_is_the_paired_contrast_broadcast():
    rng = np.random.default_rng(3)
    one, many = rng.normal(1, 0.2, (1, 6)), rng.normal(1, 0.2, (3, 6))
    for sample, reference, theta in ((one, many, 1.1), (many, one, 0.9)):
        paired = [float(v) for v in contrast(sample, reference, theta)]
        assert independent_contrast(sample, reference, theta) == pytest.approx(paired)
    with pytest.raises(ValueError, match="6 and 5 blocks"):
        independent_contrast(many, many[:, :5])


def test_independent_runs_intervals_cover_at_their_level():
    """Two arms of independent runs (3 and 2; run effects, shared block effects, residuals):
    the interval of the difference of their means holds the true difference at its level, and
    the ratio's Fieller interval the true ratio, where ignoring the runs' spread would not."""
    rng = np.random.default_rng(11)
    draws, blocks, level = 1500, 12, 0.9
    hits, naive, ratios = 0, 0, []
    for _ in range(draws):
        shared = rng.normal(0, 0.3, blocks)
        s = 2.0 + shared + rng.normal(0, 0.25, (3, 1)) + rng.normal(0, 0.1, (3, blocks))
        f = 1.6 + shared + rng.normal(0, 0.15, (2, 1)) + rng.normal(0, 0.1, (2, blocks))
        estimate, se, df = independent_contrast(s, f)
        half = stats.t.ppf(0.5 + level / 2, df) * se
        hits += abs(estimate - 0.4) <= half
        u = s.mean(0) - f.mean(0)
        naive += abs(estimate - 0.4) <= stats.t.ppf(0.5 + level / 2, blocks - 1) * u.std(
            ddof=1
        ) / math.sqrt(blocks)
        if len(ratios) < 300:  # Fieller's search is slower: fewer draws, a wider tolerance
            low, high = ratio_interval(s, f, (1 - level) / 2, independent=True)
            ratios.append(low <= 2.0 / 1.6 <= high)
    assert abs(hits / draws - level) <= 0.03, hits / draws
    assert abs(np.mean(ratios) - level) <= 0.05, np.mean(ratios)
    assert naive / draws < level - 0.1, naive / draws


def test_contrast_is_statsmodels_mixed_model_on_the_same_blocks():
    """The hand-written random-effects contrast against statsmodels' MixedLM on one balanced table
    (REML; replicate and block crossed variance components, the residual its scale): with every
    component positive, REML's estimates are the ANOVA's, so the grand mean, its standard error and
    the components agree."""
    rng = np.random.default_rng(1)
    replicates, blocks = 4, 12
    d = 0.3 + rng.normal(0, 0.5, (replicates, 1)) + rng.normal(0, 0.8, (1, blocks))
    d = d + rng.normal(0, 0.3, (replicates, blocks))
    reference = rng.normal(1.0, 0.2, d.shape)
    estimate, se, _ = contrast(d + 0.9 * reference, reference, 0.9)
    table = pd.DataFrame(
        {
            "d": d.ravel(),
            "replicate": np.repeat(np.arange(replicates), blocks),
            "block": np.tile(np.arange(blocks), replicates),
            "all": 1,
        }
    )
    components = {"replicate": "0 + C(replicate)", "block": "0 + C(block)"}
    model = smf.mixedlm("d ~ 1", table, groups="all", re_formula="0", vc_formula=components)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # one group: statsmodels warns that it is one
        fit = model.fit(reml=True)
    assert estimate == pytest.approx(fit.fe_params.iloc[0], rel=1e-9)
    assert se == pytest.approx(fit.bse_fe.iloc[0], rel=1e-4)
    rows, cols = d.mean(1), d.mean(0)
    ms_e = ((d - rows[:, None] - cols[None] + d.mean()) ** 2).sum() / (3 * 11)
    assert fit.scale == pytest.approx(ms_e, rel=1e-4)
    block_var, replicate_var = fit.vcomp  # statsmodels orders them by name
    assert replicate_var == pytest.approx((blocks * rows.var(ddof=1) - ms_e) / blocks, rel=1e-3)
    assert block_var == pytest.approx((replicates * cols.var(ddof=1) - ms_e) / replicates, rel=1e-3)


def test_one_block_is_refused():
    with pytest.raises(ConfigError, match="one spatial block"):
        contrast(np.ones((3, 1)), np.ones((3, 1)))


def test_holm_adjusts_step_down():
    # by hand: sorted 0.01 x 4, 0.03 x 3, 0.04 x 2 (raised to the 0.09 before it), 0.2 x 1
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.2]), [0.04, 0.09, 0.09, 0.2])
    assert holm([]).size == 0


def test_spatial_blocks_are_equal_cells_at_least_the_given_side():
    xy = validation_coordinates()
    frame = pd.DataFrame({"point": np.arange(len(xy)), "x_mm": xy[:, 0], "y_mm": xy[:, 1]})
    blocks = spatial_blocks(frame, DISC_MM)
    # 11.5 x 15.5 mm of coordinates: 2 x 2 cells of 5.75 x 7.75 mm (three would be < 5.2 mm)
    assert blocks.nunique() == 4
    for _, part in frame.groupby(blocks.to_numpy()):
        assert np.ptp(part["x_mm"]) <= 5.75 + 1e-9 and np.ptp(part["y_mm"]) <= 7.75 + 1e-9
    with pytest.raises(ConfigError, match="positive"):
        spatial_blocks(frame, 0)


# ---------------------------------------------------------------------------------------------
# Equivalence


def block_pair(ratio, noise=0.01, seed=0, replicates=3, blocks=6):
    rng = np.random.default_rng(seed)
    reference = (
        1.0
        + 0.2 * rng.standard_normal((1, blocks))
        + noise * rng.standard_normal((replicates, blocks))
    )
    sample = ratio * reference + noise * rng.standard_normal((replicates, blocks))
    return sample, reference


def test_tost_accepts_a_difference_inside_the_margin_and_rejects_one_outside():
    inside, reference = block_pair(1.04)
    *_, p_inside = tost(inside, reference, 0.10)
    low, high = ratio_interval(inside, reference, 0.05)
    assert p_inside < 0.05 and 0.90 < low < 1.04 < high < 1.10
    outside, reference = block_pair(1.25)
    *_, p_outside = tost(outside, reference, 0.10)
    low, high = ratio_interval(outside, reference, 0.05)
    assert p_outside > 0.05 and low > 1.10
    below, reference = block_pair(0.8)
    *_, p_below = tost(below, reference, 0.10)
    assert p_below > 0.05


def test_tost_calls_equivalence_at_the_margin_no_more_often_than_alpha():
    xy = validation_coordinates(seed=2)
    models = simulate(
        xy, 1000, 3, {20: 1.1, 80: 1.0}, sd_replicate=0.02, sd_shared=0.3, sd_model=0.1, seed=9
    )
    members = block_matrix(xy)
    *_, p = tost(models[20] @ members, models[80] @ members, 0.10)
    assert np.mean(p < 0.05) <= 0.05 + 0.015


def test_the_interval_and_the_tost_agree():
    for ratio in (0.95, 1.02, 1.08, 1.12):
        sample, reference = block_pair(ratio, noise=0.03, seed=4)
        *_, p = tost(sample, reference, 0.10)
        low, high = ratio_interval(sample, reference, 0.05)
        assert (p < 0.05) == (0.90 < low and high < 1.10), ratio


def test_tost_margin_must_be_a_fraction():
    with pytest.raises(ConfigError, match="margin"):
        tost(np.ones((2, 3)), np.ones((2, 3)), 1.5)


# ---------------------------------------------------------------------------------------------
# tests.csv and the recommendation


def study_table(ratios, seed=0, replicates=3, noise=0.02):
    """validation_mse.csv of a study whose P has mean MSE ratio `ratios[P]` against P = 80."""
    xy = validation_coordinates(seed=seed)
    rng = np.random.default_rng(seed)
    shared = 1.0 + 0.3 * np.sin(xy[:, 0] / 2) * np.cos(xy[:, 1] / 3)
    rows = []
    for p, ratio in {**ratios, 80: 1.0}.items():
        for r in range(replicates):
            mse = ratio * shared + noise * rng.standard_normal(len(xy))
            rows.append(
                pd.DataFrame(
                    {"P": p, "replicate": r, "point": np.arange(len(xy)), "mse": mse}
                ).assign(x_mm=xy[:, 0], y_mm=xy[:, 1])
            )
    table = pd.concat(rows, ignore_index=True)
    return table, spatial_blocks(table, DISC_MM)


POINTS = {1: 12, 5: 61, 10: 122, 20: 244, 40: 488, 80: 976}


def test_tests_csv_has_the_three_families_and_their_corrections():
    table, blocks = study_table({1: 3.0, 5: 1.5, 10: 1.2, 20: 1.03, 40: 1.0})
    tests = ablation_tests(table, blocks)
    assert set(tests["family"]) == {"paper", "paired", "equivalence", "placebo"}
    paired = tests[tests["family"] == "paired"].set_index("P")
    assert set(paired["correction"]) == {"holm x5"}
    np.testing.assert_allclose(
        paired["p_adjusted"].sort_index(), holm(paired["p_raw"].sort_index())
    )
    assert paired.loc[1, "conclusion"] == "worse" and paired.loc[1, "blocks"] == 4
    assert paired.loc[1, "relative_change"] == pytest.approx(2.0, rel=0.01)
    equivalence = tests[tests["family"] == "equivalence"].set_index("P")
    # fixed sequence: the adjusted p is the running maximum from the largest P down
    running = np.maximum.accumulate(equivalence["p_raw"].sort_index(ascending=False))
    np.testing.assert_allclose(equivalence["p_adjusted"], running.reindex(equivalence.index))


def test_recommendation_names_the_smallest_equivalent_fraction_with_margin_and_interval():
    table, blocks = study_table({1: 3.0, 5: 1.5, 10: 1.2, 20: 1.03, 40: 1.0})
    line = recommend(ablation_tests(table, blocks), POINTS, margin=0.10)
    assert line.startswith("probe at least 244 points: P = 20 % is equivalent to P = 80 %")
    assert "within a 10 % margin of mean validation MSE" in line
    assert "90 % interval, TOST at alpha = 0.05; 3 replicate(s), 4 spatial blocks" in line
    assert "P = 10 % is not (+20." in line and "worse by more than the margin" in line


def test_recommendation_when_the_smallest_fraction_is_equivalent():
    table, blocks = study_table({5: 1.01, 40: 1.0})
    line = recommend(ablation_tests(table, blocks), POINTS)
    assert line.startswith("probe at least 61 points: P = 5 % is equivalent")
    assert "is not" not in line


def test_recommendation_when_every_fraction_is_worse_says_so():
    table, blocks = study_table({20: 1.5, 40: 1.3})
    line = recommend(ablation_tests(table, blocks), POINTS)
    assert line.startswith("probe at least 976 points (P = 80 %): no smaller fraction is shown")
    assert "P = 40 %: change +30.0 %" in line and "worse by more than the margin" in line


def test_recommendation_when_the_design_lacks_power_says_so():
    table, blocks = study_table({20: 1.2, 40: 1.02}, noise=0.6, replicates=2)
    line = recommend(ablation_tests(table, blocks), POINTS)
    assert line.startswith("probe at least 976 points (P = 80 %): no smaller fraction")
    assert "lacks the power to show equivalence (the interval reaches past the margin" in line
    assert "stats/power.csv: the replicates and validation points it needs" in line


NARROW = "the interval reaches past the margin on the {} side (too little power)"


@pytest.mark.parametrize(
    "change, low, high, reason",
    [
        # the Mini's P = 40 % of one default study: inside the margin, crossing its lower bound
        (-0.076, -0.13, -0.012, NARROW.format("better")),
        (0.06, 0.02, 0.14, NARROW.format("worse")),
        (0.0, -0.12, 0.12, "the interval is wider than the margin allows (too little power)"),
        (0.0, -0.10, 0.05, "the interval ends on the margin (too little power)"),
        (-0.12, -0.15, -0.05, "the estimate lies past the margin on the better side"),
        (0.12, 0.05, 0.16, "the estimate lies past the margin on the worse side"),
        (0.15, 0.11, 0.2, "worse by more than the margin"),
        (-0.2, -0.3, -0.12, "better by more than the margin"),
    ],
)
def test_a_not_equivalent_conclusion_names_the_bound_crossed(change, low, high, reason):
    """Not equivalent, and why: which bound the interval crosses, and power only where the
    estimate lies inside the margin (more replicates or points would narrow the interval)."""
    conclusion = _equivalence_conclusion(False, False, change, low, high, 0.10)
    assert conclusion == f"not equivalent: {reason}"


def test_recommendation_names_the_bound_a_narrow_interval_crosses():
    """An estimate 8 % better than P = 80 %, its interval crossing the lower bound only: the
    line says which bound beside the lack of power (before: power alone)."""
    table, blocks = study_table({20: 1.2, 40: 0.92}, noise=0.1)
    tests = ablation_tests(table, blocks)
    forty = tests[(tests["family"] == "equivalence") & (tests["P"] == 40)].iloc[0]
    assert forty["ci_low"] < -0.10 < forty["ci_high"] < 0.10
    assert -0.10 < forty["relative_change"] < 0
    line = recommend(tests, POINTS)
    assert line.startswith("probe at least 976 points (P = 80 %): no smaller fraction")
    assert (
        "the design lacks the power to show equivalence (the interval reaches past the margin "
        "on the better side; stats/power.csv" in line
    )


def test_missing_reference_non_finite_and_unpaired_models_are_refused():
    table, blocks = study_table({20: 1.0})
    with pytest.raises(ConfigError, match="reference fraction P=80"):
        ablation_tests(table[table["P"] != 80], blocks)
    broken = table.copy()
    broken.loc[0, "mse"] = np.nan
    with pytest.raises(ConfigError, match="non-finite"):
        block_means(broken, blocks)
    with pytest.raises(ConfigError, match="same replicates"):
        ablation_tests(table[~((table["P"] == 20) & (table["replicate"] == 2))], blocks)


# ---------------------------------------------------------------------------------------------
# Power


def test_fit_correlation_recovers_a_known_range_and_nugget():
    xy = validation_coordinates()
    rng = np.random.default_rng(5)
    fields = list((field_factor(xy, 2.0, 0.25) @ rng.standard_normal((len(xy), 60))).T)
    range_mm, nugget = fit_correlation(fields, xy)
    assert range_mm == pytest.approx(2.0, rel=0.35) and nugget == pytest.approx(0.25, abs=0.1)


def test_variance_components_recover_the_simulated_ones():
    xy = validation_coordinates()
    models = simulate(
        xy, 1, 8, {20: 1.0, 80: 1.0}, sd_replicate=0.1, sd_shared=0.3, sd_model=0.2, seed=11
    )
    components, range_mm, nugget = variance_components(as_table(xy, models))
    row = components.set_index("P").loc[20]
    assert row["sd_model"] == pytest.approx(0.2, rel=0.2)
    assert row["sd_shared"] == pytest.approx(0.3, rel=0.5)
    assert row["kappa"] > 0.8  # both models share the field
    assert range_mm == pytest.approx(RANGE_MM, rel=0.5)


def test_power_table_grows_with_replicates_and_keeps_false_positives_near_alpha():
    xy = validation_coordinates()
    models = simulate(
        xy, 1, 3, {20: 1.0, 80: 1.0}, sd_replicate=0.05, sd_shared=0.3, sd_model=0.2, seed=12
    )
    power = power_table(as_table(xy, models), DISC_MM, GRID_MM, simulations=400, seed=1)
    assert set(power["spacing_mm"]) == {0.25, 0.5, 1.0}
    assert set(power["replicates"]) == {1, 2, 3, 5, 10}
    assert power["observed"].sum() == 1
    own = power[power["spacing_mm"] == 0.5].set_index("replicates")
    assert own.loc[10, "power_equivalence"] > own.loc[2, "power_equivalence"]
    assert own.loc[10, "power_detect"] > own.loc[2, "power_detect"]
    replicated = power[power["replicates"] >= 2]
    assert (replicated["false_positive_rate"] <= 0.01 + 0.015).all()
    assert (replicated["false_equivalence_rate"] <= 0.05 + 0.03).all()
    assert needed_design(power, 20).startswith(("none", "2 ", "3 ", "5 ", "10 "))


def test_the_design_named_is_never_one_replicate_whose_test_is_too_liberal():
    """Repro: the summary named "best: 8% with 1 replicates" for the Mini's P = 40 %, a design whose
    test rejected 45 % of true nulls; one replicate cannot see the replicate variance."""
    rows = [
        {
            "P": 40,
            "replicates": r,
            "spacing_mm": 0.38,
            "validation_points": 408,
            "power_equivalence": power,
            "false_positive_rate": fp,
        }
        for r, power, fp in ((1, 0.9, 0.45), (2, 0.3, 0.01), (3, 0.5, 0.01), (5, 0.85, 0.01))
    ]
    power = pd.DataFrame(rows)
    assert needed_design(power, 40) == "5 replicates at 0.38 mm (408 validation points): 85%"
    weak = power[power["replicates"] < 5]
    assert needed_design(weak, 40) == (
        "none of the simulated designs (best: 50% with 3 replicates at 0.38 mm)"
    )
    assert needed_design(power[power["replicates"] == 1], 40) == "—"


def test_placebo_runs_the_papers_tests_between_trainings_of_the_same_fraction():
    """The paper's tests between replicates of P = 80 (no effect of P by construction): each pair
    judged exactly as one of the paper's comparisons, so a rejection is training noise read as an
    effect."""
    table, blocks = study_table({1: 3.0, 5: 1.5}, replicates=3)
    placebo = ablation_tests(table, blocks).query("family == 'placebo'")
    assert sorted(zip(placebo["against"], placebo["replicate"], strict=True)) == [
        (0, 1),
        (0, 1),
        (0, 2),
        (0, 2),
        (1, 2),
        (1, 2),
    ]
    assert set(placebo["P"]) == {80} and set(placebo["correction"]) == {"bonferroni x2"}
    wide = table[table["P"] == 80].pivot(index="replicate", columns="point", values="mse")
    t = placebo.query("test == 't' and against == 0 and replicate == 2").iloc[0]
    expected = stats.ttest_ind(wide.loc[0], wide.loc[2], equal_var=True)
    assert t["statistic"] == pytest.approx(expected.statistic)
    assert t["p_adjusted"] == pytest.approx(min(1.0, 2 * expected.pvalue))
    # same distribution: no pair flagged; one replicate's model 15 % worse everywhere: flagged
    assert not placebo["significant"].any()
    worse = table.assign(
        mse=np.where((table["P"] == 80) & (table["replicate"] == 2), 1.15, 1.0) * table["mse"]
    )
    flagged = ablation_tests(worse, blocks).query("family == 'placebo' and significant")
    assert set(zip(flagged["against"], flagged["replicate"], strict=True)) == {(0, 2), (1, 2)}
    assert set(flagged["conclusion"]) == {"worse"}
    # one replicate: no pair, no row
    single, single_blocks = study_table({1: 3.0}, replicates=1)
    one = ablation_tests(single, single_blocks)
    assert "placebo" not in set(one["family"])
    # and the missing family leaves the columns numbers (tests.csv keeps its float format)
    assert pd.api.types.is_float_dtype(one["estimate"]) and pd.api.types.is_integer_dtype(one["P"])
    assert pd.api.types.is_bool_dtype(one["significant"])


def test_the_tests_figure_cuts_intervals_at_its_axis_and_writes_their_true_bounds(tmp_path):
    """A paired interval of -189 % to +4,293 % is drawn to the axis's edges with both values written
    beside them; an interval inside the axis and a NaN bound are left as they are."""
    cut = interval_on_axis([-1.89, -0.2, np.nan], [42.93, 0.3, 0.1])
    assert cut["low"][0] == AXIS_RATIO[0] and cut["high"][0] == AXIS_RATIO[1]
    assert (cut["below"][0], cut["above"][0]) == ("-189 %", "+4,293 %")
    assert cut["low"][1] == pytest.approx(0.8) and cut["high"][1] == pytest.approx(1.3)
    assert cut["below"][1:] == ["", ""] and cut["above"][1:] == ["", ""]
    assert np.isnan(cut["low"][2]) and cut["high"][2] == pytest.approx(1.1)
    table, blocks = study_table({1: 3.0, 5: 1.5}, replicates=3)
    tests = ablation_tests(table, blocks)
    paired = tests.index[tests["family"] == "paired"]
    tests.loc[paired, ["ci_low", "ci_high"]] = [-1.89, 42.93]  # as wide as the Mini's were
    out = tmp_path / "tests.png"
    ablation_figure.tests_figure(tests, out, "cut", margin=0.1)
    assert out.stat().st_size > 10_000


def test_arms_that_do_not_differ_at_all_give_no_change_and_a_point_interval():
    base = np.random.default_rng(3).uniform(0.01, 0.02, (4, 6))
    t, _, p = difference_test(base, base)
    assert float(t) == 0.0 and float(p) == pytest.approx(1.0)
    low, high = ratio_interval(base, base, 0.025)
    assert low == pytest.approx(1.0, abs=1e-8) and high == pytest.approx(1.0, abs=1e-8)
    low, high = ratio_interval(0.95 * base, base, 0.025)  # an exact 5 % drop everywhere
    assert low == pytest.approx(0.95, abs=1e-8) and high == pytest.approx(0.95, abs=1e-8)
