import math

import numpy as np
import pytest

from threedcal.dataset.labels import contact_radius_mm, sphere_depth, sphere_gradients
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


def test_gradients_match_finite_differences_of_the_depth_inside_the_contact():
    shape, center, R, d = (101, 121), (60.25, 50.6), 2.0, 0.6
    g = sphere_gradients(shape, center, R, d, PPM).astype(np.float64)
    fine = 1e-4  # mm step for central differences of the analytic depth
    x_off = (np.arange(shape[1]) - center[0]) / PPM
    y_off = (np.arange(shape[0]) - center[1]) / PPM
    X, Y = np.meshgrid(x_off, y_off)

    def z(x, y):
        return d - R + np.sqrt(np.clip(R * R - x * x - y * y, 0, None))

    inside = X**2 + Y**2 < (contact_radius_mm(R, d) - 0.05) ** 2
    gx = (z(X + fine, Y) - z(X - fine, Y)) / (2 * fine)
    gy = (z(X, Y + fine) - z(X, Y - fine)) / (2 * fine)
    np.testing.assert_allclose(g[..., 0][inside], gx[inside], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(g[..., 1][inside], gy[inside], rtol=1e-5, atol=1e-6)


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
    outside = np.hypot(cols - 30, rows - 25) >= a_px
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
