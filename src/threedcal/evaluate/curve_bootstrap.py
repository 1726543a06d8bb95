"""The learning curve's answer for many studies at once, with its bootstrap over replicates and
spatial blocks (threedcal.evaluate.learning_curve says how the draws are made)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from threedcal.evaluate.ablation import contrast
from threedcal.evaluate.power_law_fit import CurveFits, crossing, fit_from, fit_from_where

WEIGHT_CEILING = 4.0  # no fraction weighs more than this many times the median fraction


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
