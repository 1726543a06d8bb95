"""Align a ground-truth depth map to a predicted one in x, y by 2D cross-correlation (paper Sec. IV).

A hand-pressed object never sits exactly where the ground truth assumes; the shift that maximises
the (zero-padded, so not circular) cross-correlation of the two depth maps is taken as the offset.
"""

from __future__ import annotations

import numpy as np
from scipy import fft, ndimage

from threedcal.errors import ConfigError


def cross_correlation(
    pred: np.ndarray, gt: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear cross-correlation c[dy, dx] = Σ pred(y, x) · gt(y − dy, x − dx) for every overlap.

    Returns (c, dys, dxs): c has shape (2H − 1, 2W − 1); dys, dxs are its shifts (px).
    """
    h, w = pred.shape
    shape = (fft.next_fast_len(2 * h - 1, real=True), fft.next_fast_len(2 * w - 1, real=True))
    spec = fft.rfft2(pred, shape) * np.conj(fft.rfft2(gt, shape))
    full = fft.irfft2(spec, shape)
    dys = np.arange(-(h - 1), h)
    dxs = np.arange(-(w - 1), w)
    return full[np.ix_(dys % shape[0], dxs % shape[1])], dys, dxs


def _parabola_offset(left: float, mid: float, right: float) -> float:
    denom = left - 2 * mid + right
    if denom >= 0:  # not a strict maximum
        return 0.0
    return float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5))


def align_xy(
    pred: np.ndarray,
    gt: np.ndarray,
    *,
    max_shift_px: float | None = None,
    subpixel: bool = False,
) -> tuple[tuple[float, float], np.ndarray]:
    """Shift (dx, dy) in px (x = column, y = row) that best lays `gt` onto `pred`, and the shifted gt.

    shifted(y, x) = gt(y − dy, x − dx); what moves in from outside the image is 0 (no contact).
    Integer shifts are exact; `subpixel` refines the peak by a parabola per axis and shifts with
    linear interpolation (re-rasterising the ground truth at the refined pose is more exact; see
    :func:`threedcal.evaluate.object_errors.evaluate_press`). `max_shift_px` limits the search.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.ndim != 2 or pred.shape != gt.shape:
        raise ConfigError(f"align_xy needs two 2D maps of one shape, got {pred.shape}, {gt.shape}")
    if not (np.all(np.isfinite(pred)) and np.all(np.isfinite(gt))):
        raise ConfigError("align_xy: depth maps must be finite")
    corr, dys, dxs = cross_correlation(pred, gt)
    if max_shift_px is not None:
        far = (np.abs(dys)[:, None] > max_shift_px) | (np.abs(dxs)[None, :] > max_shift_px)
        corr = np.where(far, -np.inf, corr)
    iy, ix = np.unravel_index(int(np.argmax(corr)), corr.shape)
    dy, dx = float(dys[iy]), float(dxs[ix])
    if subpixel:
        if 0 < iy < corr.shape[0] - 1 and np.isfinite(corr[iy - 1, ix] + corr[iy + 1, ix]):
            dy += _parabola_offset(corr[iy - 1, ix], corr[iy, ix], corr[iy + 1, ix])
        if 0 < ix < corr.shape[1] - 1 and np.isfinite(corr[iy, ix - 1] + corr[iy, ix + 1]):
            dx += _parabola_offset(corr[iy, ix - 1], corr[iy, ix], corr[iy, ix + 1])
    return (dx, dy), shift_image(gt, dx, dy)


def shift_image(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """image moved by (dx, dy) px, zero fill; exact for integer shifts, bilinear otherwise."""
    if float(dx).is_integer() and float(dy).is_integer():
        out = np.zeros_like(image)
        h, w = image.shape
        dx_i, dy_i = int(dx), int(dy)
        if abs(dx_i) < w and abs(dy_i) < h:
            out[max(dy_i, 0) : h + min(dy_i, 0), max(dx_i, 0) : w + min(dx_i, 0)] = image[
                max(-dy_i, 0) : h + min(-dy_i, 0), max(-dx_i, 0) : w + min(-dx_i, 0)
            ]
        return out
    return ndimage.shift(image, (dy, dx), order=1, mode="constant", cval=0.0)
