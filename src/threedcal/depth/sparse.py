"""Masked, weighted least-squares integration with a sparse direct solver.

Minimises sum_e w_e (z_q - z_p - e_pq)^2 over the grid edges, e_pq the mean of the two pixel-centre
gradients (the shared convention). An edge's weight is the smaller of its two pixels' weights; an
edge touching an invalid pixel (masked out, weight 0, or non-finite gradient) carries no data and
only a tiny membrane term (weight FILL * mean weight, target 0). That term keeps the system
connected — masked pixels come back as a smooth (harmonic) fill, and separate valid regions get a
common offset — while biasing the valid pixels by a relative 1e-10 at most. One pixel is pinned to
remove the constant null space; the offset policy then sets the constant over the valid pixels.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from threedcal.depth.convention import apply_offset, edge_gradients
from threedcal.depth.sanitize import DEFAULT_MAX_ANGLE_DEG, integrator_inputs
from threedcal.errors import ConfigError

FILL = 1e-10
FILLS = ("harmonic", "nan")


def _pixel_weights(shape, mask, weights, nonfinite) -> np.ndarray:
    w = np.ones(shape, dtype=np.float64)
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != shape:
            raise ConfigError(
                f"lstsq_sparse: weights {weights.shape} must match the gradients {shape}"
            )
        if not np.all(np.isfinite(weights)) or np.any(weights < 0):
            raise ConfigError("lstsq_sparse: weights must be finite and >= 0")
        w = weights.copy()
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != shape:
            raise ConfigError(f"lstsq_sparse: mask {mask.shape} must match the gradients {shape}")
        if mask.dtype != bool:
            raise ConfigError(
                f"lstsq_sparse: mask must be boolean (True = valid), got {mask.dtype}"
            )
        w[~mask] = 0.0
    w[nonfinite] = 0.0
    return w


def lstsq_px(
    gx: np.ndarray, gy: np.ndarray, pixel_weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depth in pixel units (pixel 0 pinned at 0) and the valid-pixel mask."""
    h, w = gx.shape
    n = h * w
    ex, ey = edge_gradients(gx.astype(np.float64), gy.astype(np.float64))
    idx = np.arange(n).reshape(h, w)
    p = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    q = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    target = np.concatenate([ex.ravel(), ey.ravel()])
    wp, wq = pixel_weights.ravel()[p], pixel_weights.ravel()[q]
    we = np.minimum(wp, wq)
    valid_pixels = pixel_weights > 0
    scale = pixel_weights[valid_pixels].mean() if valid_pixels.any() else 1.0
    data = we > 0
    we = np.where(data, we, FILL * scale)
    target = np.where(data, target, 0.0)
    flux = we * target
    b = np.bincount(q, flux, minlength=n) - np.bincount(p, flux, minlength=n)
    rows = np.concatenate([p, q, p, q])
    cols = np.concatenate([p, q, q, p])
    vals = np.concatenate([we, we, -we, -we])
    a = sp.csc_matrix((vals, (rows, cols)), shape=(n, n))
    z = np.zeros(n)
    if n > 1:
        z[1:] = sla.spsolve(a[1:, 1:], b[1:], permc_spec="MMD_AT_PLUS_A")
    return z.reshape(h, w), valid_pixels


def lstsq_sparse(
    gx,
    gy,
    *,
    px_per_mm: float = 1.0,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    mask=None,
    weights=None,
    fill: str = "harmonic",
    workers: int | None = None,
) -> np.ndarray:
    """Depth (mm) by weighted least squares over the valid pixels (mask True = valid).

    Non-finite gradients count as invalid (not as zero slope). `fill`: 'harmonic' returns the
    smooth fill at invalid pixels, 'nan' returns NaN there. `workers` is accepted for a uniform
    signature and unused (SuperLU is single-threaded).
    """
    if fill not in FILLS:
        raise ConfigError(
            f"lstsq_sparse: fill {fill!r} is not allowed (allowed: {', '.join(FILLS)})"
        )
    gx, gy, scale, report = integrator_inputs(
        gx, gy, "lstsq_sparse", px_per_mm, offset, max_angle_deg
    )
    pixel_weights = _pixel_weights(gx.shape, mask, weights, report.nonfinite)
    z, valid = lstsq_px(gx, gy, pixel_weights)
    z = (z / scale).astype(gx.dtype, copy=False)
    apply_offset(z, offset, valid if valid.any() else None)
    if fill == "nan":
        z[~valid] = np.nan
    return z
