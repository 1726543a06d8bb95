"""The learning curve's power law, MSE = a + b · x^-c (a, b >= 0), fitted by Huber-weighted least
squares to many rows at once, with the small-data fractions left out where the curve misses them
(threedcal.evaluate.learning_curve says why)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from threedcal.errors import ConfigError

EXPONENTS = np.geomspace(0.02, 8.0, 110)  # the grid c is searched on, then refined between nodes


REFINE_STEPS = 24


HUBER_K = 1.345  # Huber's tuning constant: 95 % efficiency when the residuals are Gaussian


OFF_CURVE = 0.5  # a fraction whose Huber weight fell below this lies off the curve (|z| > 2.7)


IRLS_STEPS = 25


HUBER_TOL = 1e-4  # IRLS stops when no Huber weight moves more than this


MIN_CHECKED = 4  # a fit left with fewer fractions has no residual to judge it by


LACK_OF_FIT_P = 0.01


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
