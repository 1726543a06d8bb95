"""Ablation statistics (paper Sec. III-A): how many probe points does a calibration need?

Every model — training fraction P, replicate r — is scored on the same validation coordinates
(validation_mse.csv: one MSE per model and coordinate). Each P < 80 is compared with P = 80 by three
families of tests (rows of tests.csv, docs/explanation/statistics.md says why each choice):

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

What the families say, in words (the recommendation, the families side by side): threedcal.evaluate.
ablation_reading; the figure: threedcal.evaluate.ablation_figure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

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


def independent_contrast(
    sample: np.ndarray, reference: np.ndarray, theta: float = 1.0
) -> tuple[float, float, float]:
    """`contrast` for two arms whose replicates are independent runs (no replicate r of one is
    paired with replicate r of the other), possibly of different counts; blocks still paired.

    u_k = mean_i sample_ik - theta·mean_j reference_jk; the grand mean's variance is
    var(u)/K + (MS_R - MS_E)/(K R) of each arm with R >= 2 (theta² for the reference), an arm's
    replicate term left out where it is negative, with Satterthwaite's degrees of freedom. With
    one replicate on either side this is `contrast` with that row broadcast, which it returns.
    """
    s, f = np.atleast_2d(np.asarray(sample, float)), np.atleast_2d(np.asarray(reference, float))
    if s.shape[-1] != f.shape[-1]:
        raise ValueError(f"arms scored on {s.shape[-1]} and {f.shape[-1]} blocks cannot be paired")
    if min(s.shape[0], f.shape[0]) == 1:
        return tuple(float(v) for v in contrast(s, f, theta))
    blocks = s.shape[1]
    if blocks < 2:
        raise ConfigError(
            "the validation coordinates fill one spatial block; the paired test needs two or more"
        )
    u = s.mean(axis=0) - theta * f.mean(axis=0)
    terms = [(u.var(ddof=1) / blocks, blocks - 1.0)]  # (variance share, its degrees of freedom)
    for x, weight in ((s, 1.0), (f, theta**2)):
        replicates = x.shape[0]
        rows, columns, grand = x.mean(axis=1), x.mean(axis=0), x.mean()
        ms_r = blocks * rows.var(ddof=1)
        df_e = (replicates - 1) * (blocks - 1)
        ms_e = ((x - rows[:, None] - columns[None, :] + grand) ** 2).sum() / df_e
        if ms_r > ms_e:
            scale = weight / (blocks * replicates)
            terms += [(scale * ms_r, replicates - 1.0), (-scale * ms_e, float(df_e))]
    variance = sum(v for v, _ in terms)
    denominator = sum(v**2 / df for v, df in terms)
    df = variance**2 / denominator if denominator > 0 else blocks - 1.0
    return float(u.mean()), math.sqrt(variance), float(df)


# Below this share of the arms' own size, a contrast or its standard error is float rounding.
ROUNDING = 1e-12


def _t(sample, reference, theta, independent: bool = False):
    measure = independent_contrast if independent else contrast
    estimate, se, df = measure(sample, reference, theta)
    scale = np.abs(np.mean(sample, axis=(-2, -1))) + np.abs(
        np.asarray(theta, float) * np.mean(reference, axis=(-2, -1))
    )
    # no spread at all: a zero contrast is t = 0 (the data sit on the hypothesis), any other +-inf
    estimate = np.where(np.abs(estimate) <= ROUNDING * scale, 0.0, estimate)
    spread = np.asarray(se) > ROUNDING * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        exact = np.where(estimate == 0, 0.0, np.copysign(np.inf, estimate))
        t = np.where(spread, estimate / np.where(spread, se, 1.0), exact)
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


def ratio_interval(
    sample, reference, tail: float, independent: bool = False
) -> tuple[float, float]:
    """Fieller-type interval of mean(sample) / mean(reference): the ratios theta whose contrast
    sample - theta·reference is not rejected by a one-sided test at `tail` on either side
    (a 1 - 2·tail interval). An end is +-inf where no finite ratio is rejected. `independent`:
    the arms' replicates are unpaired runs (independent_contrast), not nested replicates."""
    ratio = float(np.mean(sample) / np.mean(reference))

    def excess(theta: float, side: int) -> float:
        t, df = _t(sample, reference, theta, independent)
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
    from statsmodels.stats.multitest import multipletests  # optional (workflow extra), slow

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
