"""Make a predicted gradient field safe to integrate: a NaN, an Inf or a 1e6 spike in one pixel
would otherwise spread through the whole depth map (every solver here is global)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from threedcal.depth.convention import check_offset, check_pair, check_px_per_mm
from threedcal.errors import ConfigError

# Steepest slope kept by default: 85 degrees (tan = 11.4). Real gel surfaces stay far below it;
# only outliers and vertical walls (not representable as gradients anyway) are clamped.
DEFAULT_MAX_ANGLE_DEG = 85.0


@dataclass(frozen=True)
class SanitizeReport:
    """What was changed: counts of pixels, and the mask of non-finite ones (set to zero slope)."""

    n_nonfinite: int
    n_clamped: int
    nonfinite: np.ndarray

    @property
    def n_changed(self) -> int:
        return self.n_nonfinite + self.n_clamped


def check_max_angle(max_angle_deg: float | None) -> float | None:
    if max_angle_deg is None:
        return None
    value = float(max_angle_deg)
    if not (0.0 < value < 90.0):
        raise ConfigError(
            f"max_angle_deg must lie in (0, 90) degrees or be None, got {max_angle_deg!r}"
        )
    return value


def sanitize_gradients(
    gx, gy, max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG
) -> tuple[np.ndarray, np.ndarray, SanitizeReport]:
    """Return (gx, gy) with non-finite pixels set to 0 and slopes clamped to a max angle.

    A pixel is non-finite when either component is NaN or +-Inf; both components become 0. A slope
    |grad z| = hypot(gx, gy) above tan(max_angle_deg) is scaled down to it, keeping its direction.
    `max_angle_deg=None` only replaces non-finite values. Inputs are never modified (an array
    comes back as given when nothing in it changed).
    """
    gx, gy = check_pair(gx, gy, "sanitize_gradients")
    max_angle = check_max_angle(max_angle_deg)
    # Fastest path, four reductions and no temporary: min and max are NaN when any value is, which
    # fails every comparison; |gx|, |gy| <= limit / sqrt(2) bounds the slope by the limit.
    bound = math.inf if max_angle is None else math.tan(math.radians(max_angle)) / math.sqrt(2.0)
    extremes = [float(f(g)) for g in (gx, gy) for f in (np.min, np.max)] if gx.size else [0.0]
    if all(-bound < value < bound for value in extremes):
        return gx, gy, SanitizeReport(0, 0, np.zeros(gx.shape, dtype=bool))
    # Fast path for the common clean field: NaN, Inf (and overflow, rechecked below) fail the test.
    with np.errstate(over="ignore", invalid="ignore"):
        slope2 = gx * gx
        slope2 += gy * gy
        if max_angle is None:
            clean = bool(np.isfinite(slope2).all())
        else:
            limit = math.tan(math.radians(max_angle))
            clean = bool((slope2 <= limit * limit).all())
    if clean:
        return gx, gy, SanitizeReport(0, 0, np.zeros(gx.shape, dtype=bool))
    finite = np.isfinite(gx) & np.isfinite(gy)
    nonfinite = ~finite
    n_nonfinite = int(nonfinite.sum())
    if n_nonfinite:
        gx = np.where(finite, gx, gx.dtype.type(0))
        gy = np.where(finite, gy, gy.dtype.type(0))
    n_clamped = 0
    if max_angle is not None:
        with np.errstate(over="ignore"):
            steep = (gx * gx + gy * gy) > limit * limit  # overflow to inf counts as steep
        n_clamped = int(steep.sum())
        if n_clamped:
            gx = np.array(gx, copy=True)
            gy = np.array(gy, copy=True)
            scale = (limit / np.hypot(gx[steep], gy[steep])).astype(gx.dtype)
            gx[steep] *= scale
            gy[steep] *= scale
    return gx, gy, SanitizeReport(n_nonfinite, n_clamped, nonfinite)


def integrator_inputs(
    gx, gy, name: str, px_per_mm: float, offset: str, max_angle_deg: float | None
):
    """The shared front of every integrator: validate, sanitise, check the scale and offset policy."""
    check_offset(offset)
    scale = check_px_per_mm(px_per_mm)
    gx, gy = check_pair(gx, gy, name)
    gx, gy, report = sanitize_gradients(gx, gy, max_angle_deg)
    return gx, gy, scale, report
