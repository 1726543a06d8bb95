import math

import numpy as np
import pytest

from threedcal.dataset.labels import sphere_gradients
from threedcal.dataset.registration import (
    RegistrationError,
    estimate_touch_offset_mm,
    find_contact,
    fit_affine,
    locate_contact,
)

PPM = 19.0
SHAPE = (320, 240)


def shaded_frame(center, depth=1.0, radius=2.0, noise=1.0, seed=0):
    """A stand-in sensor image: a smooth background plus shading linear in the surface gradient."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    background = np.stack([120 + 0.1 * cols, 110 + 0.05 * rows, 130 - 0.05 * cols], axis=-1)
    g = sphere_gradients(SHAPE, center, radius, depth, PPM).astype(float)
    mixing = np.array([[40, 0, 25], [-20, 35, 25], [-20, -35, 25]], dtype=float)  # 3 lights
    shading = g[..., 0:1] * mixing[:, 0] + g[..., 1:2] * mixing[:, 1]
    shading += (np.hypot(g[..., 0], g[..., 1]) > 0)[..., None] * mixing[:, 2]
    frame = background + shading + rng.normal(0, noise, background.shape)
    blank = background + rng.normal(0, noise, background.shape)
    return np.clip(frame, 0, 255).astype(np.uint8), np.clip(blank, 0, 255).astype(np.uint8)


def rotation_scale(theta_deg, sx, sy, shear=0.0):
    t = math.radians(theta_deg)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    return rot @ np.array([[sx, shear], [0, sy]])


def test_find_contact_locates_a_subpixel_centre():
    contact = locate_contact(*shaded_frame((101.3, 180.6)))
    assert contact is not None
    assert abs(contact.x_px - 101.3) < 0.5 and abs(contact.y_px - 180.6) < 0.5
    a_px = math.sqrt(2 * 2.0 * 1.0 - 1.0) * PPM
    assert 0.6 * a_px < contact.radius_px < 1.1 * a_px


def test_no_contact_in_a_blank_frame():
    frame, blank = shaded_frame((100, 100), depth=0.0)
    assert find_contact(frame, blank) is None


def test_shape_mismatch_is_an_error():
    frame, blank = shaded_frame((100, 100))
    with pytest.raises(RegistrationError, match="shape"):
        find_contact(frame[:-1], blank)


def test_affine_with_rotation_and_unequal_scales_is_recovered_from_frames():
    linear = rotation_scale(3.0, 19.2, -18.7)  # printer y points up in the image: negative scale
    offset = np.array([118.0, 162.0])
    xs, ys = np.meshgrid(np.linspace(-3, 3, 5), np.linspace(-5, 5, 6))
    xy_mm = np.column_stack([xs.ravel(), ys.ravel()])
    truth = xy_mm @ linear.T + offset
    found = []
    for i, (cx, cy) in enumerate(truth):
        contact = locate_contact(*shaded_frame((cx, cy), seed=i))
        found.append((np.nan, np.nan) if contact is None else (contact.x_px, contact.y_px))
    assert np.isfinite(found).all(axis=1).sum() >= 15  # contacts cut by the frame edge are left out
    fit = fit_affine(xy_mm, np.array(found))
    np.testing.assert_allclose(fit.matrix[:, :2], linear, atol=0.05)
    # Error of the fitted map over the probed area, against the true one.
    error = np.linalg.norm(fit.apply(xy_mm) - truth, axis=1)
    assert error.max() < 0.3
    sx, sy = fit.px_per_mm
    assert sx == pytest.approx(19.2, abs=0.05) and sy == pytest.approx(18.7, abs=0.05)


def test_affine_fit_rejects_outliers():
    rng = np.random.default_rng(1)
    linear = rotation_scale(-2.0, 20.0, 21.0, shear=0.3)
    xy_mm = rng.uniform(-5, 5, (60, 2))
    px = xy_mm @ linear.T + [100, 150] + rng.normal(0, 0.1, (60, 2))
    px[[3, 17, 42]] += [[25, 0], [0, -40], [13, 13]]
    px[8] = np.nan  # a frame with no contact found
    fit = fit_affine(xy_mm, px)
    assert not fit.inliers[[3, 17, 42, 8]].any()
    assert fit.inliers.sum() == 56
    np.testing.assert_allclose(fit.matrix[:, :2], linear, atol=0.02)
    assert fit.residual_px < 0.2


def test_affine_needs_three_non_collinear_points():
    with pytest.raises(RegistrationError, match="not on one line"):
        fit_affine(np.array([[0, 0], [1, 1], [2, 2]]), np.array([[0, 0], [1, 1], [2, 2]]))


def test_touch_offset_recovered_from_contact_radii():
    R, delta = 2.0, 0.15
    commanded = np.array([0.3, 0.5, 0.8, 1.0, 1.2])
    true = commanded + delta
    a = np.sqrt(2 * R * true - true**2)
    assert estimate_touch_offset_mm(commanded, a, R) == pytest.approx(delta, abs=1e-9)
    with pytest.raises(RegistrationError):
        estimate_touch_offset_mm(commanded, np.zeros(5), R)
