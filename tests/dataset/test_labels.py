import math

import numpy as np
import pytest

from threedcal.dataset.labels import contact_radius_mm, sphere_depth, sphere_gradients
from threedcal.depth import poisson_dst
from threedcal.errors import ConfigError

PPM = 20.0


def test_contact_radius_formula():
    assert contact_radius_mm(2.0, 0.5) == pytest.approx(math.sqrt(2 * 2.0 * 0.5 - 0.25))
    assert contact_radius_mm(2.0, 2.0) == pytest.approx(2.0)  # hemisphere
    assert contact_radius_mm(2.0, 3.0) == pytest.approx(2.0)  # deeper than R: full radius
    assert contact_radius_mm(2.0, 0.0) == 0.0


def test_depth_map_is_the_spherical_cap_at_subpixel_centre():
    center = (40.3, 30.7)
    depth = sphere_depth((64, 80), center, 2.0, 0.8, PPM)
    rows, cols = np.mgrid[0:64, 0:80]
    r = np.hypot((cols - center[0]) / PPM, (rows - center[1]) / PPM)
    expected = np.where(
        r < 2.0, np.maximum(0.8 - 2.0 + np.sqrt(np.clip(4.0 - r * r, 0, None)), 0), 0
    )
    np.testing.assert_allclose(depth, expected, atol=1e-12)
    assert depth.max() <= 0.8 and depth.max() > 0.79
    a = contact_radius_mm(2.0, 0.8)
    assert np.all(depth[r > a + 1e-9] == 0)


def test_labels_are_the_mean_gradient_over_each_pixel():
    """The definition, checked by brute force: the point gradient averaged over 48 x 48 sub-pixel
    samples of each pixel (pixels the rim crosses excluded: a kink there needs no quadrature test)."""
    shape, center, R, d = (41, 47), (23.25, 20.6), 2.0, 0.6
    ppm = 12.0
    g = sphere_gradients(shape, center, R, d, ppm).astype(np.float64)
    n = 48
    sub = (np.arange(n) + 0.5) / n - 0.5
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    x = (cols[..., None, None] + sub[None, :] - center[0]) / ppm
    y = (rows[..., None, None] + sub[:, None] - center[1]) / ppm
    root = np.sqrt(np.clip(R * R - x * x - y * y, 1e-12, None))
    a = contact_radius_mm(R, d)
    inside = (x * x + y * y) < a * a
    mean_gx = np.where(inside, -x / root, 0.0).mean(axis=(2, 3))
    mean_gy = np.where(inside, -y / root, 0.0).mean(axis=(2, 3))
    r = np.hypot(cols - center[0], rows - center[1]) / ppm
    clear = np.abs(r - a) > 0.75 / ppm
    np.testing.assert_allclose(g[..., 0][clear], mean_gx[clear], atol=2e-5)
    np.testing.assert_allclose(g[..., 1][clear], mean_gy[clear], atol=2e-5)


def test_labels_approach_the_point_gradient_as_pixels_shrink():
    """Where the surface is smooth the pixel mean differs from the point value by O(pitch²)."""
    R, d = 2.0, 0.6

    def worst_difference(ppm):
        shape = (int(2.4 * ppm), int(2.4 * ppm))
        center = (shape[1] / 2 + 0.3, shape[0] / 2 - 0.2)
        g = sphere_gradients(shape, center, R, d, ppm).astype(np.float64)
        x = (np.arange(shape[1]) - center[0])[None, :] / ppm
        y = (np.arange(shape[0]) - center[1])[:, None] / ppm
        inside = x * x + y * y < (contact_radius_mm(R, d) - 0.1) ** 2
        point = -x / np.sqrt(R * R - x * x - y * y)
        return np.abs(g[..., 0] - point)[inside].max()

    coarse, fine = worst_difference(10.0), worst_difference(20.0)
    assert coarse < 2e-3
    assert 3.0 < coarse / fine < 5.0  # second order: halving the pitch quarters the difference


def pixel_mean_depth(shape, center, R, d, ppm, n=16):
    """The true depth map as a finite-volume solver sees it: each pixel's mean depth (n x n samples)."""
    total = np.zeros(shape)
    for sy in (np.arange(n) + 0.5) / n - 0.5:
        for sx in (np.arange(n) + 0.5) / n - 0.5:
            total += sphere_depth(shape, (center[0] - sx, center[1] - sy), R, d, ppm)
    return total / (n * n)


@pytest.mark.parametrize("depth", [1.0, 2.0, 3.0])  # the calibration press, d = R, d > R
def test_perfect_labels_integrate_to_the_true_depth(depth):
    """poisson_dst of exact labels reproduces the press (DIGIT scale, R = 2 mm).

    Tolerances: the cap is smooth, so the only error is the convention's O(pitch²) one (measured
    under 1 um at the centre and 3 px inside the rim). At d = R the slope is infinite at the rim
    and at d > R the rim is a step d - R high: both leave an error confined to the pixels next to
    the rim that decays inward — within 3 px of the rim it stays under 5 um + 2.5 % of the step
    (measured 3.4 um at d = R, 21 um for a 1 mm step). The volume is conserved to 0.02 %.
    """
    shape, center, R, ppm = (130, 120), (60.3, 64.6), 2.0, 19.5
    g = sphere_gradients(shape, center, R, depth, ppm)
    assert np.all(np.isfinite(g))
    z = poisson_dst(g[..., 0], g[..., 1], px_per_mm=ppm, max_angle_deg=None)
    truth = pixel_mean_depth(shape, center, R, depth, ppm)
    peak = np.unravel_index(np.argmax(truth), shape)
    assert abs(z[peak] - truth[peak]) < 1e-3  # 1 um
    assert z.sum() == pytest.approx(truth.sum(), rel=2e-4)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    r_px = np.hypot(cols - center[0], rows - center[1])
    rim_px = contact_radius_mm(R, depth) * ppm
    away = np.abs(r_px - rim_px) > 3
    step = max(depth - R, 0.0)
    assert np.abs(z - truth)[away].max() < 0.005 + 0.025 * step
    if depth < R:  # a continuous surface: right everywhere, the rim's kink included
        assert np.abs(z - truth).max() < 0.015


def test_a_slope_clamp_makes_labels_no_surface_has():
    """The 45-degree clamp the default scenes used: the calibration press integrates ~10 % short."""
    shape, center, ppm = (130, 120), (60.3, 64.6), 19.5
    g = sphere_gradients(shape, center, 2.0, 1.0, ppm, max_slope_deg=45)
    peak = poisson_dst(g[..., 0], g[..., 1], px_per_mm=ppm, max_angle_deg=None).max()
    assert 0.89 < peak < 0.92


def test_vertical_rim_labels_hold_the_wall_in_the_pixels_it_crosses():
    """d > R: the step d - R lies in the pixels the rim crosses; along the centre row the labels
    sum (times the pitch) to the depth change from the border to the centre pixel."""
    shape, center, R, d, ppm = (101, 101), (50.0, 50.0), 2.0, 3.0, 20.0
    g = sphere_gradients(shape, center, R, d, ppm).astype(np.float64)
    row = g[50, :, 0]
    assert np.all(np.isfinite(g))
    # trapezoidal sum of the edge means from column 0 to the centre column 50
    rise = 0.5 * (row[:50] + row[1:51]).sum() / ppm
    # ... up to the cap's own curvature over the centre pixel: its mean lies pitch²/(6R) below d
    assert rise == pytest.approx(d - 1 / (6 * R * ppm**2), abs=1e-7)
    # the rim pixel holds the wall and the cap's last, steepest pixel: sqrt(2 R pitch) high
    wall = np.abs(row).max() / ppm
    assert d - R < wall < d - R + math.sqrt(2 * R / ppm)


def test_gradient_signs_follow_image_frame_and_depth_into_gel():
    g = sphere_gradients((41, 41), (20, 20), 2.0, 1.0, PPM)
    # Depth is largest at the centre, so it falls to the right (+x) and downwards (+y rows).
    assert g[20, 30, 0] < 0 and g[20, 10, 0] > 0
    assert g[30, 20, 1] < 0 and g[10, 20, 1] > 0
    assert g[20, 30, 1] == pytest.approx(0, abs=1e-7)


def test_zero_outside_contact_and_empty_contact():
    g = sphere_gradients((50, 60), (30, 25), 2.0, 0.3, PPM)
    a_px = contact_radius_mm(2.0, 0.3) * PPM
    rows, cols = np.mgrid[0:50, 0:60]
    # a pixel's label is its mean slope: zero once its whole square lies outside the contact
    outside = np.hypot(cols - 30, rows - 25) >= a_px + math.sqrt(0.5)
    assert np.all(g[outside] == 0)
    assert np.all(sphere_gradients((50, 60), (30, 25), 2.0, 0.0, PPM) == 0)


def test_hemisphere_rim_is_clamped_finite_with_direction_kept():
    g = sphere_gradients((81, 81), (40, 40), 2.0, 2.0, PPM, max_slope_deg=60)
    assert np.all(np.isfinite(g))
    magnitude = np.hypot(g[..., 0], g[..., 1])
    assert magnitude.max() == pytest.approx(math.tan(math.radians(60)), rel=1e-6)
    # Direction kept: the clamped rim pixel to the right of the centre still points along -x.
    assert g[40, 79, 0] < 0 and abs(g[40, 79, 1]) < 1e-6


def test_centre_off_image_gives_partial_or_no_contact():
    g = sphere_gradients((30, 30), (-100.0, 15.0), 2.0, 1.0, PPM)
    assert np.all(g == 0)
    g = sphere_gradients((30, 30), (-5.0, 15.0), 2.0, 1.0, PPM)
    assert np.any(g != 0)


@pytest.mark.parametrize(
    "radius, depth", [(0, 1), (-1, 1), (float("nan"), 1), (2, -0.1), (2, float("inf"))]
)
def test_invalid_sphere_is_refused(radius, depth):
    with pytest.raises(ConfigError):
        sphere_gradients((10, 10), (5, 5), radius, depth, PPM)
