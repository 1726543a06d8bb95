"""The ablation's learning curve: how many probe points bring the error within the margin of P = 80 %?

The TOST reads each fraction alone; the curve reads them together. Mean validation MSE against the
number of points probed n follows the inverse power law with an asymptote,

    MSE(n) = a + b · (n / n_ref)^-c        (a, b >= 0, c > 0; n_ref: the points of P = 80 %)

so a is the error no amount of data removes, b what P = 80 % could still gain, c how fast the
rest falls. The answer is the n whose predicted MSE is (1 + margin) times the prediction at n_ref:

    n* = n_ref · (1 + margin · (a + b) / b)^(-1 / c)

never extrapolated below the smallest fraction fitted (a curve flat over the fitted range answers
"at or below" it). Learning curves follow the power law past a small-data region: where the fit
through every fraction misses their means, the smallest are left out one by one while that mends
it (`fit_from_where`), a choice made once, on the data.

Each fraction's mean is the mean of its block means (replicates x spatial blocks), the quantity
the TOST compares. The fit is weighted by each fraction's own noise: the variance of its mean
(replicate and block random effects, threedcal.evaluate.ablation.contrast) after dividing out
what every fraction shares at a replicate and block (the gel's hard places, the replicate's seed),
so that a fraction whose replicates spread widely weighs little, but never a fraction more than
WEIGHT_CEILING times the median one. The loss is Huber's on those standardised residuals: one
fraction off the curve pulls it linearly, not quadratically. For a fixed c the model is linear in
(a, b), so c is searched on a grid and refined by golden section, (a, b) solved in closed form
under a, b >= 0, and every bootstrap draw is fitted at once.

The interval is a percentile bootstrap over replicates and spatial blocks, drawn with the same
indices for every fraction, so that each draw keeps the pairing of the models on the same
coordinates and the nested subsets of a replicate across fractions. Resampling rows and columns of
a two-way table together counts their interaction three times over; so each fraction's block means
are split into replicate, block and residual effects, resampled by those indices, and each rescaled
so that its spread is its variance component (the moment estimates of `contrast`), as in the
residual bootstrap of multilevel models (Carpenter, Goldstein and Rasbash 2003). Each draw is
fitted afresh, from the same fraction, and the percentile interval is widened for the few
degrees of freedom a handful of replicates and blocks give (`expanded_tail`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import MARGIN, REFERENCE_P, block_means, contrast

EXPONENTS = np.geomspace(0.02, 8.0, 110)  # the grid c is searched on, then refined between nodes
REFINE_STEPS = 24
HUBER_K = 1.345  # Huber's tuning constant: 95 % efficiency when the residuals are Gaussian
OFF_CURVE = 0.5  # a fraction whose Huber weight fell below this lies off the curve (|z| > 2.7)
IRLS_STEPS = 25
HUBER_TOL = 1e-4  # IRLS stops when no Huber weight moves more than this
WEIGHT_CEILING = 4.0  # no fraction weighs more than this many times the median fraction
BOOTSTRAP = 2000
LEVEL = 0.90
MIN_FRACTIONS = 3
MIN_CHECKED = 4  # a fit left with fewer fractions has no residual to judge it by
LACK_OF_FIT_P = 0.01

FITTED = "fitted"
FLAT = "at or below the smallest fraction"
NOT_FITTED = "not fitted"


@dataclass(frozen=True)
class CurveFits:
    """Power-law fits, one per row of the data they came from: arrays of equal shape."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    huber: np.ndarray  # (..., fractions) the Huber weight each fraction ended with (NaN: unused)
    start: np.ndarray | None = None  # index of the smallest fraction fitted (fit_from_where)
    chi2: np.ndarray | None = None  # sum of squared residuals in units of se, fitted fractions
    dof: np.ndarray | None = None  # fitted fractions (distinct points) - 3

    def predict(self, x) -> np.ndarray:
        """MSE at x = n / n_ref: (fits, len(x))."""
        x = np.asarray(x, float)
        return self.a[..., None] + self.b[..., None] * x ** -self.c[..., None]


@dataclass(frozen=True)
class LearningCurve:
    """The fitted curve, its answer and their bootstrap intervals (`learning_curve`)."""

    status: str  # FITTED, FLAT or NOT_FITTED
    reason: str  # why NOT_FITTED; empty otherwise
    reference: int
    reference_points: int
    margin: float
    level: float
    replicates: int
    blocks: int
    bootstrap: int
    seed: int
    # per P (ascending): P, points, mean_mse, replicate_low, replicate_high, in_fit (False: before
    # the power law holds, fit_from_where), se, huber (the Huber weight it ended with), weight (its
    # share of the fit), fitted, fitted_low, fitted_high
    fractions: pd.DataFrame
    replicate_means: dict[int, np.ndarray]
    parameters: dict[str, tuple[float, float, float]]  # a, b, c: (estimate, low, high)
    answer: float  # points, rounded up; NaN when not fitted
    answer_low: float
    answer_high: float
    chi2: float
    dof: int
    draws: CurveFits | None  # the bootstrap's fits (the figure's band); None when not fitted
    df: float  # degrees of freedom of the fractions' spread (median over fractions)
    tail: float  # each tail of the bootstrap distribution the intervals cut (expanded_tail)

    @property
    def smallest_points(self) -> int:
        """The points of the smallest fraction the curve describes (of all, where not fitted):
        the answer is never extrapolated below it."""
        frame = self.fractions
        fitted = frame[frame["in_fit"].astype(bool)]
        return int((fitted if len(fitted) else frame)["points"].min())

    @property
    def left_out(self) -> list[int]:
        """The fractions before the power law holds (fit_from_where), smallest first."""
        if self.status == NOT_FITTED:
            return []
        return [int(p) for p in self.fractions.loc[~self.fractions["in_fit"].astype(bool), "P"]]

    @property
    def low_censored(self) -> bool:
        """The interval's low end sits at the smallest fraction fitted: 'at or below' it."""
        return self.answer_low <= self.smallest_points

    def predict(self, points) -> np.ndarray:
        """The fitted curve's MSE at `points`."""
        a, b, c = (self.parameters[k][0] for k in "abc")
        return a + b * (np.asarray(points, float) / self.reference_points) ** -c

    def band(self, points) -> tuple[np.ndarray, np.ndarray]:
        """The bootstrap's pointwise `level` band of the curve at `points`."""
        if self.draws is None:
            nan = np.full(np.shape(points), np.nan)
            return nan, nan
        curves = self.draws.predict(np.asarray(points, float) / self.reference_points)
        low, high = np.quantile(curves, [self.tail, 1 - self.tail], axis=0)
        return low, high

    @property
    def lack_of_fit_p(self) -> float:
        """P-value of chi2 on dof (NaN without residual degrees of freedom)."""
        if self.dof < 1 or not np.isfinite(self.chi2):
            return math.nan
        return float(stats.chi2.sf(self.chi2, self.dof))


# ---------------------------------------------------------------------------------------------
# The fit


def _solve(sw, su, suu, sy, suy):
    """(a, b, loss - Σwy²) of the weighted least squares of y on a + b·u under a, b >= 0, from
    its sums (Σw, Σwu, Σwu², Σwy, Σwuy). The constrained optimum of a convex quadratic in two
    variables is the best feasible one of the unconstrained solution and the two edges (a = 0,
    b = 0); the loss of each, up to Σwy², is a² Σw + 2ab Σwu + b² Σwu² - 2a Σwy - 2b Σwuy."""
    det = sw * suu - su * su
    with np.errstate(divide="ignore", invalid="ignore"):
        b_free = (sw * suy - su * sy) / det
        a_free = (sy - b_free * su) / sw
        b_edge = np.maximum(suy / suu, 0.0)
        a_edge = np.maximum(sy / sw, 0.0)
    free = (det > 1e-12 * sw * suu) & (a_free >= 0) & (b_free >= 0)
    zero = np.zeros_like(det)
    best_a, best_b, best_loss = zero, zero, zero  # a = b = 0: loss 0 up to the constant
    candidates = (
        (np.where(free, a_free, 0.0), np.where(free, b_free, 0.0), free),
        (zero, b_edge, True),
        (a_edge, zero, True),
    )
    for a, b, ok in candidates:
        loss = a * a * sw + 2 * a * b * su + b * b * suu - 2 * a * sy - 2 * b * suy
        better = ok & (loss < best_loss)
        best_a = np.where(better, a, best_a)
        best_b = np.where(better, b, best_b)
        best_loss = np.where(better, loss, best_loss)
    return best_a, best_b, best_loss


def _profile(x: np.ndarray, y: np.ndarray, w: np.ndarray, c: np.ndarray):
    """(a, b, loss) at exponent c for each row: y, w (..., P), c (...); the loss summed directly
    (the sums' form cancels where the fit is near exact)."""
    u = x ** -c[..., None]
    wu = w * u
    a, b, _ = _solve(w.sum(-1), wu.sum(-1), (wu * u).sum(-1), (w * y).sum(-1), (wu * y).sum(-1))
    loss = (w * (y - a[..., None] - b[..., None] * u) ** 2).sum(-1)
    return a, b, loss


GRID_STEP = float(EXPONENTS[1] / EXPONENTS[0])


def _exponent(x: np.ndarray, y: np.ndarray, w: np.ndarray, start=None) -> np.ndarray:
    """The c minimising the profiled loss, for each row of y (S, P): golden section between the
    neighbours of the best grid node (every node at once, from the weighted sums), or within two
    grid steps of `start` (a previous fit's c) where given."""
    if start is None:
        u = x[None, :] ** -EXPONENTS[:, None]  # (G, P)
        wy = w * y
        sums = (w.sum(-1)[:, None], w @ u.T, w @ (u * u).T, wy.sum(-1)[:, None], wy @ u.T)
        best = np.argmin(_solve(*sums)[2], axis=-1)
        low = EXPONENTS[np.maximum(best - 1, 0)]
        high = EXPONENTS[np.minimum(best + 1, len(EXPONENTS) - 1)]
        centre = EXPONENTS[best]
    else:
        low = np.maximum(start / GRID_STEP**2, EXPONENTS[0])
        high = np.minimum(start * GRID_STEP**2, EXPONENTS[-1])
        centre = start
    ratio = (math.sqrt(5) - 1) / 2
    inner_low, inner_high = high - ratio * (high - low), low + ratio * (high - low)
    loss_low, loss_high = _profile(x, y, w, inner_low)[2], _profile(x, y, w, inner_high)[2]
    for _ in range(REFINE_STEPS):
        left = loss_low <= loss_high  # the minimum lies in [low, inner_high]
        low, high = np.where(left, low, inner_low), np.where(left, inner_high, high)
        fresh = np.where(left, high - ratio * (high - low), low + ratio * (high - low))
        fresh_loss = _profile(x, y, w, fresh)[2]
        inner_low, inner_high = np.where(left, fresh, inner_high), np.where(left, inner_low, fresh)
        loss_low, loss_high = (
            np.where(left, fresh_loss, loss_high),
            np.where(left, loss_low, fresh_loss),
        )
    refined = (low + high) / 2
    # keep the centre where the refinement did not beat it (a kink of the constrained profile)
    keep = _profile(x, y, w, centre)[2] <= _profile(x, y, w, refined)[2]
    return np.where(keep, centre, refined)


def fit_curves(x, y, se, huber: float = HUBER_K) -> CurveFits:
    """Fit MSE = a + b · x^-c (a, b >= 0) to every row of y with standard errors se (rows (..., P),
    x (P,) = points / reference points), by iteratively reweighted least squares for Huber's loss
    on the residuals in units of se."""
    x = np.asarray(x, float)
    y = np.atleast_2d(np.asarray(y, float))
    se = np.broadcast_to(np.asarray(se, float), y.shape)
    if not (np.isfinite(y).all() and np.isfinite(se).all() and (se > 0).all()):
        raise ConfigError("the learning curve needs finite means and positive standard errors")
    precision = 1.0 / se**2
    rows = y.shape[0]
    a, b, c = np.zeros(rows), np.zeros(rows), np.zeros(rows)
    h = np.ones_like(y)
    active, first = np.arange(rows), True
    for _ in range(IRLS_STEPS):
        ya, sa, pa = y[active], se[active], precision[active]
        w = h[active] * pa
        ca = _exponent(x, ya, w, None if first else c[active])
        first = False
        aa, ba, _ = _profile(x, ya, w, ca)
        a[active], b[active], c[active] = aa, ba, ca
        z = np.abs(ya - aa[:, None] - ba[:, None] * x ** -ca[:, None]) / sa
        fresh = np.minimum(1.0, huber / np.maximum(z, 1e-12))
        moved = np.abs(fresh - h[active]).max(axis=-1) > HUBER_TOL
        h[active] = fresh
        active = active[moved]
        if active.size == 0:
            break
    return CurveFits(a=a, b=b, c=c, huber=h)


def crossing(fits: CurveFits, margin: float) -> np.ndarray:
    """x* = n* / n_ref where the curve is (1 + margin) times its value at n_ref: 0 where it is
    flat (b = 0), for then every n is within the margin."""
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (1.0 + margin * (fits.a + fits.b) / fits.b) ** (-1.0 / fits.c)
    return np.where(fits.b > 0, x, 0.0)


def fit_from_where(x, y, se, huber: float = HUBER_K) -> CurveFits:
    """`fit_curves` on every fraction, and where the curve misses them (chi-squared p below
    LACK_OF_FIT_P), again without the smallest, then the two smallest, ... while MIN_CHECKED
    fractions remain: each row keeps the first fit that passes, or the fit on every fraction
    where none does (a misfit that leaving out small fractions does not mend is no small-data
    region). A learning curve follows a power law only past its small-data region; fractions
    before it are left out, never those near the answer. `start` gives each row's first
    fraction fitted; x (P,) ascending."""
    x = np.asarray(x, float)
    y = np.atleast_2d(np.asarray(y, float))
    se = np.broadcast_to(np.asarray(se, float), y.shape)
    if np.any(np.diff(x) < 0):
        raise ValueError("fit_from_where needs the fractions in ascending order of points")
    rows, count = y.shape
    starts = [k for k in range(count) if k == 0 or len(np.unique(x[k:])) >= MIN_CHECKED]
    fits, p_values = [], []
    for k in starts:
        fit = fit_curves(x[k:], y[:, k:], se[:, k:], huber)
        chi2 = (((y[:, k:] - fit.predict(x[k:])) / se[:, k:]) ** 2).sum(-1)
        dof = np.full(rows, len(np.unique(x[k:])) - 3)
        p = stats.chi2.sf(chi2, np.maximum(dof, 1)) if dof[0] > 0 else np.ones(rows)
        huber_weights = np.full((rows, count), np.nan)
        huber_weights[:, k:] = fit.huber
        fits.append(CurveFits(fit.a, fit.b, fit.c, huber_weights, np.full(rows, k), chi2, dof))
        p_values.append(p)
    p_values = np.array(p_values)  # (starts, rows)
    passing = p_values >= LACK_OF_FIT_P
    choice = np.where(passing.any(axis=0), passing.argmax(axis=0), 0)
    pick = np.arange(rows)
    return CurveFits(
        *(np.array([getattr(f, key) for f in fits])[choice, pick] for key in ("a", "b", "c")),
        huber=np.array([f.huber for f in fits])[choice, pick],
        start=np.array([f.start for f in fits])[choice, pick],
        chi2=np.array([f.chi2 for f in fits])[choice, pick],
        dof=np.array([f.dof for f in fits])[choice, pick],
    )


def fit_from(x, y, se, start_of_study: np.ndarray) -> CurveFits:
    """`fit_curves` of each row of y from its study's first fraction fitted: rows come study after
    study, as many to a study, and `start_of_study` (N,) gives each study's first fraction."""
    x = np.asarray(x, float)
    y = np.atleast_2d(np.asarray(y, float))
    se = np.broadcast_to(np.asarray(se, float), y.shape)
    rows, count = y.shape
    start = np.repeat(np.asarray(start_of_study, int), rows // len(start_of_study))
    out = {key: np.zeros(rows) for key in ("a", "b", "c", "chi2", "dof")}
    huber = np.full((rows, count), np.nan)
    for k in np.unique(start):
        chosen = start == k
        fit = fit_curves(x[k:], y[chosen, k:], se[chosen, k:])
        residual = (y[chosen, k:] - fit.predict(x[k:])) / se[chosen, k:]
        for key, value in (("a", fit.a), ("b", fit.b), ("c", fit.c)):
            out[key][chosen] = value
        out["chi2"][chosen] = (residual**2).sum(-1)
        out["dof"][chosen] = len(np.unique(x[k:])) - 3
        huber[chosen, k:] = fit.huber
    return CurveFits(huber=huber, start=start, **out)


# ---------------------------------------------------------------------------------------------
# The data


def _check(table: pd.DataFrame, points_by_p: Mapping[int, int], reference: int) -> None:
    """Bad input named before any fit: a missing column, an MSE that is not a finite number >= 0
    (its P, replicate and point), a fraction without its number of points."""
    for column in ("P", "point", "mse"):
        if column not in table:
            raise ConfigError(f"validation table lacks column {column!r}")
    mse = pd.to_numeric(table["mse"], errors="coerce").to_numpy(float)
    bad = ~np.isfinite(mse) | (mse < 0)
    if bad.any():
        first = table.index[bad][0]
        replicate = f", replicate {table.at[first, 'replicate']}" if "replicate" in table else ""
        raise ConfigError(
            f"P={table.at[first, 'P']}{replicate}, point {table.at[first, 'point']}: validation "
            f"MSE {float(mse[bad][0])} is not a finite number >= 0 ({int(bad.sum())} such "
            "value(s) in the table)"
        )
    fractions = sorted(int(p) for p in table["P"].unique())
    unknown = [p for p in fractions if p not in points_by_p]
    if unknown:
        raise ConfigError(f"points probed unknown for P = {unknown} (points_by_p)")


def _relative_variances(means: np.ndarray) -> tuple[np.ndarray, float]:
    """(P,) variance of each fraction's mean relative to itself, after dividing each replicate and
    block by what every fraction shares there (their mean), and the median of their
    Satterthwaite degrees of freedom; `means` (P, R, K) block means."""
    shared = means.mean(axis=0, keepdims=True)
    ratio = means / np.where(shared > 0, shared, 1.0)
    _, se, df = contrast(ratio, np.zeros_like(ratio), 0.0)
    variance = (se / ratio.mean(axis=(-2, -1))) ** 2
    df = float(np.median(np.where(np.isfinite(df), df, means.shape[-1] - 1.0)))
    positive = variance[variance > 0]
    if positive.size == 0:
        return np.ones_like(variance), df
    floor = max(float(np.median(variance)), float(positive.min())) / WEIGHT_CEILING
    return np.maximum(variance, floor), df


def resample_means(means: np.ndarray, pick_r: np.ndarray, pick_k: np.ndarray) -> np.ndarray:
    """(S, P) bootstrap means of every fraction: `means` (P, R, K) split into grand mean, replicate,
    block and residual effects, each resampled with the same indices for every fraction (pick_r
    (S, R), pick_k (S, K)) and scaled so that its spread is that effect's variance component."""
    fractions, replicates, blocks = means.shape
    grand = means.mean(axis=(1, 2))
    rows = means.mean(axis=2) - grand[:, None]
    columns = means.mean(axis=1) - grand[:, None]
    residual = means - grand[:, None, None] - rows[:, :, None] - columns[:, None, :]
    ms_k = replicates * (columns**2).sum(-1) / (blocks - 1)
    if replicates == 1:
        scale_r = np.zeros(fractions)
        scale_k = np.full(fractions, math.sqrt(blocks / (blocks - 1)))
        scale_e = 0.0
    else:
        ms_r = blocks * (rows**2).sum(-1) / (replicates - 1)
        ms_e = (residual**2).sum((1, 2)) / ((replicates - 1) * (blocks - 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            share_r = np.where(ms_r > 0, np.clip(1 - ms_e / ms_r, 0, 1), 0.0)
            share_k = np.where(ms_k > 0, np.clip(1 - ms_e / ms_k, 0, 1), 0.0)
        scale_r = np.sqrt(replicates / (replicates - 1) * share_r)
        scale_k = np.sqrt(blocks / (blocks - 1) * share_k)
        scale_e = math.sqrt(replicates * blocks / ((replicates - 1) * (blocks - 1)))
    drawn_rows = rows[:, pick_r].mean(-1)  # (P, S)
    drawn_columns = columns[:, pick_k].mean(-1)
    drawn_residual = residual[:, pick_r[:, :, None], pick_k[:, None, :]].mean(axis=(-2, -1))
    out = (
        grand[:, None]
        + scale_r[:, None] * drawn_rows
        + scale_k[:, None] * drawn_columns
        + scale_e * drawn_residual
    )
    return out.T


def expanded_tail(level: float, df: float) -> float:
    """The tail of the bootstrap distribution a `level` interval takes, expanded for few degrees
    of freedom: the normal tail beyond Student's t quantile on `df` (Hesterberg's expanded
    percentile interval), so that a spread estimated from a handful of blocks or replicates
    widens the interval as a t interval would."""
    tail = (1 - level) / 2
    if not np.isfinite(df) or df <= 0:
        return tail
    return float(stats.norm.sf(stats.t.isf(tail, max(df, 1.0))))


def _percentiles(values: np.ndarray, tail: float) -> tuple[float, float]:
    low, high = np.quantile(values, [tail, 1 - tail])
    return float(low), float(high)


@dataclass(frozen=True)
class Crossings:
    """The learning curves of N studies (`crossings`), each with its bootstrap: arrays over studies,
    the draws study after study."""

    fit: CurveFits  # N rows
    draws: CurveFits  # N x bootstrap rows
    relative: np.ndarray  # (N, P) relative variance of each fraction's mean
    se: np.ndarray  # (N, P) standard error of each fraction's mean
    df: np.ndarray  # (N,) degrees of freedom of the spread (median over fractions)
    tail: np.ndarray  # (N,) each tail the interval cuts from the bootstrap distribution
    answer: np.ndarray  # (N,) points within the margin, at least the smallest fraction fitted
    low: np.ndarray
    high: np.ndarray


def crossings(
    means: np.ndarray,
    points: np.ndarray,
    reference_points: float,
    margin: float,
    level: float,
    bootstrap: int,
    rng: np.random.Generator,
) -> Crossings:
    """The fewest points within `margin` of the reference and their `level` intervals for N
    studies at once: `means` (N, P, R, K) block means, fractions in ascending `points` (P,); all
    fits of every study and bootstrap draw in one vectorised call. The fractions a study's fit
    leaves out (fit_from_where) are chosen once, on its data; its draws keep that choice (a draw's
    lack-of-fit test would read the draw's own noise on top of the data's)."""
    means = np.asarray(means, float)
    studies, _, replicates, blocks = means.shape
    x = np.asarray(points, float) / reference_points
    observed = means.mean(axis=(-2, -1))  # (N, P)
    variances = [_relative_variances(study) for study in means]
    relative = np.array([v for v, _ in variances])
    df = np.array([d for _, d in variances])
    tail = np.array([expanded_tail(level, d) for d in df])
    se = observed * np.sqrt(relative)
    fit = fit_from_where(x, observed, se)
    resampled = []
    for study in means:
        pick_r = rng.integers(replicates, size=(bootstrap, replicates))
        pick_k = rng.integers(blocks, size=(bootstrap, blocks))
        resampled.append(resample_means(study, pick_r, pick_k))
    draws = fit_from(x, np.concatenate(resampled), np.repeat(se, bootstrap, axis=0), fit.start)
    floor = np.asarray(points, float)
    answer = np.maximum(crossing(fit, margin) * reference_points, floor[fit.start])
    drawn = np.maximum(crossing(draws, margin) * reference_points, floor[draws.start])
    drawn = drawn.reshape(studies, bootstrap)
    low = np.array([np.quantile(d, t) for d, t in zip(drawn, tail, strict=True)])
    high = np.array([np.quantile(d, 1 - t) for d, t in zip(drawn, tail, strict=True)])
    return Crossings(fit, draws, relative, se, df, tail, answer, low, high)


def learning_curve(
    table: pd.DataFrame,
    blocks: pd.Series,
    points_by_p: Mapping[int, int],
    margin: float = MARGIN,
    level: float = LEVEL,
    bootstrap: int = BOOTSTRAP,
    seed: int = 0,
    reference: int = REFERENCE_P,
) -> LearningCurve:
    """The learning curve of validation_mse.csv's table (P, replicate, point, mse; every point in
    `blocks`): `fit_learning_curve` on its spatial block means."""
    _check(table, points_by_p, reference)
    return fit_learning_curve(
        block_means(table, blocks), points_by_p, margin, level, bootstrap, seed, reference
    )


def _not_fitted(frame: pd.DataFrame, reason: str, common: dict) -> LearningCurve:
    nan = math.nan
    return LearningCurve(
        status=NOT_FITTED,
        reason=reason,
        fractions=frame.assign(
            in_fit=False, se=nan, huber=nan, weight=nan, fitted=nan, fitted_low=nan, fitted_high=nan
        ),
        parameters=dict.fromkeys("abc", (nan, nan, nan)),
        answer=nan,
        answer_low=nan,
        answer_high=nan,
        chi2=nan,
        dof=0,
        draws=None,
        df=nan,
        tail=nan,
        **common,
    )


def _points_up(value: float) -> float:
    """A number of points: the smallest whole one at or above `value`."""
    return float(math.ceil(value - 1e-9))


def fit_learning_curve(
    means_by_p: Mapping[int, np.ndarray],
    points_by_p: Mapping[int, int],
    margin: float = MARGIN,
    level: float = LEVEL,
    bootstrap: int = BOOTSTRAP,
    seed: int = 0,
    reference: int = REFERENCE_P,
) -> LearningCurve:
    """Fit the learning curve to every fraction's (R, K) block means (threedcal.evaluate.ablation.
    block_means) and find the fewest points within `margin` of the reference, with a `level`
    percentile interval from `bootstrap` draws of replicates and blocks (seeded by `seed`)."""
    if not 0 < margin < 1:
        raise ConfigError(f"the learning curve's margin must be between 0 and 1, got {margin}")
    if not 0 < level < 1:
        raise ConfigError(f"the learning curve's interval level must be in (0, 1), got {level}")
    if bootstrap < 1:
        raise ConfigError(f"the learning curve needs at least one bootstrap draw, got {bootstrap}")
    fractions = sorted((int(p) for p in means_by_p), key=lambda p: (points_by_p.get(p, 0), p))
    if reference not in fractions:
        raise ConfigError(
            f"the learning curve needs the reference fraction P={reference}; have {fractions}"
        )
    unknown = [p for p in fractions if p not in points_by_p]
    if unknown:
        raise ConfigError(f"points probed unknown for P = {unknown} (points_by_p)")
    shapes = {np.shape(means_by_p[p]) for p in fractions}
    if len(shapes) > 1 or len(next(iter(shapes))) != 2:
        raise ConfigError(f"every fraction needs (replicates, blocks) block means, got {shapes}")
    means = np.stack([np.asarray(means_by_p[p], float) for p in fractions])  # (P, R, K)
    for i, p in enumerate(fractions):
        if not np.isfinite(means[i]).all() or (means[i] < 0).any():
            raise ConfigError(f"P={p}: block means of validation MSE must be finite and >= 0")
    replicates, blocks = means.shape[1:]
    if blocks < 2:
        raise ConfigError(
            "the validation coordinates fill one spatial block; the learning curve needs two or more"
        )
    n = np.array([points_by_p[p] for p in fractions], float)
    n_ref = float(points_by_p[reference])
    x = n / n_ref
    observed = means.mean(axis=(-2, -1))
    per_replicate = means.mean(axis=-1)  # (P, R)
    frame = pd.DataFrame(
        {
            "P": fractions,
            "points": n.astype(int),
            "mean_mse": observed,
            "replicate_low": per_replicate.min(axis=1),
            "replicate_high": per_replicate.max(axis=1),
        }
    )
    common = {
        "reference": reference,
        "reference_points": int(n_ref),
        "margin": float(margin),
        "level": float(level),
        "replicates": int(replicates),
        "blocks": int(blocks),
        "bootstrap": int(bootstrap),
        "seed": int(seed),
        "replicate_means": {p: per_replicate[i] for i, p in enumerate(fractions)},
    }
    if len(np.unique(n)) < MIN_FRACTIONS:
        listed = ", ".join(str(p) for p in fractions)
        reason = (
            f"a curve of three parameters needs {MIN_FRACTIONS} or more fractions of different "
            f"point counts; this study has P = {listed} %"
        )
        return _not_fitted(frame, reason, common)
    if not (observed > 0).all():
        zero = [p for p, m in zip(fractions, observed, strict=True) if m <= 0]
        reason = f"the mean validation MSE of P = {zero} % is zero"
        return _not_fitted(frame, reason, common)
    rng = np.random.default_rng([int(seed), 0xC0B7E])
    found = crossings(means[None], n, n_ref, margin, level, bootstrap, rng)
    fit, draws, tail, relative = found.fit, found.draws, float(found.tail[0]), found.relative[0]
    se, start = found.se[0], int(fit.start[0])
    floor = float(n[start])
    answer, low, high = (float(getattr(found, key)[0]) for key in ("answer", "low", "high"))
    parameters = {
        key: (float(getattr(fit, key)[0]), *_percentiles(getattr(draws, key), tail))
        for key in "abc"
    }
    fitted = fit.predict(x)[0]
    band = np.quantile(draws.predict(x), [tail, 1 - tail], axis=0)
    weight = fit.huber[0] / relative
    frame = frame.assign(
        in_fit=np.arange(len(fractions)) >= start,
        se=se,
        huber=fit.huber[0],
        weight=weight / np.nansum(weight),
        fitted=fitted,
        fitted_low=band[0],
        fitted_high=band[1],
    )
    return LearningCurve(
        status=FLAT if answer <= floor else FITTED,
        reason="",
        fractions=frame,
        parameters=parameters,
        answer=_points_up(answer),
        answer_low=_points_up(low),
        answer_high=_points_up(high),
        chi2=float(fit.chi2[0]),
        dof=int(fit.dof[0]),
        draws=draws,
        df=float(found.df[0]),
        tail=tail,
        **common,
    )


CURVE_COLUMNS = ["quantity", "P", "points", "value", "low", "high", "note"]


def curve_table(curve: LearningCurve) -> pd.DataFrame:
    """stats/learning_curve.csv: the answer and the fit's parameters with their intervals, the
    fit's quality and design, then per P the observed and fitted mean validation MSE."""
    interval = f"{curve.level * 100:g} % bootstrap"
    rows = [
        {
            "quantity": "points_within_margin",
            "value": curve.answer,
            "low": curve.answer_low,
            "high": curve.answer_high,
            "note": curve.status if curve.status != NOT_FITTED else f"{NOT_FITTED}: {curve.reason}",
        },
        {
            "quantity": "level",
            "value": curve.level,
            "note": "of the bootstrap percentile intervals",
        },
        {
            "quantity": "margin",
            "P": curve.reference,
            "points": curve.reference_points,
            "value": curve.margin,
            "note": "relative to the curve at the reference fraction (P, points)",
        },
    ]
    meaning = {
        "a": "asymptote: MSE no number of points removes",
        "b": f"MSE(n_ref) - a: what P = {curve.reference} % could still gain",
        "c": "exponent: MSE(n) = a + b (n / n_ref)^-c",
    }
    rows += [
        {"quantity": key, "value": value, "low": low, "high": high, "note": meaning[key]}
        for key, (value, low, high) in curve.parameters.items()
    ]
    rows += [
        {
            "quantity": "chi2",
            "value": curve.chi2,
            "low": float(curve.dof),
            "note": "weighted residuals squared; low: degrees of freedom"
            + (f"; p = {curve.lack_of_fit_p:.3g}" if np.isfinite(curve.lack_of_fit_p) else ""),
        },
        {
            "quantity": "design",
            "value": float(curve.bootstrap),
            "low": float(curve.replicates),
            "high": float(curve.blocks),
            "note": f"value: bootstrap draws (seed {curve.seed}); low: replicates; high: blocks",
        },
        {
            "quantity": "fitted_from",
            "P": None
            if curve.status == NOT_FITTED
            else min(
                curve.fractions.loc[curve.fractions["in_fit"].astype(bool), "P"], default=None
            ),
            "points": None if curve.status == NOT_FITTED else curve.smallest_points,
            "note": "the smallest fraction fitted (smaller ones: before the power law holds)",
        },
    ]
    for row in curve.fractions.itertuples():
        common = {"P": int(row.P), "points": int(row.points)}
        left_out = curve.status != NOT_FITTED and not row.in_fit
        where = "; left out of the fit: before the power law holds" if left_out else ""
        rows += [
            {
                **common,
                "quantity": "observed_mse",
                "value": row.mean_mse,
                "low": row.replicate_low,
                "high": row.replicate_high,
                "note": "mean of block means; low/high: lowest and highest replicate",
            },
            {
                **common,
                "quantity": "fitted_mse",
                "value": row.fitted,
                "low": row.fitted_low,
                "high": row.fitted_high,
                "note": f"{interval} band{where}",
            },
            {
                **common,
                "quantity": "weight",
                "value": row.weight,
                "low": row.se,
                "high": row.huber,
                "note": "share of the fit; low: standard error; high: Huber weight (1: on the curve)"
                + where,
            },
        ]
    frame = pd.DataFrame(rows, columns=CURVE_COLUMNS)
    for column in ("P", "points"):
        frame[column] = frame[column].astype("Int64")
    return frame
