"""Unit surface normals toward the camera: of a depth field from its slopes, and of a sphere cap."""

from __future__ import annotations

import numpy as np


def surface_normals(gx: np.ndarray, gy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals toward the camera of a depth field z(x, y) (positive toward the camera)."""
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    return (-gx * inv).astype(np.float32), (-gy * inv).astype(np.float32), inv.astype(np.float32)


def sphere_normals(
    shape: tuple[int, int], center_px: tuple[float, float], radius_px: float
) -> tuple[np.ndarray, ...]:
    """Exact unit normals (toward the camera) of a sphere cap centred at `center_px`; NaN outside."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    nx = (xx - center_px[0]) / radius_px
    ny = (yy - center_px[1]) / radius_px
    nz2 = 1.0 - nx * nx - ny * ny
    nz = np.sqrt(np.where(nz2 >= 0, nz2, np.nan))
    return nx, ny, nz
