"""FALLBACK ONLY — replaced by threedcal.depth at merge (lead): a minimal DST-I Poisson solve.

Used by DepthEstimator.depth when `threedcal.depth` is not importable. Solves ∇²z = ∇·g with z = 0
on the image border; gradients are averaged to half-pixel points, so the divergence is second-order
accurate and unshifted.
"""

from __future__ import annotations

import numpy as np
from scipy import fft


def poisson_dst(gx: np.ndarray, gy: np.ndarray, px_per_mm: float) -> np.ndarray:
    """Depth (mm) of dimensionless gradients (H, W) sampled at px_per_mm; zero on the border."""
    gx = np.asarray(gx, dtype=np.float64)
    gy = np.asarray(gy, dtype=np.float64)
    height, width = gx.shape
    depth = np.zeros((height, width))
    if height < 3 or width < 3:
        return depth
    # Divergence at interior pixels from half-point gradients: (g[j+1] − g[j−1]) / 2.
    div = (gx[1:-1, 2:] - gx[1:-1, :-2]) / 2.0 + (gy[2:, 1:-1] - gy[:-2, 1:-1]) / 2.0
    m, n = div.shape
    ky = 2.0 * np.cos(np.pi * np.arange(1, m + 1) / (m + 1)) - 2.0
    kx = 2.0 * np.cos(np.pi * np.arange(1, n + 1) / (n + 1)) - 2.0
    spectrum = fft.dstn(div, type=1, norm="ortho") / (ky[:, None] + kx[None, :])
    depth[1:-1, 1:-1] = fft.idstn(spectrum, type=1, norm="ortho")
    return depth / px_per_mm  # pixels → mm: dz/dx is dimensionless, one pixel is 1/px_per_mm mm
