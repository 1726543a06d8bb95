"""Fast Poisson integrators: one transform pair each, eigenvalues cached per grid shape and dtype.

poisson_dst: Dirichlet, the outermost ring of pixels is depth 0 (the paper's choice). The interior
    5-point Laplacian is diagonalised by the DST-I with eigenvalues 2 cos(pi k / (n - 1)) - 2, k =
    1..n-2 — transform and eigenvalues must belong to the same DST (the authors' code mixes DST-II
    with these DST-I eigenvalues, see threedcal.depth.py3dcal).
poisson_dct: Neumann, i.e. the plain least-squares fit over every edge of the grid (no assumption
    about the border: right when contact reaches it). DCT-II, eigenvalues 2 cos(pi k / n) - 2.
frankot_chellappa: the classic FFT projection onto integrable periodic fields (continuous
    derivative model); exact for band-limited periodic fields, wraps around at the borders otherwise.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft

from threedcal.depth.convention import apply_offset, divergence, edge_gradients
from threedcal.depth.sanitize import DEFAULT_MAX_ANGLE_DEG, prepare
from threedcal.errors import ConfigError


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# DST-I of length n runs as an FFT of length 2(n + 1); when that has a large prime factor (a
# 240-pixel axis: 2 * 239) the FFT falls back to a slow algorithm, and for axes this short a dense
# matrix product is 3-4x faster. Longer axes keep the FFT (the product grows as n^2).
_MATRIX_DST_MAX = 512
_SMOOTH_PRIME = 13


def _largest_prime_factor(n: int) -> int:
    factor, largest = 2, 1
    while factor * factor <= n:
        while n % factor == 0:
            largest, n = factor, n // factor
        factor += 1
    return max(largest, n)


@lru_cache(maxsize=16)
def _dst1_matrix(n: int, dtype: str) -> np.ndarray | None:
    """scipy's unnormalised DST-I as an (n, n) matrix, for axes where it beats the FFT; else None."""
    if n > _MATRIX_DST_MAX or _largest_prime_factor(2 * (n + 1)) <= _SMOOTH_PRIME:
        return None
    k = np.arange(1, n + 1)
    return _readonly((2.0 * np.sin(np.pi * np.outer(k, k) / (n + 1))).astype(dtype))


def _dst1_2d(x: np.ndarray, workers: int | None) -> np.ndarray:
    """Unnormalised 2-D DST-I of `x`, each axis by matrix product or FFT, whichever is faster.

    The DST-I is its own inverse up to a factor 2(n + 1) per axis, so the solve applies this twice
    and folds that factor into `_dst_multiplier`.
    """
    for axis in (0, 1):
        matrix = _dst1_matrix(x.shape[axis], str(x.dtype))
        if matrix is None:
            x = sfft.dst(x, type=1, axis=axis, overwrite_x=True, workers=workers)
        else:
            x = matrix @ x if axis == 0 else x @ matrix  # the DST-I matrix is symmetric
    return x


@lru_cache(maxsize=16)
def _dst_multiplier(h: int, w: int, dtype: str, px_per_mm: float) -> np.ndarray:
    """Everything the Dirichlet spectrum is scaled by, in one array: 1 / the DST-I eigenvalues
    2 cos(pi k / (n - 1)) - 2 of the interior (h-2, w-2) Laplacian summed over both axes, the 1/2 of
    the central-difference divergence, the inverse transform's 1 / (2(h-1) * 2(w-1)) and 1 / px_per_mm."""
    lam_y = 2.0 * np.cos(np.pi * np.arange(1, h - 1) / (h - 1)) - 2.0
    lam_x = 2.0 * np.cos(np.pi * np.arange(1, w - 1) / (w - 1)) - 2.0
    constant = 0.5 / (4.0 * (h - 1) * (w - 1) * px_per_mm)
    return _readonly((constant / (lam_y[:, None] + lam_x[None, :])).astype(dtype))


@lru_cache(maxsize=16)
def _dct_multiplier(h: int, w: int, dtype: str, px_per_mm: float) -> np.ndarray:
    """1 / (DCT-II eigenvalues of the Neumann grid Laplacian * px_per_mm); the constant mode gets 0
    (depth mean 0)."""
    lam_y = 2.0 * np.cos(np.pi * np.arange(h) / h) - 2.0
    lam_x = 2.0 * np.cos(np.pi * np.arange(w) / w) - 2.0
    denom = (lam_y[:, None] + lam_x[None, :]) * px_per_mm
    denom[0, 0] = np.inf
    return _readonly((1.0 / denom).astype(dtype))


@lru_cache(maxsize=16)
def _fc_multipliers(h: int, w: int, dtype: str, px_per_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Z = Mx Gx + My Gy with M = -i omega / (|omega|^2 px_per_mm) (rfft layout); constant and
    Nyquist modes 0."""
    wy = 2.0 * np.pi * np.fft.fftfreq(h)[:, None]
    wx = 2.0 * np.pi * np.fft.rfftfreq(w)[None, :]
    wy = np.broadcast_to(wy, (h, wx.shape[1])).copy()
    wx = np.broadcast_to(wx, (h, wx.shape[1])).copy()
    if h % 2 == 0:
        wy[h // 2, :] = 0.0  # a Nyquist gradient has no unambiguous integral
    if w % 2 == 0:
        wx[:, -1] = 0.0
    denom = (wx**2 + wy**2) * px_per_mm
    denom[denom == 0] = np.inf
    ctype = np.complex64 if dtype == "float32" else np.complex128
    mx = (-1j * wx / denom).astype(ctype)
    my = (-1j * wy / denom).astype(ctype)
    return _readonly(mx), _readonly(my)


# Each solver takes clean pixel-centre gradients and returns depth in mm: px/mm is folded into its
# cached spectral multiplier rather than spent as one more pass over the result.


def dirichlet_mm(
    gx: np.ndarray, gy: np.ndarray, px_per_mm: float, workers: int | None
) -> np.ndarray:
    """Border ring exactly 0."""
    h, w = gx.shape
    if h < 3 or w < 3:
        raise ConfigError(
            f"poisson_dst needs at least 3x3 pixels (a zero border around one unknown), got {h}x{w}; "
            "use poisson_dct or lstsq_sparse for thinner fields"
        )
    # Interior divergence of the edge means: central differences of the pixel-centre gradients
    # (their 1/2 lives in the multiplier).
    rhs = gx[1:-1, 2:] - gx[1:-1, :-2]
    rhs += gy[2:, 1:-1]
    rhs -= gy[:-2, 1:-1]
    return _dirichlet_solve(rhs, px_per_mm, workers)


def _dirichlet_solve(twice_div: np.ndarray, px_per_mm: float, workers: int | None) -> np.ndarray:
    """(h, w) depth, ring 0, from twice the interior divergence (h-2, w-2)."""
    h, w = twice_div.shape[0] + 2, twice_div.shape[1] + 2
    spec = _dst1_2d(twice_div, workers)
    spec *= _dst_multiplier(h, w, str(twice_div.dtype), px_per_mm)
    z = np.zeros((h, w), dtype=twice_div.dtype)
    z[1:-1, 1:-1] = _dst1_2d(spec, workers)
    return z


def dirichlet_edges_px(ex: np.ndarray, ey: np.ndarray, workers: int | None = None) -> np.ndarray:
    """The same Dirichlet solve from edge differences (ex: (H, W-1), ey: (H-1, W)), in pixel units:
    the discrete-exact check of the authors' forward-difference model (tests)."""
    return _dirichlet_solve(2.0 * divergence(ex, ey)[1:-1, 1:-1], 1.0, workers)


def neumann_mm(gx: np.ndarray, gy: np.ndarray, px_per_mm: float, workers: int | None) -> np.ndarray:
    """Least squares over every edge, mean 0."""
    h, w = gx.shape
    div = divergence(*edge_gradients(gx, gy))
    spec = sfft.dctn(div, type=2, overwrite_x=True, workers=workers)
    spec *= _dct_multiplier(h, w, str(gx.dtype), px_per_mm)
    return sfft.idctn(spec, type=2, overwrite_x=True, workers=workers)


def frankot_chellappa_mm(
    gx: np.ndarray, gy: np.ndarray, px_per_mm: float, workers: int | None
) -> np.ndarray:
    h, w = gx.shape
    mx, my = _fc_multipliers(h, w, str(gx.dtype), px_per_mm)
    spec = sfft.rfft2(gx, workers=workers)
    spec *= mx
    spec += sfft.rfft2(gy, workers=workers) * my
    return sfft.irfft2(spec, s=(h, w), workers=workers, overwrite_x=True).astype(
        gx.dtype, copy=False
    )


def _run(solver, name, gx, gy, px_per_mm, offset, max_angle_deg, workers) -> np.ndarray:
    gx, gy, scale, _ = prepare(gx, gy, name, px_per_mm, offset, max_angle_deg)
    return apply_offset(solver(gx, gy, scale, workers), offset)


def poisson_dst(
    gx,
    gy,
    *,
    px_per_mm: float = 1.0,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    workers: int | None = None,
) -> np.ndarray:
    """Depth (mm) with the outermost pixel ring held at 0: DST-I Poisson solve. Needs H, W >= 3."""
    return _run(dirichlet_mm, "poisson_dst", gx, gy, px_per_mm, offset, max_angle_deg, workers)


def poisson_dct(
    gx,
    gy,
    *,
    px_per_mm: float = 1.0,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    workers: int | None = None,
) -> np.ndarray:
    """Depth (mm), least squares over all edges (Neumann): DCT-II Poisson solve. Any H, W >= 1."""
    return _run(neumann_mm, "poisson_dct", gx, gy, px_per_mm, offset, max_angle_deg, workers)


def frankot_chellappa(
    gx,
    gy,
    *,
    px_per_mm: float = 1.0,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    workers: int | None = None,
) -> np.ndarray:
    """Depth (mm) by Frankot-Chellappa (periodic FFT projection). Any H, W >= 1."""
    return _run(
        frankot_chellappa_mm, "frankot_chellappa", gx, gy, px_per_mm, offset, max_angle_deg, workers
    )
