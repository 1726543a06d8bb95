"""The one convention every integrator shares, so their outputs are comparable pixel for pixel.

- Gradients are sampled at pixel centres (what a per-pixel network predicts), dimensionless
  dz/dx and dz/dy of depth (positive into the gel), x = column right, y = row down.
- The discrete model: the depth difference across the edge between two neighbouring pixels equals
  the mean of their two gradients (trapezoidal rule, second-order accurate). Every solver is a least
  squares fit of depth to these edge differences; they differ only in boundary model and weighting.
- Integration runs in pixel units; depth leaves in mm: depth_mm = depth_px / px_per_mm.
- The constant of integration is an explicit offset policy (see `apply_offset`).
"""

from __future__ import annotations

import math

import numpy as np

from threedcal.errors import ConfigError

OFFSETS = ("border", "mean", "min", "none")


def working_dtype(*arrays: np.ndarray) -> np.dtype:
    """float32 only when every input is float32 (speed); float64 otherwise."""
    if all(np.asarray(a).dtype == np.float32 for a in arrays):
        return np.dtype(np.float32)
    return np.dtype(np.float64)


def check_pair(gx, gy, name: str = "integrate") -> tuple[np.ndarray, np.ndarray]:
    """Validate a gradient pair (2-D, same shape, real) and return them as working-dtype arrays."""
    gx = np.asarray(gx)
    gy = np.asarray(gy)
    if gx.ndim != 2 or gy.ndim != 2:
        raise ConfigError(
            f"{name}: gradients must be 2-D (H, W) arrays, got {gx.shape} and {gy.shape}"
        )
    if gx.shape != gy.shape:
        raise ConfigError(f"{name}: gx {gx.shape} and gy {gy.shape} must have the same shape")
    if gx.size == 0:
        raise ConfigError(f"{name}: empty gradient field {gx.shape}; needs at least 1x1 pixels")
    for label, g in (("gx", gx), ("gy", gy)):
        if not (np.issubdtype(g.dtype, np.floating) or np.issubdtype(g.dtype, np.integer)):
            raise ConfigError(f"{name}: {label} must be real numbers, got dtype {g.dtype}")
    dtype = working_dtype(gx, gy)
    return gx.astype(dtype, copy=False), gy.astype(dtype, copy=False)


def check_px_per_mm(px_per_mm: float) -> float:
    value = float(px_per_mm)
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"px_per_mm must be a positive finite number, got {px_per_mm!r}")
    return value


def check_offset(offset: str) -> str:
    if offset not in OFFSETS:
        raise ConfigError(f"offset {offset!r} is not allowed (allowed: {', '.join(OFFSETS)})")
    return offset


def edge_gradients(gx: np.ndarray, gy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth differences across pixel edges from pixel-centre gradients (pixel units).

    ex[i, j] = z[i, j+1] - z[i, j] ~ (gx[i, j] + gx[i, j+1]) / 2, shape (H, W-1);
    ey[i, j] = z[i+1, j] - z[i, j] ~ (gy[i, j] + gy[i+1, j]) / 2, shape (H-1, W).
    """
    ex = 0.5 * (gx[:, 1:] + gx[:, :-1])
    ey = 0.5 * (gy[1:, :] + gy[:-1, :])
    return ex, ey


def divergence(ex: np.ndarray, ey: np.ndarray) -> np.ndarray:
    """D^T e with missing (outside) edges zero: the right side of L z = div for the grid Laplacian L."""
    h, w = ey.shape[0] + 1, ex.shape[1] + 1
    div = np.zeros((h, w), dtype=np.result_type(ex, ey))
    div[:, :-1] += ex
    div[:, 1:] -= ex
    div[:-1, :] += ey
    div[1:, :] -= ey
    return div


def consistent_gradients(z_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre gradients whose edge means are exactly the depth differences of `z_px`.

    A discrete-exact field for this convention (used to test solvers to rounding error): along
    each row gx[j+1] = 2 (z[j+1] - z[j]) - gx[j], starting from the one-sided difference.
    """
    z = np.asarray(z_px, dtype=np.float64)
    h, w = z.shape
    gx = np.zeros_like(z)
    gy = np.zeros_like(z)
    dx = np.diff(z, axis=1)
    dy = np.diff(z, axis=0)
    if w > 1:
        gx[:, 0] = dx[:, 0]
        for j in range(w - 1):
            gx[:, j + 1] = 2.0 * dx[:, j] - gx[:, j]
    if h > 1:
        gy[0, :] = dy[0, :]
        for i in range(h - 1):
            gy[i + 1, :] = 2.0 * dy[i, :] - gy[i, :]
    return gx, gy


def border_ring(shape: tuple[int, int]) -> np.ndarray:
    """Boolean mask of the outermost ring of pixels."""
    ring = np.zeros(shape, dtype=bool)
    ring[0, :] = ring[-1, :] = True
    ring[:, 0] = ring[:, -1] = True
    return ring


def _ring_values(z: np.ndarray) -> np.ndarray:
    """The outermost ring's values, each pixel once."""
    if z.shape[0] <= 2 or z.shape[1] <= 2:
        return z.ravel()
    return np.concatenate([z[0], z[-1], z[1:-1, 0], z[1:-1, -1]])


def apply_offset(z: np.ndarray, offset: str, valid: np.ndarray | None = None) -> np.ndarray:
    """Fix the constant of integration, in place, from the (valid) pixels.

    border: the median of the outermost ring is zero (the gel is untouched there; a median keeps
            a contact that crosses part of the border from lifting the rest);
    mean: the mean is zero; min: the minimum is zero (depth >= 0); none: the solver's own.
    """
    if offset == "none":
        return z
    if valid is None:
        # every pixel valid: the ring by slices, not by two full-size masks (a hot path)
        values = _ring_values(z) if offset == "border" else z.ravel()
    else:
        pick = valid.copy()
        if offset == "border":
            ring = pick & border_ring(z.shape)
            pick = ring if ring.any() else pick
        values = z[pick]
    values = values[np.isfinite(values)]
    if values.size == 0:
        return z
    if offset == "border":
        shift = np.median(values)
    elif offset == "mean":
        shift = values.mean(dtype=np.float64)
    else:
        shift = values.min()
    z -= z.dtype.type(shift)
    return z
