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
from threedcal.depth.sanitize import DEFAULT_MAX_ANGLE_DEG, integrator_inputs
from threedcal.errors import ConfigError


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# DST-I of length n runs as an FFT of length 2(n + 1); when that has a large prime factor (a
# 240-pixel axis: 2 * 239) the FFT falls back to a slow algorithm, and a dense product split in two
# by symmetry is faster: 5x at n = 238, 1.7x at n = 958 (960 x 1280: 2 * 7 * 137), one thread.
# Longer axes keep the FFT (the product grows as n^2).
_MATRIX_DST_MAX = 1024
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
def _dst1_matrix(n: int, dtype: str) -> tuple[np.ndarray, np.ndarray] | None:
    """scipy's unnormalised DST-I as its two half blocks, for axes where a product beats the FFT;
    else None.

    With N = n + 1, S[k, N - j] = (-1)^(k+1) S[k, j]: odd outputs k only see x_j + x_(N-j), even
    ones x_j - x_(N-j), so the (n, n) product splits into a ceil(n/2) and a floor(n/2) square one,
    half the work. The odd block keeps the middle column when n is odd (j = N - j there).
    """
    if n > _MATRIX_DST_MAX or _smooth_dst1(n):
        return None
    k = np.arange(1, n + 1)
    # k j reduced mod 2(n + 1) in integers first: the sine's argument stays small and exact
    full = 2.0 * np.sin(np.pi * (np.outer(k, k) % (2 * (n + 1))) / (n + 1))
    half_odd, half_even = (n + 1) // 2, n // 2
    odd = full[0::2, :half_odd].astype(dtype)  # rows k = 1, 3, 5, ...
    even = full[1::2, :half_even].astype(dtype)  # rows k = 2, 4, ...
    return _readonly(np.ascontiguousarray(odd)), _readonly(np.ascontiguousarray(even))


def _dst1_columns(x: np.ndarray, workers: int | None, out: np.ndarray | None = None) -> np.ndarray:
    """Unnormalised DST-I of `x` along axis 0, by the split matrix product or FFT, whichever is
    faster; written into `out` when given (the products write there directly, no copy).

    The DST-I is symmetric and its own inverse up to a factor 2(n + 1), so the solve applies it
    forward and back and folds that factor into `_mode_factors`.
    """
    n = x.shape[0]
    blocks = _dst1_matrix(n, str(x.dtype))
    if blocks is None:
        result = sfft.dst(x, type=1, axis=0, overwrite_x=True, workers=workers)
        if out is None:
            return result
        out[...] = result
        return out
    odd, even = blocks
    half_even = n // 2
    mirrored = x[: n - half_even - 1 : -1]  # rows N - j for j = 1 .. floor(n/2)
    if n % 2:  # the middle row pairs with itself: odd outputs only
        plus = np.empty((odd.shape[0],) + x.shape[1:], dtype=x.dtype)
        np.add(x[:half_even], mirrored, out=plus[:half_even])
        plus[half_even] = x[half_even]
    else:
        plus = x[:half_even] + mirrored
    minus = x[:half_even] - mirrored
    if out is None:
        out = np.empty(x.shape, dtype=x.dtype)
    np.matmul(odd, plus, out=out[0::2])
    np.matmul(even, minus, out=out[1::2])
    return out


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
    D is stored negated, so that the solve returns the modes of the depth itself (with L D L^T
    negated its inverse is too; dpttrs only divides by D).
    """
    pttrf, pttrs = get_lapack_funcs(("pttrf", "pttrs"), dtype=np.dtype(np.float64))
    lam = 2.0 * np.cos(np.pi * np.arange(1, n_modes + 1) / (n_modes + 1)) - 2.0
    inverse_c = 4.0 * (n_modes + 1) * px_per_mm
    diagonal = np.repeat((2.0 - lam) * inverse_c, n_lines)
    off = np.full((n_modes, n_lines), -inverse_c)
    off[:, -1] = 0.0  # one mode's last line does not couple to the next mode's first
    if diagonal.size == 1:  # one unknown (a 3 x 3 grid): LAPACK's wrapper takes no empty e
        return _readonly(-diagonal), None, None
    d, e, info = pttrf(diagonal, off.ravel()[:-1])
    if info != 0:  # cannot happen: -T_k is strictly diagonally dominant
        raise ArithmeticError(f"tridiagonal factorisation failed (LAPACK info {info})")
    return _readonly(-d), _readonly(e), pttrs


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


def _solve_modes(spec: np.ndarray, px_per_mm: float) -> np.ndarray:
    """Every mode's tridiagonal system along the untransformed axis (modes along axis 0), solved
    in float64 and returned in spec's dtype."""
    # The tridiagonal solve runs in float64. Its modes decay geometrically away from the contact,
    # through the subnormal numbers (below 1e-38 in float32, 1e-308 in float64), on which every
    # operation is ~20-100x slower; a full pass to flush them cost as much as the solve. Instead a
    # floor of eps^3 times the largest mode is added to every mode's right-hand side: the matrix
    # solved is minus an M-matrix (its inverse has no positive entry), so every solved mode gets
    # at least floor / its diagonal, all of one sign, far above subnormal, while the answer moves by
    # ~n^2 eps^3 relative, far below rounding (eps of the output dtype).
    d, e, pttrs = _mode_factors(spec.shape[0], spec.shape[1], px_per_mm)
    largest = max(float(spec.max()), -float(spec.min())) if spec.size else 0.0
    floor = largest * float(np.finfo(spec.dtype).eps) ** 3
    if spec.dtype == np.float64 and spec.flags.c_contiguous:
        spec += floor  # spec is the forward transform's own output: free to overwrite
        flat = spec.reshape(-1, 1)
    else:  # cast and add in one pass
        flat = np.add(spec, floor, dtype=np.float64).reshape(-1, 1)
    if pttrs is None:
        modes, info = flat / d, 0
    else:
        modes, info = pttrs(d, e, flat, overwrite_b=True)
    if info != 0:
        raise ArithmeticError(f"tridiagonal solve failed (LAPACK info {info})")
    return modes.reshape(spec.shape).astype(spec.dtype, copy=False)


def _dirichlet_solve(twice_div: np.ndarray, px_per_mm: float, workers: int | None) -> np.ndarray:
    """(h, w) depth, ring 0, from twice the interior divergence (h-2, w-2): a DST-I across one
    axis, one tridiagonal solve per mode along the other, the DST-I back."""
    n_rows, n_cols = twice_div.shape
    axis = _transform_axis(n_rows, n_cols)
    source = twice_div if axis == 0 else twice_div.T
    spec = _dst1_columns(source, workers)
    modes = _solve_modes(spec, px_per_mm)
    z = np.zeros((n_rows + 2, n_cols + 2), dtype=twice_div.dtype)
    _dst1_columns(modes, workers, out=z[1:-1, 1:-1] if axis == 0 else z[1:-1, 1:-1].T)
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
    gx, gy, scale, _ = integrator_inputs(gx, gy, name, px_per_mm, offset, max_angle_deg)
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
