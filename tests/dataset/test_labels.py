import math

import numpy as np
import pytest

from threedcal.dataset.labels import (
    LocalDome,
    contact_radius_mm,
    local_dome,
    sphere_depth,
    sphere_gradients,
)
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


def pixel_mean_depth(shape, center, R, d, ppm, n=16, dome=None):
    """The true depth map as a finite-volume solver sees it: each pixel's mean depth (n x n samples)."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    total = np.zeros(shape)
    for sy in (np.arange(n) + 0.5) / n - 0.5:
        for sx in (np.arange(n) + 0.5) / n - 0.5:
            if dome is None:
                total += sphere_depth(shape, (center[0] - sx, center[1] - sy), R, d, ppm)
                continue
            x, y = (cols + sx - center[0]) / ppm, (rows + sy - center[1]) / ppm
            inside = x * x + y * y < R * R
            z = d - R + np.sqrt(np.where(inside, R * R - x * x - y * y, 0.0)) - dome.sag_mm(x, y)
            total += np.where(inside, np.maximum(z, 0.0), 0.0)
    return total / (n * n)


# A DIGIT's dome seen from a press 6 mm left of and 7 mm below its apex, and a far stronger one
DIGIT_DOME = LocalDome(0.013, 0.0043, -6.0, 7.0)
STEEP_DOME = LocalDome(0.1, 0.05, 3.0, -4.0)


def edge_mean_gradients(shape, center, R, d, ppm, dome, n=3000):
    """Brute force of the definition: each pixel's mean gradient is the difference of the depth's
    means along its two edges (n samples each) over the pitch."""
    pitch = 1.0 / ppm
    x = (np.arange(shape[1]) - center[0]) * pitch
    y = (np.arange(shape[0]) - center[1]) * pitch
    t = ((np.arange(n) + 0.5) / n - 0.5) * pitch

    def z(X, Y):
        inside = X * X + Y * Y < R * R
        cap = d - R + np.sqrt(np.where(inside, R * R - X * X - Y * Y, 0.0)) - dome.sag_mm(X, Y)
        return np.where(inside, np.maximum(cap, 0.0), 0.0)

    g = np.zeros(shape + (2,))
    x_edges, y_edges = (
        np.append(x - pitch / 2, x[-1] + pitch / 2),
        np.append(y - pitch / 2, y[-1] + pitch / 2),
    )
    for i in range(shape[0]):
        g[i, :, 0] = np.diff(z(x_edges[:, None], y[i] + t[None, :]).mean(axis=1)) / pitch
    for j in range(shape[1]):
        g[:, j, 1] = np.diff(z(x[j] + t[None, :], y_edges[:, None]).mean(axis=1)) / pitch
    return g


@pytest.mark.parametrize("dome", [DIGIT_DOME, STEEP_DOME], ids=["digit", "steep"])
@pytest.mark.parametrize("depth", [0.3, 1.0])
def test_domed_labels_are_the_mean_gradient_over_each_pixel(depth, dome):
    """On a domed gel the ball pushes the gel where it lies below the undeformed surface: the labels
    are the pixel means of that depth's gradient (the contact is off the axis and tilted)."""
    shape, center, R, ppm = (54, 58), (28.3, 25.6), 2.0, 12.0
    g = sphere_gradients(shape, center, R, depth, ppm, dome=dome).astype(np.float64)
    brute = edge_mean_gradients(shape, center, R, depth, ppm, dome)
    # 3e-4: the brute force's own error where the steep dome's contact nears the ball's equator
    # (a square-root edge: 2.4e-4 with 3,000 samples per edge, 1.4e-5 with 48,000)
    np.testing.assert_allclose(g, brute, atol=3e-4)
    flat = sphere_gradients(shape, center, R, depth, ppm).astype(np.float64)
    assert np.abs(g - flat).max() > 0.1  # the dome changes the labels (at the rim most)


def test_a_dome_without_curvature_gives_the_flat_labels():
    shape, center = (50, 50), (24.2, 25.9)
    for depth in (0.5, 2.0, 3.0):
        flat = sphere_gradients(shape, center, 2.0, depth, 12.0)
        level = sphere_gradients(shape, center, 2.0, depth, 12.0, dome=LocalDome(0, 0, -5.0, 3.0))
        np.testing.assert_allclose(level, flat, atol=1e-6)


def test_local_dome_places_the_press_relative_to_the_apex():
    dome = {"kx_per_mm": 0.013, "ky_per_mm": 0.0043, "apex_x_mm": 0.5, "apex_y_mm": 0.0}
    local = local_dome(dome, (159.5 + 40.0, 119.5 - 20.0), (240, 320), 20.0)
    assert (local.x0_mm, local.y0_mm) == pytest.approx((1.5, -1.0))
    # the sag relative to the axis: zero there, the dome's own difference elsewhere
    assert local.sag_mm(0.0, 0.0) == 0.0
    assert local.sag_mm(1.0, 2.0) == pytest.approx(
        0.013 * (2.5**2 - 1.5**2) + 0.0043 * (1.0**2 - 1.0**2)
    )
    assert local_dome(None, (10, 10), (240, 320), 20.0) is None


@pytest.mark.parametrize("depth", [1.0, 3.0])
def test_domed_labels_integrate_to_the_domed_depth(depth):
    """poisson_dst of exact domed labels gives back the depth below the undeformed dome (peak to
    1 um, volume to 0.05 %), a wall (d > R) as on a flat gel."""
    shape, center, R, ppm = (130, 120), (60.3, 64.6), 2.0, 19.5
    g = sphere_gradients(shape, center, R, depth, ppm, dome=DIGIT_DOME)
    z = poisson_dst(g[..., 0], g[..., 1], px_per_mm=ppm, max_angle_deg=None)
    truth = pixel_mean_depth(shape, center, R, depth, ppm, dome=DIGIT_DOME)
    peak = np.unravel_index(np.argmax(truth), shape)
    assert abs(z[peak] - truth[peak]) < 1e-3
    assert z.sum() == pytest.approx(truth.sum(), rel=5e-4)
    if depth < R:  # a continuous surface: right everywhere, the rim's kink included
        assert np.abs(z - truth).max() < 0.015
    else:  # the wall stands at the equator all round: as on a flat gel, right 3 px from it
        rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
        away = np.abs(np.hypot(cols - center[0], rows - center[1]) - R * ppm) > 3
        assert np.abs(z - truth)[away].max() < 0.005 + 0.025 * (depth - R)


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
