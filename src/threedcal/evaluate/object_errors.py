"""Test-object errors (paper Sec. IV, Table II): MAE by type under two protocols.

Type 1 errors sit where the ground truth is 0 (the object does not touch: any predicted depth is
wrong); Type 2 where it is not (the shape inside the contact). All reported in µm.

- `printer`: the ground truth sits where the printer put the object (`printer_press`): its pose
  through the registration, its depth from the commanded Z. Nothing is fitted to the prediction.
- `paper`: the authors' protocol for hand presses (`evaluate_press`): the ground truth is moved to
  the prediction by cross-correlation and its depth fitted to it, which also absorbs part of the
  error it should show (a prediction too shallow everywhere is fitted shallower).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import stdtrit

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import contrast
from threedcal.evaluate.align import align_xy
from threedcal.evaluate.groundtruth import HeightMap, check_indentation, surface_height
from threedcal.evaluate.mesh import Mesh

ERROR_COLUMNS = ("object", "P", "overall_um", "type1_um", "type2_um")
PROTOCOLS = ("printer", "paper")  # the headline first

# Paper Table II, Type 2 MAE (µm) of real sensors at P = 80 %: the yardstick.
PAPER_TYPE2_UM = {
    "digit": {"hemispheres": 107.0, "pill": 65.0, "pawn": 296.0},
    "gelsight_mini": {"hemispheres": 172.0, "pill": 153.0, "pawn": 290.0},
}


def fit_indentation(
    pred: np.ndarray,
    height: HeightMap | np.ndarray,
    *,
    bounds: tuple[float, float],
    mask: np.ndarray | None = None,
) -> float:
    """Indentation d in `bounds` minimising Σ (pred − max(0, d − h))² over the (masked) pixels.

    The ground truth is not linear in d (the contact grows with it), so the cost is piecewise
    quadratic and need not be convex. Between consecutive sorted heights the set of touching pixels
    is fixed and the optimum is closed-form; every piece is solved and the best taken: the global
    minimum, exactly, in O(n log n).
    """
    h = height.height_mm if isinstance(height, HeightMap) else np.asarray(height, dtype=np.float64)
    p = np.asarray(pred, dtype=np.float64)
    if p.shape != h.shape:
        raise ConfigError(f"fit_indentation: prediction {p.shape} and heights {h.shape} differ")
    lo, hi = float(bounds[0]), float(bounds[1])
    if not (0 <= lo <= hi and np.isfinite(hi)):
        raise ConfigError(f"fit_indentation: bounds must satisfy 0 <= low <= high, got {bounds}")
    keep = np.isfinite(p) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(p))
    p, h = p[keep], h[keep]
    touch = np.isfinite(h) & (h < hi)  # pixels that can touch within the bounds
    order = np.argsort(h[touch], kind="stable")
    hs, ps = h[touch][order], p[touch][order]
    if len(hs) == 0:
        return lo
    k = np.arange(1, len(hs) + 1)
    s1 = np.cumsum(ps + hs)
    s2 = np.cumsum((ps + hs) ** 2)
    p2 = np.cumsum(ps**2)
    left = np.maximum(hs, lo)
    right = np.minimum(np.append(hs[1:], np.inf), hi)
    ok = left <= right
    d = np.clip(s1 / k, left, right)
    # cost minus the constant Σ p² over all pixels: pieces with k touching pixels
    cost = np.where(ok, -p2 + s2 - 2 * d * s1 + k * d**2, np.inf)
    best = int(np.argmin(cost))
    if lo <= hs[0] and cost[best] >= 0:  # the piece before any contact (cost 0 there) wins
        return lo
    return float(d[best])


def depth_errors_um(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """MAE (µm) overall, Type 1 (gt == 0) and Type 2 (gt != 0), with the pixel counts."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ConfigError(f"prediction {pred.shape} and ground truth {gt.shape} differ in shape")
    keep = np.ones(pred.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    keep &= np.isfinite(pred) & np.isfinite(gt)
    err = np.abs(pred - gt)[keep] * 1000.0
    type2 = gt[keep] != 0

    def mae(values: np.ndarray) -> float:
        return float(values.mean()) if values.size else float("nan")

    return {
        "overall_um": mae(err),
        "type1_um": mae(err[~type2]),
        "type2_um": mae(err[type2]),
        "n_type1": int((~type2).sum()),
        "n_type2": int(type2.sum()),
    }


def error_row(object_name: str, p: int, pred: np.ndarray, gt: np.ndarray) -> dict:
    """One row of `objects/errors.csv`: object, P, overall_um, type1_um, type2_um."""
    errors = depth_errors_um(pred, gt)
    return {"object": object_name, "P": int(p), **{k: errors[k] for k in ERROR_COLUMNS[2:]}}


def pixel_errors_um(object_name: str, pred: np.ndarray, gt: np.ndarray) -> pd.DataFrame:
    """Long table of signed pixelwise errors (pred − gt, µm) with their type, for violin plots."""
    pred = np.asarray(pred, dtype=np.float64).ravel()
    gt = np.asarray(gt, dtype=np.float64).ravel()
    return pd.DataFrame(
        {
            "object": object_name,
            "type": np.where(gt != 0, "Type 2", "Type 1"),
            "error_um": (pred - gt) * 1000.0,
        }
    )


@dataclass(frozen=True)
class PressEvaluation:
    """The aligned, depth-fitted ground truth of one press and its errors."""

    gt_mm: np.ndarray
    surface: HeightMap
    shift_px: tuple[float, float]
    indentation_mm: float
    errors: dict


def evaluate_press(
    pred: np.ndarray,
    mesh: Mesh,
    *,
    px_per_mm: float,
    nominal_indentation_mm: float,
    max_penetration_mm: float,
    center_px: Sequence[float] | None = None,
    rotation_deg: float = 0.0,
    linear_px_per_mm: np.ndarray | None = None,
    surface: HeightMap | None = None,
    max_shift_px: float | None = None,
    iterations: int = 3,
    min_shift_px: float = 0.05,
    dome: Mapping | None = None,
) -> PressEvaluation:
    """The paper's protocol on one predicted depth map: align in x, y, fit the depth, score.

    The ground truth at the nominal pose and depth (give the printer's pose: `center_px` and
    `rotation_deg`, or the registration's `linear_px_per_mm`) is aligned to the prediction by
    cross-correlation (sub-pixel); the mesh is re-rasterised at the corrected pose (exact, no image
    interpolation); the indentation is fitted; and the alignment is repeated with the fitted depth,
    keeping the pose and depth with the least squared error. Rotation is never changed.
    `surface`: the ground truth already rasterised at that starting pose (saves one raster). A
    shift under `min_shift_px` in x and y (below the sub-pixel peak's precision) counts as none:
    the alignment has converged and the mesh is not rasterised again. `dome`: the gel's (profile
    `gel.dome`), which the ground truth is measured from (`surface_height`).
    """
    pred = np.asarray(pred, dtype=np.float64)
    check_indentation(nominal_indentation_mm, max_penetration_mm)
    if pred.ndim != 2:
        raise ConfigError(f"the predicted depth map must be 2D, got shape {pred.shape}")
    h, w = pred.shape
    center = np.array(center_px if center_px is not None else ((w - 1) / 2, (h - 1) / 2), float)

    def raster(at: np.ndarray) -> HeightMap:
        return surface_height(
            mesh, pred.shape, px_per_mm, at, rotation_deg, linear_px_per_mm, dome=dome
        )

    if surface is None:
        surface = raster(center)
    elif surface.shape != pred.shape:
        raise ConfigError(f"surface {surface.shape} and prediction {pred.shape} differ in shape")
    depth = nominal_indentation_mm
    total = np.zeros(2)
    best = None
    for _ in range(max(1, iterations)):
        (dx, dy), _ = align_xy(pred, surface.depth(depth), max_shift_px=max_shift_px, subpixel=True)
        moved = max(abs(dx), abs(dy)) >= min_shift_px
        if moved:
            total = total + (dx, dy)
            surface = raster(center + total)
        depth = fit_indentation(pred, surface, bounds=(0.0, max_penetration_mm))
        sse = float(((pred - surface.depth(depth)) ** 2).sum())
        # vertical walls make the correlation step as a wall crosses a pixel centre: a
        # refinement is kept only if it fits better
        if best is None or sse < best[0]:
            best = (sse, surface, depth, total.copy())
        elif not moved:
            break
    _, surface, depth, total = best
    gt = surface.depth(depth)
    return PressEvaluation(
        gt, surface, (float(total[0]), float(total[1])), depth, depth_errors_um(pred, gt)
    )


def printer_press(
    pred: np.ndarray,
    surface: HeightMap,
    depth_mm: float,
    *,
    max_penetration_mm: float | None = None,
) -> PressEvaluation:
    """The printer protocol on one predicted depth map: the ground truth where the printer put
    the object (`surface`, posed through the registration) at the depth it commanded; scored as is."""
    pred = np.asarray(pred, dtype=np.float64)
    if pred.shape != surface.shape:
        raise ConfigError(f"prediction {pred.shape} and ground truth {surface.shape} differ")
    gt = surface.depth(depth_mm, max_penetration_mm)
    return PressEvaluation(gt, surface, (0.0, 0.0), float(depth_mm), depth_errors_um(pred, gt))


def mean_interval(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its `level` t interval over independent presses: mean ± t(n−1) · sd / √n.

    NaN values (a press with no Type 2 pixel) are left out; fewer than two values give NaN bounds.
    """
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    mean = float(x.mean())
    if x.size < 2:
        return mean, float("nan"), float("nan")
    half = float(stdtrit(x.size - 1, 0.5 + level / 2) * x.std(ddof=1) / np.sqrt(x.size))
    return mean, mean - half, mean + half


def crossed_mean_interval(cells, level: float = 0.95) -> tuple[float, float, float]:
    """Mean of a (replicates, presses) table and its `level` t interval when both are random
    draws: every replicate's model (its own subset and initialisation) scores the same presses.

    The two-way random-effects grand mean of `threedcal.evaluate.ablation.contrast` (replicate +
    press + residual, Satterthwaite's degrees of freedom): the model's spread between replicates
    widens the interval, which a t interval over one model's presses leaves out. Presses with a NaN
    in any replicate (no Type 2 pixel) are left out; one replicate gives `mean_interval`.
    """
    x = np.atleast_2d(np.asarray(cells, dtype=np.float64))
    x = x[:, np.isfinite(x).all(axis=0)]
    if x.shape[0] == 1 or x.shape[1] < 2:
        return mean_interval(x.mean(axis=0), level)
    mean, se, df = (float(v) for v in contrast(x, np.zeros_like(x), 0.0))
    half = float(stdtrit(df, 0.5 + level / 2)) * se
    return mean, mean - half, mean + half
