"""Exact gradient labels of a sphere pressed into the gel: each pixel's mean slope over its area.

A ball of radius R pressed to depth d (mm, positive into the gel) leaves the gel surface at depth
``z(r) = d - R + sqrt(R² - r²)`` inside the contact radius ``a = sqrt(2Rd - d²)`` and at zero outside;
once d ≥ R the contact is the ball's equator (a = R) and its rim a vertical wall d − R high. Image
frame: x along columns (right), y along rows (down), gradients dimensionless (x, y and z in mm).

The point gradient ``∂z/∂x = -x / sqrt(R² - r²)`` grows without bound toward r = R, so a label
sampled at pixel centres is arbitrary near a deep press's rim (and infinite on a vertical wall).
The label of a pixel is instead the *pixel-integrated* (cell-average) gradient: the mean of ∂z/∂x
over the pixel's square, which is the difference of z's mean along the pixel's right and left
edges divided by the pixel width — finite for any surface, a wall included (it holds the wall's
whole height), and equal to the point gradient to second order wherever the surface is smooth.
This matches the integrators' convention (threedcal.depth: the depth step across the edge between
two pixels is the mean of their gradients), so integrating perfect labels gives back the depth:
the spherical cap to well under a micrometre, the volume to 0.05 %, and a vertical wall as a step
spread over the two or three pixels next to it (tests/dataset/test_labels.py).

``max_slope_deg`` optionally clamps each label's slope magnitude (direction kept). That is a
deviation from the paper (the authors label up to about 84°): clamped labels are not the gradient
of any surface — a perfect model of them integrates the calibration press (R 2 mm, d 1 mm) to a
peak of 0.904 mm at 45° instead of 1.000 (docs/labels.md).
"""

from __future__ import annotations

import math

import numpy as np

from threedcal.errors import ConfigError

# No clamp: labels are the physical (pixel-integrated) gradients. A number clamps (a deviation).
DEFAULT_MAX_SLOPE_DEG: float | None = None


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


def check_max_slope(max_slope_deg: float | None) -> float | None:
    """None (physical labels) or a clamp angle in (0, 90) degrees."""
    if max_slope_deg is None:
        return None
    value = float(max_slope_deg)
    if not 0 < value < 90:
        raise ConfigError(f"max_slope_deg must lie in (0, 90) or be null, got {max_slope_deg!r}")
    return value


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
    """Depth map (mm, positive into the gel) of the sphere's imprint at pixel centres, float64 (H, W)."""
    _check_sphere(radius_mm, depth_mm)
    x, y = _offsets_mm(shape, center_px, px_per_mm)
    r2 = x * x + y * y
    inside = r2 < radius_mm * radius_mm
    cap = depth_mm - radius_mm + np.sqrt(np.where(inside, radius_mm * radius_mm - r2, 0.0))
    return np.where(inside, np.maximum(cap, 0.0), 0.0)


def _line_integral(u, v0, v1, radius_mm: float, depth_mm: float) -> np.ndarray:
    """∫ z dv from v0 to v1 along the line at distance u (mm) from the sphere's axis (arrays broadcast).

    Where the imprint is non-zero, |v| < b (the half chord), z = (d − R) + sqrt(c² − v²) with
    c² = R² − u², whose antiderivative is (d − R) v + (v sqrt(c² − v²) + c² asin(v / c)) / 2.
    """
    c2 = np.maximum(radius_mm * radius_mm - u * u, 0.0)
    floor = max(radius_mm - depth_mm, 0.0)  # the cap meets z = 0 where sqrt(c² − v²) = R − d
    half_chord = np.sqrt(np.maximum(c2 - floor * floor, 0.0))
    lo = np.clip(v0, -half_chord, half_chord)
    hi = np.clip(v1, -half_chord, half_chord)
    c = np.sqrt(c2)
    safe_c = np.where(c > 0, c, 1.0)

    def antiderivative(v):
        ratio = np.clip(v / safe_c, -1.0, 1.0)
        return 0.5 * (v * np.sqrt(np.maximum(c2 - v * v, 0.0)) + c2 * np.arcsin(ratio))

    return (depth_mm - radius_mm) * (hi - lo) + antiderivative(hi) - antiderivative(lo)


def sphere_gradients(
    shape: tuple[int, int],
    center_px: tuple[float, float],
    radius_mm: float,
    depth_mm: float,
    px_per_mm: float,
    max_slope_deg: float | None = DEFAULT_MAX_SLOPE_DEG,
) -> np.ndarray:
    """Gradient labels (H, W, 2) float32: [..., 0] = ∂z/∂x (columns), [..., 1] = ∂z/∂y (rows).

    Each is the mean over the pixel's area (see the module docstring); `max_slope_deg` clamps."""
    _check_sphere(radius_mm, depth_mm)
    limit_deg = check_max_slope(max_slope_deg)
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ConfigError(f"px_per_mm must be a positive finite number, got {px_per_mm!r}")
    height, width = shape
    out = np.zeros((height, width, 2), dtype=np.float64)
    # Only pixels within R (plus one pixel) of the centre can touch the imprint.
    cx, cy = center_px
    reach = radius_mm * px_per_mm + 1.0
    c0, c1 = max(int(math.floor(cx - reach)), 0), min(int(math.ceil(cx + reach)) + 1, width)
    r0, r1 = max(int(math.floor(cy - reach)), 0), min(int(math.ceil(cy + reach)) + 1, height)
    if depth_mm > 0 and c1 > c0 and r1 > r0:
        pitch = 1.0 / px_per_mm
        x = (np.arange(c0, c1, dtype=np.float64) - cx) * pitch
        y = (np.arange(r0, r1, dtype=np.float64) - cy) * pitch
        x_edges = np.append(x - 0.5 * pitch, x[-1] + 0.5 * pitch)
        y_edges = np.append(y - 0.5 * pitch, y[-1] + 0.5 * pitch)
        # mean of z along each vertical pixel edge (rows) and each horizontal one (columns)
        along_x = _line_integral(
            x_edges[None, :],
            (y - 0.5 * pitch)[:, None],
            (y + 0.5 * pitch)[:, None],
            radius_mm,
            depth_mm,
        )
        along_y = _line_integral(
            y_edges[:, None],
            (x - 0.5 * pitch)[None, :],
            (x + 0.5 * pitch)[None, :],
            radius_mm,
            depth_mm,
        )
        area = pitch * pitch
        out[r0:r1, c0:c1, 0] = np.diff(along_x, axis=1) / area
        out[r0:r1, c0:c1, 1] = np.diff(along_y, axis=0) / area
    if limit_deg is not None:
        limit = math.tan(math.radians(limit_deg))
        magnitude = np.hypot(out[..., 0], out[..., 1])
        out *= np.where(magnitude > limit, limit / np.maximum(magnitude, 1e-300), 1.0)[..., None]
    return out.astype(np.float32)
