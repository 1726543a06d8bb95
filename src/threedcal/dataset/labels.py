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
peak of 0.904 mm at 45° instead of 1.000 (docs/explanation/labels.md).

On a domed gel (a DIGIT's) the ball meets a surface that falls away from the apex: the gel is
pushed where the ball lies below the *undeformed* surface, so the depth (from that surface) is
``max(0, d − R + sqrt(R² − r²) − Δ)`` with Δ the dome's sag relative to its sag under the axis
(`LocalDome`). The contact is no longer a circle about the axis and the labels carry the dome's
tilt; along each pixel edge the interval where the depth is positive is found from the tilted
plane's exact roots refined by Newton steps, and the integral over it stays in closed form.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

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


@dataclass(frozen=True)
class LocalDome:
    """The undeformed gel around one press: its sag relative to the sag under the press axis is
    ``kx (2 x0 x + x²) + ky (2 y0 y + y²)`` mm at (x, y) mm from the axis, (x0, y0) being the axis's
    position from the dome's apex (profile ``gel.dome``; both curvatures >= 0)."""

    kx_per_mm: float
    ky_per_mm: float
    x0_mm: float
    y0_mm: float

    def sag_mm(self, x_mm, y_mm):
        return self.kx_per_mm * (2 * self.x0_mm * x_mm + x_mm * x_mm) + self.ky_per_mm * (
            2 * self.y0_mm * y_mm + y_mm * y_mm
        )


def local_dome(
    dome: Mapping | None, center_px, image_shape: tuple[int, int], px_per_mm: float
) -> LocalDome | None:
    """The profile's `gel.dome` (mm about the image centre) as seen from a press at `center_px` in an
    image of `image_shape` (rows, cols) at `px_per_mm`; None for a flat gel."""
    if not dome:
        return None
    height, width = image_shape
    return LocalDome(
        float(dome["kx_per_mm"]),
        float(dome["ky_per_mm"]),
        (center_px[0] - (width - 1) / 2) / px_per_mm - float(dome.get("apex_x_mm", 0.0)),
        (center_px[1] - (height - 1) / 2) / px_per_mm - float(dome.get("apex_y_mm", 0.0)),
    )


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
    dome: LocalDome | None = None,
) -> np.ndarray:
    """Depth map (mm, positive into the gel, from the undeformed surface) of the sphere's imprint at
    pixel centres, float64 (H, W). `dome`: the gel's dome about this press (None: flat)."""
    _check_sphere(radius_mm, depth_mm)
    x, y = _offsets_mm(shape, center_px, px_per_mm)
    r2 = x * x + y * y
    inside = r2 < radius_mm * radius_mm
    cap = depth_mm - radius_mm + np.sqrt(np.where(inside, radius_mm * radius_mm - r2, 0.0))
    if dome is not None:
        cap = cap - dome.sag_mm(x, y)
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


_NEWTON_STEPS = 4  # the dome's curvature moves a root by ~γc²/f'; four steps leave < 1e-12 mm


def _domed_line_integral(u, v0, v1, radius_mm, depth_mm, k_u, u0, k_v, w0) -> np.ndarray:
    """∫ max(z, 0) dv from v0 to v1 along the line at u, with z = d − R + sqrt(c² − v²) − Δ for
    |v| < c = sqrt(R² − u²) (no surface beyond) and Δ = k_u (2 u0 u + u²) + k_v (2 w0 v + v²).

    With v = c sin θ, z = K + c cos θ − β c sin θ − γ c² sin² θ (K = d − R − k_u(2 u0 u + u²),
    β = 2 k_v w0, γ = k_v). Without γ, z = K + c sqrt(1 + β²) cos(θ + atan β): the interval of
    contact is exact. γ ≥ 0 only lowers z, so the true interval lies inside that one; Newton steps
    from its ends (where z ≤ 0) move inward onto the roots. An end at θ = ±π/2 where z > 0 is a wall.
    """
    c2 = np.maximum(radius_mm * radius_mm - u * u, 0.0)
    c = np.sqrt(c2)
    K = depth_mm - radius_mm - k_u * (2.0 * u0 * u + u * u)
    beta, gamma = 2.0 * k_v * w0, k_v
    amp = c * math.sqrt(1.0 + beta * beta)
    phi = math.atan(beta)
    ratio = np.where(amp > 0, -K / np.where(amp > 0, amp, 1.0), 2.0)
    touching = ratio < 1.0
    half = np.arccos(np.clip(ratio, -1.0, 1.0))
    edge = 0.5 * math.pi
    bounds = []
    for sign in (-1.0, 1.0):
        theta = np.clip(-phi + sign * half, -edge, edge)
        if gamma > 0:
            outer = theta
            for _ in range(_NEWTON_STEPS):
                s_, c_ = np.sin(theta), np.cos(theta)
                z = K + c * c_ - beta * c * s_ - gamma * c2 * s_ * s_
                slope = -c * s_ - beta * c * c_ - 2.0 * gamma * c2 * s_ * c_
                step = np.where(
                    (z < 0) & (sign * slope < 0), -z / np.where(slope != 0, slope, 1.0), 0.0
                )
                theta = np.clip(theta + step, -edge, edge)
                # never past the start (the γ = 0 root) nor across the crest
                theta = np.where(sign < 0, np.maximum(theta, outer), np.minimum(theta, outer))
        bounds.append(c * np.sin(theta))
    lo = np.maximum(np.where(touching, bounds[0], 0.0), v0)
    hi = np.minimum(np.where(touching, bounds[1], 0.0), v1)
    hi = np.maximum(hi, lo)
    safe_c = np.where(c > 0, c, 1.0)

    def antiderivative(v):
        ratio_v = np.clip(v / safe_c, -1.0, 1.0)
        return (
            K * v
            - 0.5 * beta * v * v
            - gamma * v * v * v / 3.0
            + 0.5 * (v * np.sqrt(np.maximum(c2 - v * v, 0.0)) + c2 * np.arcsin(ratio_v))
        )

    return np.where(touching, antiderivative(hi) - antiderivative(lo), 0.0)


def sphere_gradients(
    shape: tuple[int, int],
    center_px: tuple[float, float],
    radius_mm: float,
    depth_mm: float,
    px_per_mm: float,
    max_slope_deg: float | None = DEFAULT_MAX_SLOPE_DEG,
    dome: LocalDome | None = None,
) -> np.ndarray:
    """Gradient labels (H, W, 2) float32: [..., 0] = ∂z/∂x (columns), [..., 1] = ∂z/∂y (rows).

    Each is the mean over the pixel's area (see the module docstring); `max_slope_deg` clamps;
    `dome`: the gel's dome about this press (None: flat)."""
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
        if dome is None:
            along, vertical, horizontal = _line_integral, (), ()
        else:
            along = _domed_line_integral
            vertical = (dome.kx_per_mm, dome.x0_mm, dome.ky_per_mm, dome.y0_mm)
            horizontal = (dome.ky_per_mm, dome.y0_mm, dome.kx_per_mm, dome.x0_mm)
        along_x = along(
            x_edges[None, :],
            (y - 0.5 * pitch)[:, None],
            (y + 0.5 * pitch)[:, None],
            radius_mm,
            depth_mm,
            *vertical,
        )
        along_y = along(
            y_edges[:, None],
            (x - 0.5 * pitch)[None, :],
            (x + 0.5 * pitch)[None, :],
            radius_mm,
            depth_mm,
            *horizontal,
        )
        area = pitch * pitch
        out[r0:r1, c0:c1, 0] = np.diff(along_x, axis=1) / area
        out[r0:r1, c0:c1, 1] = np.diff(along_y, axis=0) / area
    if limit_deg is not None:
        limit = math.tan(math.radians(limit_deg))
        magnitude = np.hypot(out[..., 0], out[..., 1])
        out *= np.where(magnitude > limit, limit / np.maximum(magnitude, 1e-300), 1.0)[..., None]
    return out.astype(np.float32)
