"""Fast Poisson integrators: one transform pair each, eigenvalues cached per grid shape and dtype.

poisson_dst: Dirichlet, the outermost ring of pixels is depth 0 (the paper's choice). The interior
    5-point Laplacian is diagonalised by the DST-I with eigenvalues 2 cos(pi k / (n - 1)) - 2, k =
    1..n-2 — transform and eigenvalues must belong to the same DST (the authors' code mixes DST-II
    with these DST-I eigenvalues, see threedcal.depth.py3dcal). Only one axis is transformed: each
    mode is then a tridiagonal system along the other, solved directly in O(n) (`_mode_factors`).
poisson_dct: Neumann, i.e. the plain least-squares fit over every edge of the grid (no assumption
    about the border: right when contact reaches it). DCT-II, eigenvalues 2 cos(pi k / n) - 2.
frankot_chellappa: the classic FFT projection onto integrable periodic fields (continuous
    derivative model); exact for band-limited periodic fields, wraps around at the borders otherwise.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.linalg import get_lapack_funcs

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


def _smooth_dst1(n: int) -> bool:
    """Whether scipy's DST-I of length n runs on a fast FFT (2(n + 1) has only small factors)."""
    return _largest_prime_factor(2 * (n + 1)) <= _SMOOTH_PRIME


@lru_cache(maxsize=16)
def _dst1_matrix(n: int, dtype: str) -> np.ndarray | None:
    """scipy's unnormalised DST-I as an (n, n) matrix, for axes where it beats the FFT; else None."""
    if n > _MATRIX_DST_MAX or _smooth_dst1(n):
        return None
    k = np.arange(1, n + 1)
    return _readonly((2.0 * np.sin(np.pi * np.outer(k, k) / (n + 1))).astype(dtype))


def _dst1_columns(x: np.ndarray, workers: int | None) -> np.ndarray:
    """Unnormalised DST-I of `x` along axis 0, by matrix product or FFT, whichever is faster.

    The DST-I is symmetric and its own inverse up to a factor 2(n + 1), so the solve applies it
    forward and back and folds that factor into `_mode_factors`.
    """
    matrix = _dst1_matrix(x.shape[0], str(x.dtype))
    if matrix is None:
        return sfft.dst(x, type=1, axis=0, overwrite_x=True, workers=workers)
    return matrix @ x


def _transform_axis(n_rows: int, n_cols: int) -> int:
    """The interior axis the solve transforms (the other is solved directly): a fast-FFT axis if
    there is one, else the shorter (a matrix product costs n per value, an FFT of an awkward length
    several times its smooth cost)."""
    key = [(not _smooth_dst1(n), n) for n in (n_rows, n_cols)]
    return 0 if key[0] <= key[1] else 1


@lru_cache(maxsize=16)
def _mode_factors(n_modes: int, n_lines: int, px_per_mm: float):
    """LDL^T factors (LAPACK dpttrf) of every mode's tridiagonal system, stacked into one.

    After a DST-I across the transformed axis, mode k of the interior 5-point Laplacian is the
    tridiagonal T_k = tridiag(1, lambda_k - 2, 1) along the other axis, with lambda_k = 2 cos(pi k /
    (n_modes + 1)) - 2 the DST-I eigenvalues: solving T_k directly (O(n)) replaces the second
    transform pair. The matrix factored is -T_k / c, positive definite, with c the 1/2 of the
    central-difference divergence times the inverse DST's 1 / (2(n_modes + 1)) and 1 / px_per_mm;
    the caller negates the result.
    """
    pttrf, pttrs = get_lapack_funcs(("pttrf", "pttrs"), dtype=np.dtype(np.float64))
    lam = 2.0 * np.cos(np.pi * np.arange(1, n_modes + 1) / (n_modes + 1)) - 2.0
    inverse_c = 4.0 * (n_modes + 1) * px_per_mm
    diagonal = np.repeat((2.0 - lam) * inverse_c, n_lines)
    off = np.full((n_modes, n_lines), -inverse_c)
    off[:, -1] = 0.0  # one mode's last line does not couple to the next mode's first
    if diagonal.size == 1:  # one unknown (a 3 x 3 grid): LAPACK's wrapper takes no empty e
        return _readonly(diagonal), None, None
    d, e, info = pttrf(diagonal, off.ravel()[:-1])
    if info != 0:  # cannot happen: -T_k is strictly diagonally dominant
        raise ArithmeticError(f"tridiagonal factorisation failed (LAPACK info {info})")
    return _readonly(d), _readonly(e), pttrs


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
    """(h, w) depth, ring 0, from twice the interior divergence (h-2, w-2): a DST-I across one
    axis, one tridiagonal solve per mode along the other, the DST-I back."""
    n_rows, n_cols = twice_div.shape
    axis = _transform_axis(n_rows, n_cols)
    source = twice_div if axis == 0 else twice_div.T
    spec = _dst1_columns(source, workers)
    # The tridiagonal solve runs in float64: its modes decay geometrically away from the contact,
    # into subnormal float32 numbers that slow every later operation on them ~20x.
    d, e, pttrs = _mode_factors(spec.shape[0], spec.shape[1], px_per_mm)
    flat = np.asarray(spec, dtype=np.float64, order="C").reshape(-1, 1)
    if pttrs is None:
        modes, info = flat / d, 0
    else:
        modes, info = pttrs(d, e, flat, overwrite_b=True)
    if info != 0:
        raise ArithmeticError(f"tridiagonal solve failed (LAPACK info {info})")
    modes[np.abs(modes) < np.finfo(spec.dtype).tiny] = 0.0  # subnormal in the output dtype
    modes = modes.reshape(spec.shape).astype(spec.dtype, copy=False)
    inner = _dst1_columns(modes, workers)
    z = np.zeros((n_rows + 2, n_cols + 2), dtype=twice_div.dtype)
    np.negative(inner if axis == 0 else inner.T, out=z[1:-1, 1:-1])
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
