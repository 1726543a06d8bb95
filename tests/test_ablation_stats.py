import numpy as np
import pytest
from scipy import stats

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import compare_fractions, recommend


def samples(seed=0):
    rng = np.random.default_rng(seed)
    return {
        1: rng.normal(5.0, 1.0, 80),  # clearly worse
        5: rng.normal(3.0, 1.0, 80),  # clearly worse
        20: rng.normal(1.0, 1.0, 80),  # same distribution as the reference
        80: rng.normal(1.0, 1.0, 80),
    }


def test_statistics_agree_with_scipy():
    data = samples()
    table = compare_fractions(data)
    row = table[(table.P == 5) & (table.test == "t")].iloc[0]
    expected = stats.ttest_ind(data[5], data[80], equal_var=False, alternative="greater")
    assert row.statistic == pytest.approx(expected.statistic) and row.p_raw == pytest.approx(
        expected.pvalue
    )
    row = table[(table.P == 20) & (table.test == "mannwhitney")].iloc[0]
    expected = stats.mannwhitneyu(data[20], data[80], alternative="greater")
    assert row.statistic == pytest.approx(expected.statistic) and row.p_raw == pytest.approx(
        expected.pvalue
    )


def test_bonferroni_factor_is_the_number_of_comparisons():
    table = compare_fractions(samples())
    n = 3 * 2  # three fractions below 80 × two tests
    assert len(table) == n
    np.testing.assert_allclose(table.p_bonferroni, np.minimum(1, table.p_raw * n))


def test_known_outcomes():
    table = compare_fractions(samples())
    significant = table.groupby("P").significant.all().to_dict()
    assert significant[1] and significant[5] and not significant[20]


def test_recommendation_is_the_smallest_not_worse_fraction():
    table = compare_fractions(samples())
    line = recommend(table, {1: 4, 5: 20, 20: 80, 80: 320})
    assert line.startswith("probe at least 80 points (P = 20 %")


def test_when_every_smaller_fraction_is_worse_the_reference_is_recommended_and_says_why():
    rng = np.random.default_rng(2)
    table = compare_fractions(
        {p: rng.normal(mean, 0.1, 60) for p, mean in ((5, 0.2), (40, 0.15), (80, 0.1))}
    )
    line = recommend(table, {5: 20, 40: 160, 80: 320})
    assert line.startswith("probe at least 320 points (P = 80 %: P = 40 % is already significantly")


def test_a_better_small_fraction_is_not_significant_one_sided():
    rng = np.random.default_rng(1)
    table = compare_fractions({10: rng.normal(0.0, 1, 50), 80: rng.normal(2.0, 1, 50)})
    assert not table.significant.any()


def test_missing_reference_or_too_few_values_is_an_error():
    with pytest.raises(ConfigError, match="reference fraction P=80"):
        compare_fractions({5: [1, 2, 3]})
    with pytest.raises(ConfigError, match="P=5: needs at least 2"):
        compare_fractions({5: [1.0, np.nan], 80: [1, 2, 3]})
