"""Exact gradient labels of a sphere pressed into the gel, at sub-pixel centres.

A ball of radius R pressed to depth d (mm, positive into the gel) leaves the gel surface at depth
``z(r) = d - R + sqrt(R² - r²)`` inside the contact radius ``a = sqrt(2Rd - d²)`` and at zero outside.
Gradients are ``∂z/∂x = -x / sqrt(R² - r²)`` (x, r and z in mm, so the ratio is dimensionless), in the
image frame: x along columns (right), y along rows (down), sampled at pixel centres.

At the rim the slope is ``a / (R - d)``: finite for d < R, infinite for a hemisphere (d = R). Labels
clamp the slope magnitude to ``tan(max_slope_deg)`` (direction kept), so a deep press never yields
inf/NaN and the network never chases a singular target.
"""

from __future__ import annotations

import math

import numpy as np

from threedcal.errors import ConfigError

DEFAULT_MAX_SLOPE_DEG = 75.0


def contact_radius_mm(radius_mm: float, depth_mm: float) -> float:
    """Radius of the contact circle, sqrt(2Rd - d²); the full radius R for d >= R."""
    _check_sphere(radius_mm, depth_mm)
    depth = min(depth_mm, radius_mm)
    return math.sqrt(max(2.0 * radius_mm * depth - depth * depth, 0.0))


def _check_sphere(radius_mm: float, depth_mm: float) -> None:
    if not (math.isfinite(radius_mm) and radius_mm > 0):
        raise ConfigError(
            f"sphere radius must be a positive finite number of mm, got {radius_mm!r}"
        )
    if not (math.isfinite(depth_mm) and depth_mm >= 0):
        raise ConfigError(f"indentation depth must be a finite number of mm >= 0, got {depth_mm!r}")


def _offsets_mm(shape, center_px, px_per_mm):
    height, width = shape
    cx, cy = center_px
    x = (np.arange(width, dtype=np.float64) - cx) / px_per_mm
    y = (np.arange(height, dtype=np.float64) - cy) / px_per_mm
    return x[None, :], y[:, None]


def sphere_depth(
    shape: tuple[int, int],
    center_px: tuple[float, float],
    radius_mm: float,
    depth_mm: float,
    px_per_mm: float,
) -> np.ndarray:
    """Depth map (mm, positive into the gel) of the sphere's imprint, float64 (H, W)."""
    _check_sphere(radius_mm, depth_mm)
    x, y = _offsets_mm(shape, center_px, px_per_mm)
    r2 = x * x + y * y
    inside = r2 < radius_mm * radius_mm
    cap = depth_mm - radius_mm + np.sqrt(np.where(inside, radius_mm * radius_mm - r2, 0.0))
    return np.where(inside, np.maximum(cap, 0.0), 0.0)


def sphere_gradients(
    shape: tuple[int, int],
    center_px: tuple[float, float],
    radius_mm: float,
    depth_mm: float,
    px_per_mm: float,
    max_slope_deg: float = DEFAULT_MAX_SLOPE_DEG,
) -> np.ndarray:
    """Gradient labels (H, W, 2) float32: [..., 0] = ∂z/∂x (columns), [..., 1] = ∂z/∂y (rows)."""
    _check_sphere(radius_mm, depth_mm)
    if not 0 < max_slope_deg < 90:
        raise ConfigError(f"max_slope_deg must lie in (0, 90), got {max_slope_deg!r}")
    x, y = _offsets_mm(shape, center_px, px_per_mm)
    a = contact_radius_mm(radius_mm, depth_mm)
    r2 = x * x + y * y
    inside = r2 < a * a
    # sqrt(R² - r²) > 0 inside the contact unless d >= R; the floor keeps the division finite there.
    root = np.sqrt(np.maximum(radius_mm * radius_mm - r2, 1e-12 * radius_mm * radius_mm))
    gx = np.where(inside, -x / root, 0.0)
    gy = np.where(inside, -y / root, 0.0)
    limit = math.tan(math.radians(max_slope_deg))
    magnitude = np.hypot(gx, gy)
    scale = np.where(magnitude > limit, limit / np.maximum(magnitude, 1e-300), 1.0)
    return np.stack([gx * scale, gy * scale], axis=-1).astype(np.float32)
