"""Ablation statistics (paper Sec. III-A): how many probe points does a calibration need?

Every model — training fraction P, replicate r — is scored on the same validation coordinates
(validation_mse.csv: one MSE per model and coordinate). Each P < 80 is compared with P = 80 by three
families of tests (rows of tests.csv, docs/statistics.md says why each choice):

paper        the paper's tests as published, run on each replicate alone: an independent two-sample
             t-test (Student's, pooled variance) and a two-sided Mann-Whitney U test on the
             per-coordinate MSE, P = 80 first (so t < 0 and U < n·n/2 when P is worse),
             Bonferroni over the comparisons of each test, alpha = 0.01. They treat the coordinates
             as independent samples of two unrelated models.
paired       the same coordinates, paired: per replicate and spatial block (square blocks at least
             one scoring disc across) the mean MSE of P minus that of P = 80, then a two-way
             random-effects model (replicate + block + residual) for the grand mean: its variance
             (MS_replicate + MS_block - MS_residual) / (R K) with Satterthwaite degrees of freedom,
             two-sided t, Holm over the comparisons.
equivalence  TOST on the same model: is mean MSE(P) / mean MSE(80) within 1 +- margin? Each
             one-sided test is a contrast (P - theta·80, theta = 1 +- margin), so the interval of the
             ratio is Fieller's; P is tested from the largest down (fixed sequence: no correction,
             and a P is only called equivalent when every larger one is).
placebo      the paper's two tests, judged exactly as one of its comparisons, between two replicates
             of P = 80 itself: the fraction is the same, so every rejection is the training run's
             own randomness (seed, subset draw) read as an effect. Not a test of P: a check of how
             far the paper family can be trusted on this bench.

`recommend` names the smallest P equivalent to P = 80 %, or says why none is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize, stats

from threedcal.errors import ConfigError

ALPHA = 0.01
EQUIVALENCE_ALPHA = 0.05
MARGIN = 0.10
REFERENCE_P = 80
PAPER_TESTS = ("t", "mannwhitney")
TEST_COLUMNS = [
    "family",
    "test",
    "P",
    "replicate",
    "against",
    "replicates",
    "n",
    "blocks",
    "estimate",
    "relative_change",
    "ci_low",
    "ci_high",
    "statistic",
    "df",
    "p_raw",
    "p_adjusted",
    "correction",
    "significant",
    "conclusion",
]


def _models(table: pd.DataFrame) -> dict[int, pd.DataFrame]:
    """P -> (replicates x points) table of per-coordinate MSE; every model on the same coordinates."""
    for column in ("P", "point", "mse"):
        if column not in table:
            raise ConfigError(f"validation table lacks column {column!r}")
    if "replicate" not in table:
        table = table.assign(replicate=0)
    wide = {
        int(p): part.pivot(index="replicate", columns="point", values="mse").sort_index(axis=1)
        for p, part in table.groupby("P")
    }
    points = {tuple(w.columns) for w in wide.values()}
    replicates = {tuple(w.index) for w in wide.values()}
    if len(points) > 1:
        raise ConfigError("every model must be scored on the same validation coordinates")
    if len(replicates) > 1:
        raise ConfigError(
            f"every fraction needs the same replicates, got {sorted(replicates, key=len)}"
        )
    return wide


def _reference(wide: Mapping[int, pd.DataFrame], reference: int) -> pd.DataFrame:
    if reference not in wide:
        raise ConfigError(
            f"the ablation needs the reference fraction P={reference}; have {sorted(wide)}"
        )
    return wide[reference]


def _finite(values, p: int, replicate) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    array = array[np.isfinite(array)]
    if array.size < 2:
        raise ConfigError(
            f"P={p}, replicate {replicate}: needs at least 2 finite validation errors, got {array.size}"
        )
    return array


def _direction(difference: float, significant: bool) -> str:
    if not significant:
        return "no significant difference"
    return "worse" if difference > 0 else "better"


def _paper_rows(ref, sample, comparisons: int, alpha: float, **labels) -> list[dict]:
    """Student's t and Mann-Whitney U, two-sided, (reference, sample), Bonferroni x comparisons."""
    difference = float(sample.mean() - ref.mean())
    rows = []
    for name in PAPER_TESTS:
        if name == "t":
            result = stats.ttest_ind(ref, sample, equal_var=True)
            df = float(ref.size + sample.size - 2)
        else:
            result = stats.mannwhitneyu(ref, sample, alternative="two-sided")
            df = float("nan")
        p_adj = min(1.0, float(result.pvalue) * comparisons)
        rows.append(
            {
                **labels,
                "test": name,
                "replicates": 1,
                "n": int(sample.size),
                "estimate": difference,
                "relative_change": difference / float(ref.mean()),
                "statistic": float(result.statistic),
                "df": df,
                "p_raw": float(result.pvalue),
                "p_adjusted": p_adj,
                "correction": f"bonferroni x{comparisons}",
                "significant": bool(p_adj < alpha),
                "conclusion": _direction(difference, p_adj < alpha),
            }
        )
    return rows


def paper_family(
    table: pd.DataFrame, reference: int = REFERENCE_P, alpha: float = ALPHA
) -> pd.DataFrame:
    """The paper's tests on each replicate: Student's t and Mann-Whitney U, two-sided, (P = 80, P).

    Bonferroni over the comparisons of each test (one per P < reference).
    """
    wide = _models(table)
    ref_wide = _reference(wide, reference)
    others = sorted(p for p in wide if p != reference)
    rows = []
    for replicate in ref_wide.index:
        ref = _finite(ref_wide.loc[replicate], reference, replicate)
        for p in others:
            sample = _finite(wide[p].loc[replicate], p, replicate)
            labels = {"family": "paper", "P": p, "replicate": int(replicate)}
            rows += _paper_rows(ref, sample, len(others), alpha, **labels, against=int(replicate))
    return _frame(rows)


def placebo_family(
    table: pd.DataFrame, reference: int = REFERENCE_P, alpha: float = ALPHA
) -> pd.DataFrame:
    """The paper's tests between every pair of replicates of the reference fraction (replicate a
    as the reference, b as the sample), judged as one of the paper's comparisons (the same
    Bonferroni factor): how often they call two trainings of one fraction different."""
    wide = _models(table)
    ref_wide = _reference(wide, reference)
    comparisons = max(1, len(wide) - 1)
    replicates = list(ref_wide.index)
    rows = []
    for i, a in enumerate(replicates):
        for b in replicates[i + 1 :]:
            ref = _finite(ref_wide.loc[a], reference, a)
            sample = _finite(ref_wide.loc[b], reference, b)
            labels = {"family": "placebo", "P": reference, "replicate": int(b), "against": int(a)}
            rows += _paper_rows(ref, sample, comparisons, alpha, **labels)
    return _frame(rows)


def spatial_blocks(table: pd.DataFrame, min_side_mm: float) -> pd.Series:
    """point -> block id: the validation coordinates' bounding box cut into nx x ny equal blocks,
    each at least `min_side_mm` on a side (empty blocks dropped, ids 0..K-1 in x-then-y order)."""
    if not min_side_mm > 0:
        raise ConfigError(f"spatial block side must be positive, got {min_side_mm}")
    coords = table.drop_duplicates("point").set_index("point")[["x_mm", "y_mm"]].sort_index()
    ids = np.zeros(len(coords), dtype=int)
    for column in ("x_mm", "y_mm"):
        values = coords[column].to_numpy(float)
        low, span = values.min(), np.ptp(values)
        count = max(1, int(span // min_side_mm))
        cell = np.minimum(((values - low) / (span / count)).astype(int), count - 1) if span else 0
        ids = ids * count + cell
    _, compact = np.unique(ids, return_inverse=True)
    return pd.Series(compact, index=coords.index, name="block")


def block_means(table: pd.DataFrame, blocks: pd.Series) -> dict[int, np.ndarray]:
    """P -> (R, K) array: mean MSE of replicate r over the validation coordinates of block k."""
    wide = _models(table)
    missing = set(next(iter(wide.values())).columns) - set(blocks.index)
    if missing:
        raise ConfigError(f"{len(missing)} validation coordinates have no spatial block")
    out = {}
    for p, frame in wide.items():
        values = frame.to_numpy(float)
        if not np.isfinite(values).all():
            raise ConfigError(f"P={p}: non-finite validation errors cannot be paired")
        grouped = pd.DataFrame(values.T, index=frame.columns).groupby(blocks[frame.columns].values)
        out[p] = grouped.mean().to_numpy().T
    return out


def contrast(
    sample: np.ndarray, reference: np.ndarray, theta: float | np.ndarray = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Estimate, standard error and degrees of freedom of mean(sample) - theta · mean(reference).

    `sample` and `reference` are (..., R, K) block means (replicates x blocks), leading axes
    vectorised. D = sample - theta·reference follows D_rk = mu + a_r + c_k + e_rk with random
    replicate (a), block (c) and residual (e) effects; the grand mean's variance is
    (MS_R + MS_K - MS_E) / (R K) (at least MS_E / (R K)), with Satterthwaite's degrees of freedom.
    With one replicate, the blocks alone: MS_K / K on K - 1 degrees of freedom (no replicate
    variance can be estimated: the test then compares two fitted models, not two fractions).
    """
    d = np.asarray(sample, float) - np.asarray(theta, float)[..., None, None] * np.asarray(
        reference, float
    )
    replicates, blocks = d.shape[-2:]
    if blocks < 2:
        raise ConfigError(
            "the validation coordinates fill one spatial block; the paired test needs two or more"
        )
    grand = d.mean(axis=(-2, -1))
    columns = d.mean(axis=-2)
    ms_k = replicates * columns.var(axis=-1, ddof=1)
    if replicates == 1:
        return grand, np.sqrt(ms_k / blocks), np.full_like(grand, blocks - 1.0)
    rows = d.mean(axis=-1)
    ms_r = blocks * rows.var(axis=-1, ddof=1)
    residual = d - rows[..., None] - columns[..., None, :] + grand[..., None, None]
    df_e = (replicates - 1) * (blocks - 1)
    ms_e = (residual**2).sum(axis=(-2, -1)) / df_e
    combined = ms_r + ms_k - ms_e
    with np.errstate(divide="ignore", invalid="ignore"):  # all zero: the floor's df below
        satterthwaite = combined**2 / (
            ms_r**2 / (replicates - 1) + ms_k**2 / (blocks - 1) + ms_e**2 / df_e
        )
    floor = combined <= ms_e
    variance = np.where(floor, ms_e, combined)
    df = np.where(floor, float(df_e), satterthwaite)
    return grand, np.sqrt(variance / (replicates * blocks)), df


def _t(sample, reference, theta):
    estimate, se, df = contrast(sample, reference, theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(se > 0, estimate / np.where(se > 0, se, 1.0), np.sign(estimate) * np.inf)
    return t, df


def difference_test(sample, reference) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-sided paired test of mean(sample) = mean(reference): (t, df, p), vectorised."""
    t, df = _t(sample, reference, 1.0)
    return t, df, 2 * stats.t.sf(np.abs(t), df)


def tost(
    sample, reference, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Two one-sided tests of 1 - margin < mean(sample) / mean(reference) < 1 + margin.

    Returns (t_lower, df_lower, t_upper, df_upper, p): p is the larger one-sided p-value.
    """
    if not 0 < margin < 1:
        raise ConfigError(f"equivalence margin must be between 0 and 1, got {margin}")
    t_low, df_low = _t(sample, reference, 1.0 - margin)
    t_high, df_high = _t(sample, reference, 1.0 + margin)
    p = np.maximum(stats.t.sf(t_low, df_low), stats.t.cdf(t_high, df_high))
    return t_low, df_low, t_high, df_high, p


def ratio_interval(sample, reference, tail: float) -> tuple[float, float]:
    """Fieller-type interval of mean(sample) / mean(reference): the ratios theta whose contrast
    sample - theta·reference is not rejected by a one-sided test at `tail` on either side
    (a 1 - 2·tail interval). An end is +-inf where no finite ratio is rejected."""
    ratio = float(np.mean(sample) / np.mean(reference))

    def excess(theta: float, side: int) -> float:
        t, df = _t(sample, reference, theta)
        return float(t) - side * float(stats.t.isf(tail, df))

    ends = []
    for side, direction in ((1, -1.0), (-1, 1.0)):
        step, inner = max(abs(ratio), 1e-3) * 0.05, ratio
        end = math.copysign(math.inf, direction)
        for _ in range(60):
            outer = inner + direction * step
            if np.sign(excess(outer, side)) != np.sign(excess(inner, side)):
                end = optimize.brentq(excess, *sorted((inner, outer)), args=(side,), xtol=1e-10)
                break
            inner, step = outer, step * 2
            if abs(inner) > 1e6:
                break
        ends.append(end)
    return ends[0], ends[1]


def holm(p_values) -> np.ndarray:
    """Holm's step-down adjusted p-values (statsmodels' multipletests)."""
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(p_values, dtype=float)
    return multipletests(p, method="holm")[1] if p.size else p


def _block_row(family, test, p, sample, ref, low, high, statistic, df, p_raw) -> dict:
    """The columns a block-level test of P against the reference shares: change and ratio interval."""
    estimate = float(np.mean(sample) - np.mean(ref))
    return {
        "family": family,
        "test": test,
        "P": p,
        "replicates": ref.shape[0],
        "blocks": ref.shape[1],
        "estimate": estimate,
        "relative_change": estimate / float(np.mean(ref)),
        "ci_low": low - 1.0,
        "ci_high": high - 1.0,
        "statistic": float(statistic),
        "df": float(df),
        "p_raw": float(p_raw),
    }


def paired_family(
    means: Mapping[int, np.ndarray], reference: int = REFERENCE_P, alpha: float = ALPHA
) -> pd.DataFrame:
    """Paired spatial-block test of every P against the reference, Holm over the family."""
    ref = _reference(means, reference)
    others = sorted(p for p in means if p != reference)
    rows = []
    for p in others:
        t, df, p_raw = difference_test(means[p], ref)
        low, high = ratio_interval(means[p], ref, alpha / 2)
        rows.append(
            _block_row("paired", "block_mixed_t", p, means[p], ref, low, high, t, df, p_raw)
        )
    adjusted = holm([r["p_raw"] for r in rows]) if rows else []
    for row, p_adj in zip(rows, adjusted, strict=True):
        significant = bool(p_adj < alpha)
        row.update(
            p_adjusted=float(p_adj),
            correction=f"holm x{len(rows)}",
            significant=significant,
            conclusion=_direction(row["estimate"], significant),
        )
    return _frame(rows)


def equivalence_family(
    means: Mapping[int, np.ndarray],
    margin: float = MARGIN,
    alpha: float = EQUIVALENCE_ALPHA,
    reference: int = REFERENCE_P,
) -> pd.DataFrame:
    """TOST of every P against the reference within +-margin, tested from the largest P down.

    The fixed-sequence adjusted p of a P is the largest TOST p of it and every larger P, so a P is
    equivalent only when all larger ones are; the family-wise error stays at alpha.
    """
    ref = _reference(means, reference)
    others = sorted((p for p in means if p != reference), reverse=True)
    rows, running = [], 0.0
    for p in others:
        t_low, df_low, t_high, df_high, p_tost = tost(means[p], ref, margin)
        low, high = ratio_interval(means[p], ref, alpha)
        running = max(running, float(p_tost))
        equivalent = running < alpha
        binding_low = stats.t.sf(t_low, df_low) >= stats.t.cdf(t_high, df_high)
        row = _block_row(
            "equivalence",
            "tost",
            p,
            means[p],
            ref,
            low,
            high,
            t_low if binding_low else t_high,
            df_low if binding_low else df_high,
            p_tost,
        )
        row.update(
            p_adjusted=running,
            correction="fixed sequence (largest P first)",
            significant=bool(equivalent),
            conclusion=_equivalence_conclusion(
                equivalent, p_tost < alpha, row["relative_change"], low - 1.0, high - 1.0, margin
            ),
        )
        rows.append(row)
    return _frame(sorted(rows, key=lambda r: r["P"]))


def _equivalence_conclusion(
    equivalent: bool, own: bool, change: float, low: float, high: float, margin: float
) -> str:
    """Why P is not equivalent: wholly past a bound; an estimate past a bound (the interval
    reaching back inside); or an estimate inside the margin with an interval that crosses one or
    both bounds, which more replicates or points would narrow (power)."""
    if equivalent:
        return "equivalent"
    if own:
        return "not equivalent: a larger P is not"
    if low > margin:
        return "not equivalent: worse by more than the margin"
    if high < -margin:
        return "not equivalent: better by more than the margin"
    past_low, past_high = low < -margin, high > margin
    if not (past_low or past_high):  # the interval ends on a bound: its tests part by rounding
        return "not equivalent: the interval ends on the margin (too little power)"
    if past_low and past_high:
        return "not equivalent: the interval is wider than the margin allows (too little power)"
    side = "worse" if past_high else "better"
    if abs(change) > margin:
        return f"not equivalent: the estimate lies past the margin on the {side} side"
    return f"not equivalent: the interval reaches past the margin on the {side} side (too little power)"


def _frame(rows: list[dict]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=TEST_COLUMNS)
    for column in ("replicate", "against", "replicates", "n", "blocks"):
        frame[column] = frame[column].astype("Int64")
    return frame


def ablation_tests(
    table: pd.DataFrame,
    blocks: pd.Series,
    alpha: float = ALPHA,
    margin: float = MARGIN,
    equivalence_alpha: float = EQUIVALENCE_ALPHA,
    reference: int = REFERENCE_P,
) -> pd.DataFrame:
    """tests.csv: the paper, paired and equivalence families of every P against the reference,
    and the placebo family (the paper's tests between the reference's own replicates)."""
    means = block_means(table, blocks)
    n_points = table["point"].nunique()
    paired = paired_family(means, reference, alpha)
    equivalence = equivalence_family(means, margin, equivalence_alpha, reference)
    for frame in (paired, equivalence):
        frame["n"] = pd.array([n_points] * len(frame), dtype="Int64")
    families = [paper_family(table, reference, alpha), paired, equivalence]
    families.append(placebo_family(table, reference, alpha))
    # an empty family (one replicate: no placebo pair) would turn every column to text in the
    # concatenation, and tests.csv would lose its number format
    return pd.concat([f for f in families if len(f)], ignore_index=True)


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


# The tests figure's ratio axis: an interval reaching past it (a paired interval with few degrees
# of freedom can span -150 % to +5,000 %) is cut at the edge and its bound written beside it, so
# that the intervals that matter are not squeezed into a sliver.
AXIS_RATIO = (0.2, 20.0)


def interval_on_axis(ci_low, ci_high, limits=AXIS_RATIO) -> dict:
    """Ratio bounds (1 + relative bound) cut to `limits`, and for each cut bound its true value as
    text ("" where it lies on the axis). NaN bounds stay NaN."""
    ci_low, ci_high = np.asarray(ci_low, dtype=float), np.asarray(ci_high, dtype=float)
    low, high = 1 + ci_low, 1 + ci_high
    below = [f"{v * 100:+.0f} %" if v + 1 < limits[0] else "" for v in ci_low]
    above = [f"{v * 100:+,.0f} %" if v + 1 > limits[1] else "" for v in ci_high]
    return {
        "low": np.where(np.isnan(low), low, np.clip(low, limits[0], limits[1])),
        "high": np.where(np.isnan(high), high, np.clip(high, limits[0], limits[1])),
        "below": below,
        "above": above,
    }


def tests_figure(tests: pd.DataFrame, path: str | Path, title: str, margin: float = MARGIN) -> None:
    """Each P against P = 80: ratio of mean validation MSE with the paired (1 - alpha) and TOST
    (1 - 2 alpha) intervals, the margin shaded, each replicate's paper-family ratio as a dot
    (filled where both of the paper's tests are significant)."""
    from matplotlib import ticker

    from threedcal.plotting import pyplot

    plt = pyplot()

    paired = tests[tests["family"] == "paired"].set_index("P").sort_index()
    equivalence = tests[tests["family"] == "equivalence"].set_index("P")
    paper = tests[tests["family"] == "paper"]
    fractions = list(paired.index)
    x = np.arange(len(fractions))
    fig, ax = plt.subplots(figsize=(7, 4.6), dpi=120)
    ax.axhspan(
        1 - margin,
        1 + margin,
        color="tab:green",
        alpha=0.15,
        lw=0,
        label=f"margin ±{margin * 100:.0f} %",
    )
    ax.axhline(1.0, c="k", lw=0.6)

    drawn = []

    def bars(frame, offset, colour, label, width):
        ratio = 1 + frame["relative_change"].to_numpy(float)
        bounds = interval_on_axis(frame["ci_low"].to_numpy(float), frame["ci_high"].to_numpy(float))
        ax.errorbar(
            x + offset,
            ratio,
            yerr=[ratio - bounds["low"], bounds["high"] - ratio],
            fmt="o",
            c=colour,
            lw=width,
            capsize=3,
            label=label,
        )
        drawn.append((x + offset, colour, bounds))

    bars(paired, -0.08, "tab:blue", "paired test, 1 - alpha interval", 1.2)
    bars(equivalence.loc[fractions], 0.08, "tab:green", "TOST, 1 - 2 alpha interval", 2.4)
    for i, p in enumerate(fractions):
        part = paper[(paper["P"] == p) & (paper["test"] == "t")]
        both = paper[paper["P"] == p].groupby("replicate")["significant"].all()
        for _, row in part.iterrows():
            filled = bool(both.get(row["replicate"], False))
            ax.plot(
                i + 0.25,
                np.clip(1 + row["relative_change"], *AXIS_RATIO),
                "s",
                ms=4,
                mec="tab:red",
                mfc="tab:red" if filled else "none",
            )
    ax.plot([], [], "s", ms=4, mec="tab:red", mfc="tab:red", label="paper's tests, a replicate")
    ax.set_yscale("log")
    low, high = ax.get_ylim()
    low, high = max(low, AXIS_RATIO[0]), min(high, AXIS_RATIO[1])
    # room above and below for the verdicts written at the panel's edges
    low, high = min(low, 1 - 2 * margin) / 1.8, max(high, 1 + 2 * margin) * 1.8
    ax.set_ylim(low, high)
    edges = (("below", 0, "v", -2, "top"), ("above", 1, "^", 2, "bottom"))
    for xs, colour, bounds in drawn:  # an interval past the axis: an arrow at the edge, its value
        for side, end, marker, dy, va in edges:
            for xi, text in zip(xs, bounds[side], strict=True):
                if text:
                    ax.plot(xi, AXIS_RATIO[end], marker, c=colour, ms=5)
                    ax.annotate(
                        text,
                        (xi, AXIS_RATIO[end]),
                        xytext=(-4, dy),
                        textcoords="offset points",
                        ha="right",
                        va=va,
                        fontsize=6,
                        color=colour,
                    )
    nice = [0.2, 0.25, 0.5, 0.75, 0.9, 1.0, 1.1, 1.25, 1.5, 2, 3, 5, 10, 20]
    if high / low > 3:  # on a wide axis the small steps crowd the 0 %; the shaded band shows them
        nice = [v for v in nice if v not in (0.25, 0.75, 0.9, 1.1, 1.25)]
    ax.yaxis.set_major_locator(ticker.FixedLocator([v for v in nice if low <= v <= high]))
    ax.yaxis.set_major_formatter(
        ticker.FuncFormatter(lambda v, _: f"{(v - 1) * 100:+,.0f} %" if v != 1 else "0 %")
    )
    ax.yaxis.set_minor_locator(ticker.NullLocator())
    ax.set_xticks(x, [f"P = {p} %" for p in fractions])
    ax.set(ylabel="change of mean validation MSE against P = 80 %", title=title)
    comparison = family_comparison(tests).set_index("P")
    for i, p in enumerate(fractions):
        row = comparison.loc[p]
        ax.annotate(
            f"t {row['paper_t']}, U {row['paper_u']}",
            (i, 0.02),
            xycoords=("data", "axes fraction"),
            ha="center",
            fontsize=7,
            color="tab:red",
        )
        if row["agreement"].startswith(("disagree", "mixed")):
            ax.annotate(
                "families disagree",
                (i, 0.95),
                xycoords=("data", "axes fraction"),
                ha="center",
                fontsize=7,
                color="tab:orange",
            )
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4, frameon=False)
    placebo = placebo_summary(tests, short=True)
    if placebo:
        fig.text(0.5, 0.01, placebo, ha="center", fontsize=7, color="tab:red")
    fig.tight_layout(rect=(0, 0.04 if placebo else 0, 1, 1))
    fig.savefig(path)
    plt.close(fig)
