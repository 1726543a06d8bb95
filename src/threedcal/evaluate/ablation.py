"""Ablation statistics (paper Sec. III-A): is a model trained on P % of the probe points worse than
the one trained on all of them (P = 80 %)?

Each P yields one validation MSE per validation coordinate. Each P < 80 is compared with P = 80 by an
independent-samples t-test and a Mann-Whitney U test. "Worse" is one-sided (greater MSE), as the
question is; p-values are Bonferroni-corrected over every comparison made (tests × fractions) and
judged at α = 0.01.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy import stats

from threedcal.errors import ConfigError

ALPHA = 0.01
REFERENCE_P = 80
TESTS = ("t", "mannwhitney")


def _test(name: str, sample: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    if name == "t":
        result = stats.ttest_ind(sample, reference, equal_var=False, alternative="greater")
    elif name == "mannwhitney":
        result = stats.mannwhitneyu(sample, reference, alternative="greater", method="auto")
    else:
        raise ConfigError(f"unknown test {name!r} (allowed: {', '.join(TESTS)})")
    return float(result.statistic), float(result.pvalue)


def compare_fractions(
    mse_by_p: Mapping[int, Sequence[float]],
    reference: int = REFERENCE_P,
    tests: Sequence[str] = TESTS,
    alpha: float = ALPHA,
) -> pd.DataFrame:
    """Table with columns P, test, statistic, p_raw, p_bonferroni, significant (one row per P < reference × test)."""
    if reference not in mse_by_p:
        raise ConfigError(
            f"the ablation needs the reference fraction P={reference}; have {sorted(mse_by_p)}"
        )
    ref = _finite(mse_by_p[reference], reference)
    others = sorted(p for p in mse_by_p if p != reference)
    n_comparisons = len(others) * len(tests)
    rows = []
    for p in others:
        sample = _finite(mse_by_p[p], p)
        for name in tests:
            statistic, p_raw = _test(name, sample, ref)
            p_adj = min(1.0, p_raw * n_comparisons)
            rows.append(
                {
                    "P": p,
                    "test": name,
                    "statistic": statistic,
                    "p_raw": p_raw,
                    "p_bonferroni": p_adj,
                    "significant": bool(p_adj < alpha),
                }
            )
    return pd.DataFrame(
        rows, columns=["P", "test", "statistic", "p_raw", "p_bonferroni", "significant"]
    )


def _finite(values: Sequence[float], p: int) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    array = array[np.isfinite(array)]
    if array.size < 2:
        raise ConfigError(f"P={p}: needs at least 2 finite validation errors, got {array.size}")
    return array


def recommend(
    table: pd.DataFrame, n_points_by_p: Mapping[int, int], reference: int = REFERENCE_P
) -> str:
    """'Probe at least N points': the smallest P not significantly worse than the reference in any test,
    such that every larger P is not significantly worse either."""
    worse = table.groupby("P")["significant"].any() if len(table) else pd.Series(dtype=bool)
    candidates = sorted(set(n_points_by_p) | {reference})
    best = reference
    for p in reversed(candidates):
        if p == reference or not worse.get(p, False):
            best = p
        else:
            break
    smaller = [p for p in candidates if p < best]
    if best == reference and smaller:
        return (
            f"probe at least {n_points_by_p[best]} points (P = {reference} %: P = {smaller[-1]} % "
            f"is already significantly worse at alpha = {ALPHA}, Bonferroni-corrected)"
        )
    return (
        f"probe at least {n_points_by_p[best]} points (P = {best} % is not significantly worse than "
        f"P = {reference} % at alpha = {ALPHA}, Bonferroni-corrected)"
    )
