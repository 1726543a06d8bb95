"""threedcal.depth: exactness on discrete-exact fields, analytic surfaces, convergence, symmetry,
precision, extreme inputs, and the documented flaw of the authors' solver."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import scipy.fft as sfft

from threedcal.depth import (
    METHODS,
    consistent_gradients,
    frankot_chellappa,
    integrate,
    lstsq_sparse,
    poisson_dct,
    poisson_dst,
    py3dcal_fast_poisson,
    sanitize_gradients,
)
from threedcal.depth.scenarios import gaussian, make_scene, pawn_press, pixel_centres_mm, sphere_cap
from threedcal.depth.spectral import _dst1_columns, _dst1_matrix, _solve_modes, dirichlet_edges_px
from threedcal.errors import ConfigError

# The authors' file, where `make bench` unpacks it (tests never download it; they skip without it).
AUTHORS = Path(__file__).parents[2] / ".cache/py3dcal/py3DCal/model_training/lib/fast_poisson.py"
FAST = ["poisson_dst", "poisson_dct", "frankot_chellappa"]
SHAPES = [(240, 320), (320, 240)]


def zero_border(z):
    z = z.copy()
    z[0] = z[-1] = 0
    z[:, 0] = z[:, -1] = 0
    return z


def rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


# --- discrete-exact fields -------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(3, 3), (24, 32), (61, 47)])
def test_dst_recovers_discrete_exact_zero_border_field(shape):
    z = zero_border(np.random.default_rng(1).normal(size=shape))
    gx, gy = consistent_gradients(z)
    assert rel(poisson_dst(gx, gy, max_angle_deg=None), z) <= 1e-10


@pytest.mark.parametrize("method", ["poisson_dct", "lstsq_sparse"])
@pytest.mark.parametrize("shape", [(1, 7), (7, 1), (2, 2), (24, 32), (33, 20)])
def test_least_squares_recover_discrete_exact_field_up_to_the_mean(method, shape):
    z = np.random.default_rng(2).normal(size=shape) * 3
    gx, gy = consistent_gradients(z)
    depth = METHODS[method](gx, gy, offset="mean", max_angle_deg=None)
    assert np.max(np.abs(depth - (z - z.mean()))) <= 1e-10 * np.max(np.abs(z))


def test_frankot_chellappa_exact_on_band_limited_periodic_field():
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w].astype(float)
    z = np.zeros((h, w))
    gx = np.zeros((h, w))
    gy = np.zeros((h, w))
    rng = np.random.default_rng(3)
    for _ in range(6):
        kx, ky = rng.integers(-8, 9, 2)
        a, phase = rng.normal(), rng.uniform(0, 2 * np.pi)
        arg = 2 * np.pi * (kx * x / w + ky * y / h) + phase
        z += a * np.cos(arg)
        gx -= a * np.sin(arg) * 2 * np.pi * kx / w
        gy -= a * np.sin(arg) * 2 * np.pi * ky / h
    depth = frankot_chellappa(gx, gy, offset="mean", max_angle_deg=None)
    assert rel(depth, z - z.mean()) <= 1e-10


def test_lstsq_masked_weighted_exact_on_valid_pixels_and_fills_the_rest():
    rng = np.random.default_rng(4)
    z = rng.normal(size=(30, 40))
    gx, gy = consistent_gradients(z)
    mask = np.ones(z.shape, bool)
    mask[5:12, 8:20] = False  # a hole: the valid region stays connected
    gx[~mask] = rng.normal(size=(~mask).sum()) * 100  # garbage where invalid
    weights = rng.uniform(0.1, 3, z.shape)
    depth = lstsq_sparse(gx, gy, mask=mask, weights=weights, offset="mean", max_angle_deg=None)
    truth = z - z[mask].mean()
    assert np.max(np.abs(depth - truth)[mask]) <= 1e-8 * np.max(np.abs(z))
    hole = depth[~mask]
    assert (
        np.isfinite(hole).all()
        and hole.min() >= truth[mask].min()
        and hole.max() <= truth[mask].max()
    )
    nan_fill = lstsq_sparse(gx, gy, mask=mask, weights=weights, fill="nan", max_angle_deg=None)
    assert np.isnan(nan_fill[~mask]).all() and np.isfinite(nan_fill[mask]).all()


def test_weights_matter_when_data_disagree():
    z = np.random.default_rng(5).normal(size=(20, 20))
    gx, gy = consistent_gradients(z)
    gx_bad = gx.copy()
    gx_bad[10, 5:15] += 5.0
    low = np.ones(z.shape)
    low[10, 5:15] = 1e-6
    plain = lstsq_sparse(gx_bad, gy, offset="mean", max_angle_deg=None)
    weighted = lstsq_sparse(gx_bad, gy, weights=low, offset="mean", max_angle_deg=None)
    truth = z - z.mean()
    trusted = low == 1  # the down-weighted pixels themselves are undetermined (all edges ~0 weight)
    assert np.abs(weighted - truth)[trusted].max() < 1e-3 * np.abs(plain - truth)[trusted].max()


# --- the authors' solver ---------------------------------------------------------------------


def forward_differences(z):
    fx = np.zeros_like(z)
    fy = np.zeros_like(z)
    fx[:, :-1] = np.diff(z, axis=1)
    fy[:-1] = np.diff(z, axis=0)
    return fx, fy


def test_py3dcal_mode_misses_a_field_its_own_model_solves_exactly():
    # Their model (forward differences, zero border) is right: a DST-I solve of it is exact.
    z = zero_border(np.random.default_rng(6).normal(size=(40, 56)))
    fx, fy = forward_differences(z)
    assert rel(dirichlet_edges_px(fx[:, :-1], fy[:-1]), z) <= 1e-10
    # Their DST-II transform with DST-I eigenvalues is not: >10 % off.
    theirs = py3dcal_fast_poisson(fx, fy)
    assert np.linalg.norm(theirs - z) / np.linalg.norm(z) > 0.10
    # ... and on a smooth zero-border bump (their intended use) still several percent.
    x, y = pixel_centres_mm(240, 320, 19.5)
    bump, bx, by = gaussian(x, y, 0.5, 1.5)
    fx, fy = forward_differences(bump * 19.5)
    err = rel(py3dcal_fast_poisson(fx, fy), bump * 19.5)
    assert 0.005 < err < 0.5


@pytest.mark.skipif(
    not AUTHORS.is_file(), reason="py3DCal source not unpacked (make bench fetches it)"
)
def test_py3dcal_mode_reproduces_the_authors_code():
    spec = importlib.util.spec_from_file_location("authors_fast_poisson", AUTHORS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rng = np.random.default_rng(7)
    gx, gy = rng.normal(size=(2, 60, 80))
    assert np.allclose(
        py3dcal_fast_poisson(gx, gy), module.fast_poisson(gx, gy), rtol=0, atol=1e-12
    )


# --- analytic surfaces at sensor size ---------------------------------------------------------

# rmse tolerances in mm at 19.5 px/mm (analytic gradients sampled at pixel centres).
CASES = {
    "gaussian": (
        lambda x, y: gaussian(x, y, 0.5, 1.5),
        {"poisson_dst": 1e-4, "poisson_dct": 5e-5, "frankot_chellappa": 1e-6},
    ),
    "shallow_cap": (lambda x, y: sphere_cap(x, y, 4.0, 0.2), dict.fromkeys(FAST, 5e-4)),
    "cap": (lambda x, y: sphere_cap(x, y, 4.0, 1.0), dict.fromkeys(FAST, 1.5e-3)),
    "hemisphere": (lambda x, y: sphere_cap(x, y, 3.0, 2.9), dict.fromkeys(FAST, 0.04)),
}


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("case", list(CASES))
def test_analytic_surfaces(case, shape):
    surface, tolerances = CASES[case]
    x, y = pixel_centres_mm(*shape, 19.5)
    z, gx, gy = surface(x, y)
    for method, tol in tolerances.items():
        depth = integrate(gx, gy, method, px_per_mm=19.5)
        rmse = np.sqrt(np.mean((depth - z) ** 2))
        assert rmse <= tol, (method, rmse)
        assert abs(depth.max() - z.max()) <= 10 * tol


@pytest.mark.parametrize("shape", SHAPES)
def test_ramp_and_step_along_each_axis(shape):
    h, w = shape
    # A ramp: least squares recovers it exactly; a zero border cannot hold it.
    gx = np.full(shape, 0.1)
    gy = np.zeros(shape)
    depth = poisson_dct(gx, gy, px_per_mm=10.0, offset="min")
    x = np.arange(w) / 10.0
    assert np.allclose(depth, 0.1 * (x - x[0])[None, :], atol=1e-12)
    # A step has no gradient anywhere: no integrator can see it -> flat output, not garbage.
    for method in FAST:
        assert np.abs(integrate(np.zeros(shape), np.zeros(shape), method)).max() == 0


@pytest.mark.parametrize("shape", SHAPES)
def test_contact_crossing_the_border_needs_neumann(shape):
    x, y = pixel_centres_mm(*shape, 19.5)
    z, gx, gy = sphere_cap(x, y, 4.0, 1.0, cx=x.min() + 1.0)
    err = {m: np.sqrt(np.mean((integrate(gx, gy, m, px_per_mm=19.5) - z) ** 2)) for m in FAST}
    assert err["poisson_dct"] < 1.5e-3
    assert err["poisson_dst"] > 50 * err["poisson_dct"]  # the zero border is violated


def test_pawn_is_finite_and_loses_only_its_walls():
    sc = make_scene("pawn", 120, 160)
    depth = integrate(sc.gx, sc.gy, "poisson_dct", px_per_mm=sc.px_per_mm)
    assert np.isfinite(depth).all()
    _, gx, gy = pawn_press(*pixel_centres_mm(120, 160, sc.px_per_mm))
    assert np.abs(depth - sc.depth_mm).max() < sc.depth_mm.max()


# --- convergence, symmetry, precision ---------------------------------------------------------


@pytest.mark.parametrize("method", ["poisson_dst", "poisson_dct"])
def test_second_order_convergence(method):
    errors = []
    for n in (32, 64, 128):
        px = n / 12.0  # a 12 x 12 mm field sampled ever finer (the bump is 0 at its border)
        x, y = pixel_centres_mm(n, n, px)
        z, gx, gy = gaussian(x, y, 0.5, 1.0)
        depth = integrate(
            gx, gy, method, px_per_mm=px, offset="none" if method == "poisson_dst" else "mean"
        )
        truth = z if method == "poisson_dst" else z - z.mean()
        errors.append(np.sqrt(np.mean((depth - truth) ** 2)))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 1.8), orders


@pytest.mark.parametrize("method", list(METHODS))
def test_transpose_invariance(method):
    sc = make_scene("noise_low", 30, 44, seed=3)
    a = integrate(sc.gx, sc.gy, method, px_per_mm=sc.px_per_mm)
    b = integrate(sc.gy.T, sc.gx.T, method, px_per_mm=sc.px_per_mm)
    assert np.allclose(a, b.T, rtol=0, atol=1e-12 * max(1.0, np.abs(a).max()))


@pytest.mark.parametrize("method", list(METHODS))
def test_float32_matches_float64(method):
    sc = make_scene("cap", 60, 80)
    d64 = integrate(sc.gx, sc.gy, method, px_per_mm=sc.px_per_mm)
    d32 = integrate(
        sc.gx.astype(np.float32), sc.gy.astype(np.float32), method, px_per_mm=sc.px_per_mm
    )
    assert d32.dtype == np.float32 and d64.dtype == np.float64
    assert np.abs(d32 - d64).max() <= 1e-4 * np.abs(d64).max()


def test_px_per_mm_scales_depth_and_dtype_preserved():
    sc = make_scene("cap", 40, 50)
    a = poisson_dst(sc.gx, sc.gy, px_per_mm=10.0)
    b = poisson_dst(sc.gx, sc.gy, px_per_mm=20.0)
    assert np.allclose(a, 2 * b, rtol=1e-14, atol=0)


# --- extreme inputs ---------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("method", list(METHODS))
def test_nan_inf_and_spikes_give_finite_output(method, dtype):
    sc = make_scene("outliers", 40, 60, seed=1)
    gx, gy = sc.gx.astype(dtype), sc.gy.astype(dtype)
    gx[3, 4] = 1e30 if dtype == np.float64 else 3e38
    depth, report = integrate(gx, gy, method, px_per_mm=sc.px_per_mm, return_report=True)
    assert np.isfinite(depth).all()
    assert report.n_nonfinite == int((~(np.isfinite(gx) & np.isfinite(gy))).sum()) > 0
    assert report.n_clamped >= 1


def test_sanitize_counts_and_clamps_keeping_direction():
    gx = np.array([[0.0, np.nan, 3.0, 1e6]])
    gy = np.array([[0.0, 1.0, 4.0, -1e6]])
    sx, sy, report = sanitize_gradients(gx, gy, max_angle_deg=45.0)
    assert (report.n_nonfinite, report.n_clamped) == (1, 2)
    assert report.nonfinite.tolist() == [[False, True, False, False]]
    assert np.allclose(np.hypot(sx, sy), [0, 0, 1, 1])
    assert np.allclose([sx[0, 2], sy[0, 2]], [0.6, 0.8])
    assert np.isnan(gx[0, 1])  # the input is untouched
    untouched = sanitize_gradients(np.ones((2, 2)), np.ones((2, 2)), max_angle_deg=None)[2]
    assert untouched.n_changed == 0


@pytest.mark.parametrize("max_angle_deg", [None, 89.0])
def test_sanitize_huge_finite_float32_is_not_called_nonfinite(max_angle_deg):
    # 1e20 squared overflows float32: the one-pass clean check fails, the exact path must decide.
    gx = np.array([[1e20, 0.5, np.inf]], dtype=np.float32)
    gy = np.zeros_like(gx)
    sx, sy, report = sanitize_gradients(gx, gy, max_angle_deg=max_angle_deg)
    assert report.n_nonfinite == 1 and report.nonfinite.tolist() == [[False, False, True]]
    assert report.n_clamped == (0 if max_angle_deg is None else 1)
    expected_first = 1e20 if max_angle_deg is None else np.tan(np.radians(89.0))
    assert sx[0, 0] == pytest.approx(expected_first, rel=1e-6) and sx[0, 1] == np.float32(0.5)
    assert sx.dtype == np.float32 and sx[0, 2] == 0


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (2, 2)])
def test_tiny_grids(shape):
    gx = np.ones(shape) * 0.1
    gy = np.ones(shape) * 0.2
    for method in ("poisson_dct", "frankot_chellappa", "lstsq_sparse"):
        assert np.isfinite(integrate(gx, gy, method)).all()
    with pytest.raises(ConfigError, match="at least 3x3"):
        integrate(gx, gy, "poisson_dst")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"method": "magic"}, "method 'magic' is not allowed"),
        ({"px_per_mm": 0}, "px_per_mm must be a positive"),
        ({"offset": "median"}, "offset 'median' is not allowed"),
        ({"max_angle_deg": 90}, "max_angle_deg must lie in"),
        ({"mask": np.ones((5, 5), bool)}, "mask/weights need method 'lstsq_sparse'"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        integrate(np.zeros((5, 5)), np.zeros((5, 5)), **kwargs)


def test_bad_shapes_are_refused():
    with pytest.raises(ConfigError, match="same shape"):
        integrate(np.zeros((4, 5)), np.zeros((5, 4)))
    with pytest.raises(ConfigError, match="2-D"):
        integrate(np.zeros(5), np.zeros(5))
    with pytest.raises(ConfigError, match="empty"):
        integrate(np.zeros((0, 5)), np.zeros((0, 5)))
    with pytest.raises(ConfigError, match="mask .* must match"):
        integrate(np.zeros((4, 5)), np.zeros((4, 5)), "lstsq_sparse", mask=np.ones((5, 4), bool))


@pytest.mark.parametrize("shape", [(238, 318), (317, 9), (12, 10), (1278, 40)])
def test_dst1_by_matrix_or_fft_equals_scipy_both_ways(shape):
    x = np.random.default_rng(3).normal(size=shape)
    forward = _dst1_columns(x.copy(), workers=None)
    np.testing.assert_allclose(forward, sfft.dst(x, type=1, axis=0), rtol=1e-12, atol=1e-10)
    # Applied twice it is the identity times 2(n + 1), the factor the solve folds away.
    twice = _dst1_columns(forward.copy(), workers=None) / (2.0 * (shape[0] + 1))
    np.testing.assert_allclose(twice, x, atol=1e-12)
    # 238 + 1 = 239 is prime and 2 * 318 = 4 * 3 * 53: those axes go through the split product
    # (317 odd: its middle row joins the odd outputs only); 11 stays with the FFT.
    assert _dst1_matrix(238, "float64") is not None and _dst1_matrix(317, "float64") is not None
    assert _dst1_matrix(10, "float64") is None


@pytest.mark.parametrize(
    "shape",  # one unknown; thin; transformed axis 0 or 1 by matrix, smooth FFT or awkward FFT
    [
        *[(3, 3), (3, 9), (9, 3), (240, 320), (320, 240), (12, 514), (30, 12), (602, 602)],
        *[(319, 402), (1032, 1032)],  # split product of odd length; awkward FFT (2 * 1031)
    ],
)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_dst_solve_is_exact_on_every_path_and_dtype(shape, dtype):
    z = zero_border(np.random.default_rng(7).normal(size=shape))
    gx, gy = consistent_gradients(z)
    depth = poisson_dst(gx.astype(dtype), gy.astype(dtype), max_angle_deg=None, offset="none")
    assert depth.dtype == dtype
    assert rel(depth, z) <= (1e-12 if dtype == np.float64 else 1e-4)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_dst_modes_never_go_subnormal_and_stay_exact(dtype):
    """A contact at one end of a long strip: its modes decay along the 1498 lines by up to 0.17 per
    line, through float32's and float64's subnormal range (where every operation is ~20-100x
    slower). The floor added before the tridiagonal solve keeps every mode normal; the depth stays
    exact, and a zero field stays exactly zero."""
    z = np.zeros((40, 1500))
    z[1:-1, 1:6] = np.random.default_rng(11).normal(size=(38, 5))
    gx, gy = consistent_gradients(z)
    depth = poisson_dst(gx.astype(dtype), gy.astype(dtype), max_angle_deg=None, offset="none")
    assert rel(depth, z) <= (1e-12 if dtype == np.float64 else 1e-4)
    gx, gy = gx.astype(dtype), gy.astype(dtype)
    rhs = gx[1:-1, 2:] - gx[1:-1, :-2] + gy[2:, 1:-1] - gy[:-2, 1:-1]  # as dirichlet_mm forms it
    spec = _dst1_columns(rhs, workers=None)  # 38 rows: 2 * 39 = 78 is smooth, lines along 1498
    modes = _solve_modes(spec, 1.0)
    assert modes.dtype == dtype
    assert np.all(np.abs(modes) >= np.finfo(dtype).tiny)  # no subnormal, no zero
    zero = poisson_dst(np.zeros((40, 1500), dtype), np.zeros((40, 1500), dtype), offset="none")
    assert not zero.any()
