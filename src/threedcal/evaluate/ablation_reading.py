"""What the ablation's tests say, in words: the recommendation (`recommend`: the smallest P
equivalent to P = 80 %, or why none is), the families side by side (`family_comparison`), the
placebo's line (`placebo_summary`), the learning curve's answer (`curve_sentence`) and where it
and the TOST differ, why (`readings_compared`); `read_validation_errors` composes them all."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import (
    ALPHA,
    EQUIVALENCE_ALPHA,
    MARGIN,
    PAPER_TESTS,
    REFERENCE_P,
    ablation_tests,
)
from threedcal.evaluate.learning_curve import (
    BOOTSTRAP,
    FLAT,
    NOT_FITTED,
    LearningCurve,
    learning_curve,
)
from threedcal.evaluate.power_law_fit import EXPONENTS, LACK_OF_FIT_P, OFF_CURVE


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


# ---------------------------------------------------------------------------------------------
# The learning curve in words, and the two readings side by side


def _points(value: float) -> str:
    return f"{int(value):,}"


def _fractions_listed(fractions) -> str:
    return ", ".join(str(int(p)) for p in fractions)


def _neighbours(curve: LearningCurve, points: float) -> str:
    """'between P = 20 % (244) and P = 40 % (488)': the measured fractions around `points`."""
    frame = curve.fractions.sort_values("points")
    below = frame[frame["points"] < points]
    above = frame[frame["points"] >= points]
    if below.empty or above.empty:
        return ""
    low, high = below.iloc[-1], above.iloc[0]
    if high["points"] == points:
        return f"P = {int(high['P'])} % has {_points(points)}"
    return (
        f"between P = {int(low['P'])} % ({_points(low['points'])}) and "
        f"P = {int(high['P'])} % ({_points(high['points'])})"
    )


def answer_interval(low: float, high: float, smallest: int, level: float) -> str:
    """'90 % interval 86 to 141'; a low end at the smallest fraction fitted is 'at or below' it,
    and so is a whole interval there ('90 % interval at or below 122')."""
    if high <= smallest:
        return f"{level * 100:g} % interval at or below {_points(smallest)}"
    start = f"at or below {_points(smallest)}" if low <= smallest else _points(low)
    return f"{level * 100:g} % interval {start} to {_points(high)}"


def _curve_interval(curve: LearningCurve) -> str:
    return answer_interval(curve.answer_low, curve.answer_high, curve.smallest_points, curve.level)


def _relative_to_reference(curve: LearningCurve, points: float) -> float:
    return float(curve.predict(points) / curve.predict(curve.reference_points) - 1.0)


def curve_sentence(curve: LearningCurve) -> str:
    """The learning curve's answer in one line: the fewest points within the margin, with its
    interval, how it was fitted, and what limits it (a flat curve, fractions before the power law
    holds, interpolation between the two largest fractions, a fraction off the curve, a poor fit,
    one replicate)."""
    if curve.status == NOT_FITTED:
        return f"learning curve not fitted: {curve.reason}"
    frame = curve.fractions
    fitted = frame[frame["in_fit"].astype(bool)]
    c = curve.parameters["c"]
    smallest = fitted.iloc[0]
    margin = f"{curve.margin * 100:g} %"
    left_out = curve.left_out
    shape = (
        "flat: b = 0"
        if curve.parameters["b"][0] == 0
        else f"c = {c[0]:.2f}, interval {c[1]:.2f} to {c[2]:.2f}"
    )
    how = (
        f"MSE(n) = a + b·(n / {_points(curve.reference_points)})^-c fitted on P = "
        f"{_fractions_listed(fitted['P'])} % ({shape}), each fraction weighted by its own "
        f"spread, Huber loss; {curve.bootstrap} bootstrap draws of {curve.replicates} "
        f"replicate(s) and {curve.blocks} spatial blocks"
    )
    if left_out:
        how += (
            f"; P = {_fractions_listed(left_out)} % left out: a power law through "
            f"{'it' if len(left_out) == 1 else 'them'} misses the larger fractions' means (a "
            "learning curve follows one only past its small-data region)"
        )
    measured = "the smallest fraction the curve describes" if left_out else "the smallest measured"
    if curve.status == FLAT:
        text = (
            f"learning curve: at or below {_points(curve.answer)} points (P = {int(smallest['P'])} "
            f"%, {measured}; the curve is not extrapolated below it): it predicts every fraction "
            f"it describes within {margin} of P = {curve.reference} %'s mean validation MSE "
            f"({_curve_interval(curve)} points); {how}"
        )
    else:
        where = _neighbours(curve, curve.answer)
        text = (
            f"learning curve: {_points(curve.answer)} points ({_curve_interval(curve)}) bring the "
            f"predicted mean validation MSE within {margin} of P = {curve.reference} %'s "
            f"({_points(curve.reference_points)} points)"
            + (f", {where}" if where else "")
            + f"; {how}"
        )
        below = frame[frame["P"] != curve.reference]
        if len(below) and curve.answer > below["points"].max():
            largest = below.loc[below["points"].idxmax()]
            text += (
                f"; no fraction measured below P = {curve.reference} % is within the margin: the "
                f"number rests on the curve between P = {int(largest['P'])} % and "
                f"P = {curve.reference} %"
            )
    reference_mse = frame.set_index("P").loc[curve.reference, "mean_mse"]
    for row in fitted.itertuples():
        if row.huber < OFF_CURVE and row.P != curve.reference:
            observed = row.mean_mse / reference_mse - 1
            text += (
                f"; P = {row.P} % lies off the curve (observed {_pct(observed)}, curve "
                f"{_pct(_relative_to_reference(curve, row.points))} of P = {curve.reference} %) "
                "and weighs less in the fit"
            )
    if curve.lack_of_fit_p < LACK_OF_FIT_P:
        text += (
            f"; the curve misses the fractions' means by more than their spread (chi-squared "
            f"{curve.chi2:.1f} on {curve.dof} degrees of freedom, {_p_text(curve.lack_of_fit_p)}): "
            "read the number with care"
        )
    if c[0] >= EXPONENTS[-1] * 0.999:
        text += "; the exponent sits at its search limit: the curve is a step, flat past it"
    if curve.replicates == 1:
        text += (
            "; one replicate: the interval holds the spatial sampling only, not the training's "
            "own randomness"
        )
    return text


def _tost_reason(row, curve: LearningCurve, p: int) -> str:
    """Why the TOST of P is not equivalent, in words with its numbers and its replicates' spread."""
    conclusion = str(row["conclusion"]).removeprefix("not equivalent: ")
    numbers = f"change {_pct(row['relative_change'])}, interval {_interval(row)}"
    if "wider than the margin" in conclusion:
        text = f"the TOST of P = {p} % is too wide to show equivalence ({numbers})"
    else:
        text = f"the TOST of P = {p} % is not equivalent: {conclusion} ({numbers})"
    if curve.replicates > 1:
        spread = curve.fractions.set_index("P").loc[p]
        width = (spread["replicate_high"] - spread["replicate_low"]) / spread["mean_mse"]
        text += (
            f": its {curve.replicates} replicates' mean MSE spread from "
            f"{spread['replicate_low']:.3g} to {spread['replicate_high']:.3g} "
            f"({width * 100:.0f} % of their mean)"
        )
    return text


def _p_text(p: float) -> str:
    return f"p = {p:.2g}" if p >= 1e-4 else "p < 0.0001"


def _misfit(curve: LearningCurve) -> str:
    """'' where the power law describes the fractions fitted, else the words that say it does not."""
    if not curve.lack_of_fit_p < LACK_OF_FIT_P:
        return ""
    return (
        "; but a power law does not describe these fractions (chi-squared "
        f"{_p_text(curve.lack_of_fit_p)})"
    )


def _fitted_on(curve: LearningCurve) -> str:
    """'fitted on every fraction' or 'fitted on P = 10-80 %'."""
    if not curve.left_out:
        return "fitted on every fraction"
    fitted = curve.fractions.loc[curve.fractions["in_fit"].astype(bool), "P"]
    return f"fitted on P = {_fractions_listed(fitted)} %"


def readings_compared(
    tests: pd.DataFrame, curve: LearningCurve, points_by_p: Mapping[int, int]
) -> str | None:
    """Whether the TOST's fixed sequence and the learning curve agree on the points to probe,
    and where they do not, why; None where the curve was not fitted.

    They agree where the TOST's fraction lies inside the curve's interval, or where the curve's
    interval lies between that fraction and the next smaller one (the TOST can only name the
    fractions measured). They differ where the curve says a smaller measured fraction may suffice
    (its points reach the curve's interval), or where the TOST's fraction lies below it."""
    if curve.status == NOT_FITTED:
        return None
    rows = tests[tests["family"] == "equivalence"].set_index("P").sort_index()
    equivalent = rows[rows["significant"].astype(bool)]
    reference = curve.reference
    tost_p = int(equivalent.index.min()) if not equivalent.empty else reference
    tost_n = points_by_p[tost_p]
    says = (
        f"the TOST says {_points(tost_n)} points (P = {tost_p} %), the curve "
        f"{_points(curve.answer)} ({_curve_interval(curve)})"
    )
    low = -math.inf if curve.low_censored else curve.answer_low
    smaller = rows.index[rows.index < tost_p]
    stop = int(smaller.max()) if len(smaller) else None
    if low <= tost_n <= curve.answer_high:
        return f"the two readings agree: {says}"
    if tost_n > curve.answer_high and (stop is None or points_by_p[stop] < low):
        return (
            f"the two readings agree: {says}, which lies between P = {stop} % "
            f"({_points(points_by_p[stop])}) and P = {tost_p} %: the TOST names measured "
            "fractions only"
            if stop is not None
            else f"the two readings agree: {says}"
        )
    if tost_n > curve.answer_high:
        return _smaller_suffices(rows, curve, points_by_p, stop, says)
    row = rows.loc[tost_p]
    fitted_on = _fitted_on(curve)
    return (
        f"the readings differ: {says}: the TOST shows P = {tost_p} % equivalent on its own data "
        f"(change {_pct(row['relative_change'])}, interval {_interval(row)}), while the curve, "
        f"{fitted_on}, puts it at {_pct(_relative_to_reference(curve, tost_n))} of "
        f"P = {reference} %, past the margin: its neighbours pull the curve above P = "
        f"{tost_p} %'s own mean (observed and fitted means in stats/learning_curve.csv)"
        + (
            f"{_misfit(curve)}, so P = {tost_p} %'s own test is the better guide"
            if _misfit(curve)
            else ""
        )
    )


def _smaller_suffices(rows, curve: LearningCurve, points_by_p, stop: int, says: str) -> str:
    """Why the readings differ where the curve says fewer points than the TOST's fraction do:
    the fixed sequence stopped at P = `stop`, and the curve reads that fraction within the margin."""
    reference = curve.reference
    fitted_on = _fitted_on(curve)
    parts = [_tost_reason(rows.loc[stop], curve, stop)]
    own = [
        int(p)
        for p, row in rows.iterrows()
        if p < stop
        and str(row["conclusion"]) == "not equivalent: a larger P is not"
        and -curve.margin < row["ci_low"]
        and row["ci_high"] < curve.margin
    ]
    if own:
        shown = [f"P = {p} % ({_interval(rows.loc[p])})" for p in own]
        listed = shown[0] if len(shown) == 1 else ", ".join(shown[:-1]) + " and " + shown[-1]
        parts.append(
            "the fixed sequence stops there, so no smaller fraction is called equivalent, "
            + (
                f"though the interval of {listed} lies inside the margin"
                if len(own) == 1
                else f"though the intervals of {listed} lie inside the margin"
            )
        )
    means = curve.fractions.set_index("P")["mean_mse"]
    observed = means[stop] / means[reference] - 1
    share = curve.fractions.set_index("P").loc[stop, "weight"]
    parts.append(
        f"the curve, {fitted_on}, each weighted by its spread (P = {stop} % "
        f"{share * 100:.0f} % of the fit), puts P = {stop} % at "
        f"{_pct(_relative_to_reference(curve, points_by_p[stop]))} of P = {reference} % "
        f"(observed {_pct(observed)}) and reaches the margin at {_points(curve.answer)} points"
    )
    misfit = _misfit(curve)
    return (
        f"the readings differ: {says}: "
        + "; ".join(parts)
        + (f"{misfit}: read the curve's number with care" if misfit else "")
    )


@dataclass(frozen=True)
class Readings:
    """tests.csv, the learning curve, and recommendation.txt's lines: the TOST's answer, the
    curve's, and whether they agree (absent where the curve was not fitted)."""

    tests: pd.DataFrame
    curve: LearningCurve
    recommendation: str
    curve_line: str
    comparison: str | None

    @property
    def text(self) -> str:
        """recommendation.txt: one reading a line."""
        lines = [self.recommendation, self.curve_line]
        return "\n".join(lines + ([self.comparison] if self.comparison else [])) + "\n"


def read_validation_errors(
    table: pd.DataFrame,
    blocks: pd.Series,
    points_by_p: Mapping[int, int],
    *,
    alpha: float = ALPHA,
    margin: float = MARGIN,
    equivalence_alpha: float = EQUIVALENCE_ALPHA,
    bootstrap: int = BOOTSTRAP,
    seed: int = 0,
    reference: int = REFERENCE_P,
) -> Readings:
    """Every reading of one ablation's validation errors (validation_mse.csv's table, its spatial
    blocks, the points each P probed): the test families, the TOST's recommendation, the learning
    curve at the TOST's interval level (1 - 2 equivalence_alpha), and the two compared. Call it
    once per training budget."""
    curve = learning_curve(
        table,
        blocks,
        points_by_p,
        margin=margin,
        level=1 - 2 * equivalence_alpha,
        bootstrap=bootstrap,
        seed=seed,
        reference=reference,
    )
    tests = ablation_tests(
        table,
        blocks,
        alpha=alpha,
        margin=margin,
        equivalence_alpha=equivalence_alpha,
        reference=reference,
    )
    line = recommend(tests, points_by_p, margin, equivalence_alpha, reference)
    return Readings(
        tests=tests,
        curve=curve,
        recommendation=line,
        curve_line=curve_sentence(curve),
        comparison=readings_compared(tests, curve, points_by_p),
    )


def curve_summary(table: pd.DataFrame) -> str:
    """stats/learning_curve.csv's answer in short: '111 points (90 % interval 86 to 141)', 'at or
    below 12 points (...)', or 'not fitted (why)'."""
    rows = table.set_index("quantity")
    for quantity in ("points_within_margin", "level"):
        if quantity not in rows.index:
            raise ConfigError(f"learning_curve.csv lacks its {quantity!r} row")
    answer, level = rows.loc["points_within_margin"], float(rows.loc["level", "value"])
    status = str(answer["note"])
    if status.startswith(NOT_FITTED):
        return f"not fitted ({status.removeprefix(NOT_FITTED).removeprefix(': ')})"
    smallest = int(table.loc[table["quantity"] == "observed_mse", "points"].min())
    low = (
        f"at or below {_points(smallest)}" if answer["low"] <= smallest else _points(answer["low"])
    )
    value = (
        f"at or below {_points(answer['value'])}" if status == FLAT else _points(answer["value"])
    )
    return f"{value} points ({level * 100:g} % interval {low} to {_points(answer['high'])})"
