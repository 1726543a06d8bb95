"""Compatibility mode: the authors' `fast_poisson` (py3DCal 1.1.0), reproduced to document the gap.

What their solver does, re-expressed here: gradients are read as forward differences
(gx[i, j] = z[i, j+1] - z[i, j]), the interior divergence is a backward difference of them, the
outermost ring is held at 0 — all consistent with a Dirichlet solve. But the source is transformed
with an orthonormal DST-II and divided by the eigenvalues of the DST-I Laplacian
(2 cos(pi k / (n - 1)) - 2). The DST-II does not diagonalise that operator, so even a field the
solver should reproduce exactly comes back wrong (tests/depth/test_depth.py measures it). Their
`get_depthmap` then clips negative depth to 0, which `py3dcal` (the integrate method) does too.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from threedcal.depth.convention import apply_offset
from threedcal.depth.sanitize import DEFAULT_MAX_ANGLE_DEG, integrator_inputs
from threedcal.errors import ConfigError


def py3dcal_fast_poisson(gx: np.ndarray, gy: np.ndarray, workers: int | None = None) -> np.ndarray:
    """The authors' fast_poisson numerics (pixel units, border 0), flaw included."""
    gx = np.asarray(gx)
    gy = np.asarray(gy)
    h, w = gx.shape
    if h < 3 or w < 3:
        raise ConfigError(f"py3dcal fast_poisson needs at least 3x3 pixels, got {h}x{w}")
    source = (gx[1:-1, 1:-1] - gx[1:-1, :-2]) + (gy[1:-1, 1:-1] - gy[:-2, 1:-1])
    spec = sfft.dst(source, type=2, norm="ortho", axis=1, workers=workers)
    spec = sfft.dst(spec, type=2, norm="ortho", axis=0, workers=workers)
    lam_x = 2.0 * np.cos(np.pi * np.arange(1, w - 1) / (w - 1)) - 2.0
    lam_y = 2.0 * np.cos(np.pi * np.arange(1, h - 1) / (h - 1)) - 2.0
    spec = spec / (lam_x[None, :] + lam_y[:, None])
    inner = sfft.idst(spec, type=2, norm="ortho", axis=1, workers=workers)
    inner = sfft.idst(inner, type=2, norm="ortho", axis=0, workers=workers)
    return np.pad(inner, 1, mode="constant")


def py3dcal(
    gx,
    gy,
    *,
    px_per_mm: float = 1.0,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    workers: int | None = None,
) -> np.ndarray:
    """Depth (mm) as the authors' pipeline gives it: fast_poisson, negative depth clipped to 0."""
    gx, gy, scale, _ = integrator_inputs(gx, gy, "py3dcal", px_per_mm, offset, max_angle_deg)
    z = np.clip(py3dcal_fast_poisson(gx, gy, workers), 0, None).astype(gx.dtype, copy=False)
    z /= z.dtype.type(scale)
    return apply_offset(z, offset)
