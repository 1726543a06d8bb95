"""Indenter shapes for the gel simulator, all in mm in the indenter's own frame.

An indenter answers one question: at a horizontal offset (dx, dy) mm from its axis, how far above its
lowest point is its surface (the *gap*, mm; +inf where it has no surface)? Pressing it `d` mm into the
gel puts the gel surface at depth `d - gap` wherever that is positive. The sphere is exact, so a
sphere of radius R pressed d deep touches the gel inside r < a = sqrt(2 R d - d^2), as the dataset
stage assumes when it computes labels.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from threedcal.errors import ConfigError


class Indenter(ABC):
    """A rigid indenter; `reach_mm` bounds its horizontal extent from its axis."""

    @property
    @abstractmethod
    def reach_mm(self) -> float: ...

    @abstractmethod
    def gap(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Surface height above the lowest point at offsets (dx, dy) mm; +inf where there is none."""

    def contact_radius_mm(self, depth_mm: float) -> float | None:
        """Exact radius of a circular contact at this depth, or None if the contact is not a disc."""
        return None


class Sphere(Indenter):
    """An exact sphere of radius `radius_mm` (a ball probe, a hemisphere test object)."""

    def __init__(self, radius_mm: float):
        if not (math.isfinite(radius_mm) and radius_mm > 0):
            raise ConfigError(f"sphere radius_mm must be a positive number, got {radius_mm!r}")
        self.radius_mm = float(radius_mm)

    @property
    def reach_mm(self) -> float:
        return self.radius_mm

    def gap(self, dx, dy):
        r2 = dx * dx + dy * dy
        inside = np.maximum(self.radius_mm**2 - r2, 0.0)
        out = self.radius_mm - np.sqrt(inside)
        return np.where(r2 <= self.radius_mm**2, out, np.inf).astype(np.float32)

    def contact_radius_mm(self, depth_mm: float) -> float:
        d = min(max(depth_mm, 0.0), self.radius_mm)  # deeper than R: the equator's vertical wall
        return math.sqrt(max(2 * self.radius_mm * d - d * d, 0.0))

    def __repr__(self) -> str:
        return f"Sphere(radius_mm={self.radius_mm})"


class Flat(Indenter):
    """A flat circular punch of radius `radius_mm`: vertical walls, the hardest case for the optics."""

    def __init__(self, radius_mm: float):
        if not (math.isfinite(radius_mm) and radius_mm > 0):
            raise ConfigError(f"flat punch radius_mm must be a positive number, got {radius_mm!r}")
        self.radius_mm = float(radius_mm)

    @property
    def reach_mm(self) -> float:
        return self.radius_mm

    def gap(self, dx, dy):
        r2 = dx * dx + dy * dy
        return np.where(r2 <= self.radius_mm**2, 0.0, np.inf).astype(np.float32)

    def contact_radius_mm(self, depth_mm: float) -> float:
        return self.radius_mm if depth_mm > 0 else 0.0

    def __repr__(self) -> str:
        return f"Flat(radius_mm={self.radius_mm})"


class Relief(Indenter):
    """Any shape given as a relief map: `relief_mm[row, col]` = how far the surface protrudes (mm).

    The map's centre pixel sits on the indenter axis; its rows run along +y and its columns along +x
    at `px_per_mm`. NaN marks "no surface". The highest protrusion is the tip (gap 0). Sampled with
    bilinear interpolation between map pixels (nearest where a neighbour is NaN).
    """

    def __init__(self, relief_mm: np.ndarray, px_per_mm: float):
        relief = np.asarray(relief_mm, dtype=np.float64)
        if relief.ndim != 2 or min(relief.shape) < 2:
            raise ConfigError(f"height map must be a 2-D array of at least 2x2, got {relief.shape}")
        if not (math.isfinite(px_per_mm) and px_per_mm > 0):
            raise ConfigError(f"height map px_per_mm must be positive, got {px_per_mm!r}")
        if not np.isfinite(relief).any():
            raise ConfigError("height map has no finite value (all NaN)")
        if np.isinf(relief).any():
            raise ConfigError("height map holds +-inf; mark 'no surface' with NaN")
        self.px_per_mm = float(px_per_mm)
        self.relief = relief
        tip = np.nanmax(relief)
        gap = (tip - relief).astype(np.float32)
        gap[~np.isfinite(gap)] = np.inf
        # one ring of "no surface" so samples beyond the map read +inf
        self._gap = np.pad(gap, 1, constant_values=np.inf)
        h, w = relief.shape
        self._c = ((w - 1) / 2 + 1, (h - 1) / 2 + 1)  # axis in padded-map pixels (x, y)
        self._reach = math.hypot(w, h) / 2 / self.px_per_mm

    @property
    def reach_mm(self) -> float:
        return self._reach

    def gap(self, dx, dy):
        fx = np.asarray(dx, dtype=np.float64) * self.px_per_mm + self._c[0]
        fy = np.asarray(dy, dtype=np.float64) * self.px_per_mm + self._c[1]
        h, w = self._gap.shape
        x0 = np.floor(fx).astype(np.int64)
        y0 = np.floor(fy).astype(np.int64)
        outside = (x0 < 0) | (y0 < 0) | (x0 >= w - 1) | (y0 >= h - 1)
        x0c = np.clip(x0, 0, w - 2)
        y0c = np.clip(y0, 0, h - 2)
        tx = fx - x0c
        ty = fy - y0c
        g = self._gap
        corners = [g[y0c, x0c], g[y0c, x0c + 1], g[y0c + 1, x0c], g[y0c + 1, x0c + 1]]
        weights = [(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty]
        finite = [np.isfinite(c) for c in corners]
        all_finite = finite[0] & finite[1] & finite[2] & finite[3]
        with np.errstate(invalid="ignore"):
            bilinear = sum(
                w_ * np.where(f, c, 0.0) for w_, c, f in zip(weights, corners, finite, strict=True)
            )
        # where a neighbour has no surface, take the nearest map pixel (keeps walls vertical)
        nearest = g[
            np.clip(np.rint(fy).astype(np.int64), 0, h - 1),
            np.clip(np.rint(fx).astype(np.int64), 0, w - 1),
        ]
        out = np.where(all_finite, bilinear, nearest)
        out[outside] = np.inf
        return out.astype(np.float32)

    def __repr__(self) -> str:
        return f"Relief(shape={self.relief.shape}, px_per_mm={self.px_per_mm})"
