"""What the ablation's tests say, in words: the recommendation (`recommend`: the smallest P
equivalent to P = 80 %, or why none is), the families side by side (`family_comparison`) and the
placebo's line (`placebo_summary`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import EQUIVALENCE_ALPHA, MARGIN, PAPER_TESTS, REFERENCE_P


def _pct(value: float) -> str:
    if not np.isfinite(value):
        return "+inf" if value > 0 else "-inf"
    return f"{value * 100:+.1f} %"


def _interval(row) -> str:
    return f"{_pct(row['ci_low'])} to {_pct(row['ci_high'])}"


def recommend(
    tests: pd.DataFrame,
    n_points_by_p: Mapping[int, int],
    margin: float = MARGIN,
    equivalence_alpha: float = EQUIVALENCE_ALPHA,
    reference: int = REFERENCE_P,
) -> str:
    """'Probe at least N points': the smallest P shown equivalent to the reference (TOST within
    +-margin of its mean validation MSE, fixed sequence), with its interval — or why none is."""
    rows = tests[tests["family"] == "equivalence"].set_index("P").sort_index()
    if rows.empty:
        raise ConfigError("the recommendation needs the equivalence family of tests.csv")
    first = rows.iloc[0]
    design = (
        f"{(1 - 2 * equivalence_alpha) * 100:.0f} % interval, TOST at alpha = "
        f"{equivalence_alpha:g}; {int(first['replicates'])} replicate(s), "
        f"{int(first['blocks'])} spatial blocks"
    )
    equivalent = rows[rows["significant"].astype(bool)]
    if not equivalent.empty:
        best = int(equivalent.index.min())
        row = rows.loc[best]
        text = (
            f"probe at least {n_points_by_p[best]} points: P = {best} % is equivalent to "
            f"P = {reference} % within a {margin * 100:.0f} % margin of mean validation MSE "
            f"(change {_pct(row['relative_change'])}, interval {_interval(row)}; {design})"
        )
        smaller = rows[rows.index < best]
        if not smaller.empty:
            below = smaller.iloc[-1]
            text += (
                f"; P = {int(smaller.index[-1])} % is not ({_pct(below['relative_change'])}, "
                f"{_interval(below)}: {below['conclusion'].removeprefix('not equivalent: ')})"
            )
        return text
    largest = rows.iloc[-1]
    p = int(rows.index[-1])
    reason = largest["conclusion"].removeprefix("not equivalent: ")
    why = reason
    if "power" in reason:
        where = "" if "wider" in reason else reason.removesuffix(" (too little power)") + "; "
        why = (
            f"the design lacks the power to show equivalence ({where}stats/power.csv: the "
            "replicates and validation points it needs)"
        )
    return (
        f"probe at least {n_points_by_p[reference]} points (P = {reference} %): no smaller fraction "
        f"is shown equivalent within a {margin * 100:.0f} % margin of mean validation MSE; "
        f"P = {p} %: change {_pct(largest['relative_change'])}, interval {_interval(largest)} — "
        f"{why} ({design})"
    )


def family_comparison(tests: pd.DataFrame) -> pd.DataFrame:
    """Per P: the paper family's verdicts over replicates, the paired test and the TOST side by
    side, and whether they agree (the report shows disagreements with their numbers)."""
    paper = tests[tests["family"] == "paper"]
    paired = tests[tests["family"] == "paired"].set_index("P")
    equivalence = tests[tests["family"] == "equivalence"].set_index("P")
    rows = []
    for p in sorted(paired.index):
        part = paper[paper["P"] == p]
        replicates = part["replicate"].nunique()
        significant = part["significant"].astype(bool)
        counts = {name: int(significant[part["test"] == name].sum()) for name in PAPER_TESTS}
        worse = significant & (part["conclusion"] == "worse")
        # the paper's verdict "worse": both tests, in most replicates; "none": no test anywhere
        paper_worse = all(
            int(worse[part["test"] == name].sum()) * 2 > replicates for name in PAPER_TESTS
        )
        paper_none = not significant.any()
        pair, eq = paired.loc[p], equivalence.loc[p]
        paired_worse = bool(pair["significant"]) and pair["estimate"] > 0
        equivalent = bool(eq["significant"])
        if paper_worse and paired_worse or paper_none and equivalent:
            agreement = "agree"
        elif paper_worse:
            agreement = (
                "disagree: the paper's tests find P worse, the paired test does not "
                f"(p = {pair['p_adjusted']:.3g} after Holm)"
            )
        elif paired_worse:
            agreement = (
                "disagree: the paired test finds P worse "
                f"({_pct(pair['relative_change'])}, p = {pair['p_adjusted']:.3g} after Holm), "
                "the paper's tests not in most replicates"
            )
        elif paper_none:
            agreement = (
                "disagree: the paper's tests find no difference, yet equivalence is not shown "
                f"(interval {_interval(eq)})"
            )
        else:
            agreement = "mixed: the paper's tests split over replicates"
        rows.append(
            {
                "P": p,
                "paper_t": f"{counts['t']}/{replicates}",
                "paper_u": f"{counts['mannwhitney']}/{replicates}",
                "change": _pct(pair["relative_change"]),
                "paired": f"{pair['conclusion']} (p = {pair['p_adjusted']:.3g}, "
                f"interval {_interval(pair)})",
                "equivalence": f"{eq['conclusion']} (interval {_interval(eq)})",
                "agreement": agreement,
            }
        )
    return pd.DataFrame(rows)


def placebo_summary(tests: pd.DataFrame, short: bool = False) -> str | None:
    """One line on the placebo family: how often the paper's tests call two trainings of the
    reference fraction different, and by how much their means differ; None without replicates.
    `short`: the figure's footnote."""
    rows = tests[tests["family"] == "placebo"]
    if rows.empty:
        return None
    pairs = len(rows.drop_duplicates(["against", "replicate"]))
    t, u = (
        int(rows.loc[rows["test"] == name, "significant"].astype(bool).sum())
        for name in PAPER_TESTS
    )
    change = np.abs(rows["relative_change"].to_numpy(float)) * 100
    low, high = f"{change.min():.1f}", f"{change.max():.1f}"
    reference = int(rows["P"].iloc[0])
    if short:
        apart = low if low == high else f"{low}-{high}"
        return (
            f"placebo: the paper's tests call two trainings of P = {reference} % different in "
            f"{t}/{pairs} (t) and {u}/{pairs} (U) pairs; means {apart} % apart"
        )
    return (
        f"the paper's tests between two trainings of P = {reference} % (the same fraction: no "
        f"effect of P): t significant in {t} of {pairs} pairs, U in {u} of {pairs}; their mean "
        f"MSE differ by {low if low == high else f'{low} to {high}'} %"
    )
