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
from threedcal.evaluate.ablation import MARGIN, REFERENCE_P, block_means
from threedcal.evaluate.curve_bootstrap import crossings
from threedcal.evaluate.power_law_fit import CurveFits

BOOTSTRAP = 2000
LEVEL = 0.90
MIN_FRACTIONS = 3

FITTED = "fitted"
FLAT = "at or below the smallest fraction"
NOT_FITTED = "not fitted"


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


def _percentiles(values: np.ndarray, tail: float) -> tuple[float, float]:
    low, high = np.quantile(values, [tail, 1 - tail])
    return float(low), float(high)


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


def _checked_means(means_by_p, points_by_p, margin, level, bootstrap, reference):
    """(fractions by ascending points, their (P, R, K) block means), or a ConfigError naming
    what is wrong with the inputs of `fit_learning_curve`."""
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
    return fractions, means


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
    fractions, means = _checked_means(means_by_p, points_by_p, margin, level, bootstrap, reference)
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
    return _fitted(found, frame, n, x, common)


def _fitted(
    found, frame: pd.DataFrame, n: np.ndarray, x: np.ndarray, common: dict
) -> LearningCurve:
    """The LearningCurve of a fit and its bootstrap (`crossings` of one study): its answer,
    parameters and per-fraction fit with their intervals."""
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
        in_fit=np.arange(len(frame)) >= start,
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
    rows = _summary_rows(curve) + _fraction_rows(curve)
    frame = pd.DataFrame(rows, columns=CURVE_COLUMNS)
    for column in ("P", "points"):
        frame[column] = frame[column].astype("Int64")
    return frame


def _summary_rows(curve: LearningCurve) -> list[dict]:
    """The answer, the parameters, the fit's quality and its design."""
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
    return rows


def _fraction_rows(curve: LearningCurve) -> list[dict]:
    """Per P: the observed and fitted mean validation MSE and its weight in the fit."""
    interval = f"{curve.level * 100:g} % bootstrap"
    rows = []
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
    return rows
