"""The radial lens model: exact mappings, its inverse, rectification, and the profile's constants."""

import math

import cv2
import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.lens import RadialLens, rectify_if
from threedcal.profiles import load_profile

BARREL = RadialLens(centre_px=(119.5, 159.5), kappa1=-1.0e-6, kappa2=2.0e-12, shape=(320, 240))


def test_distort_moves_a_point_by_the_closed_form_radial_factor():
    # 30 px right and 40 px down of the centre: r = 50, factor 1 + κ₁ 2500 + κ₂ 2500²
    point = np.array([119.5 + 30.0, 159.5 + 40.0])
    factor = 1 - 1e-6 * 2500 + 2e-12 * 2500**2
    np.testing.assert_allclose(
        BARREL.distort(point), [119.5 + 30 * factor, 159.5 + 40 * factor], rtol=0, atol=1e-12
    )
    # the principal point does not move
    np.testing.assert_allclose(BARREL.distort(np.array(BARREL.centre_px)), BARREL.centre_px)


def test_undistort_inverts_distort_to_1e_9_px_over_the_whole_frame():
    cols, rows = np.meshgrid(np.linspace(-5, 245, 23), np.linspace(-5, 325, 31))
    ideal = np.stack([cols, rows], axis=-1)
    np.testing.assert_allclose(BARREL.undistort(BARREL.distort(ideal)), ideal, atol=1e-9)


def test_undistort_refuses_a_lens_that_folds_the_frame():
    # r (1 + κ₁ r²) turns back at r = 1 / sqrt(3 |κ₁|) = 57.7 px: corners 200 px out cannot invert
    folding = RadialLens(centre_px=(0.0, 0.0), kappa1=-1e-4)
    with pytest.raises(ConfigError, match="folds the image"):
        folding.undistort(np.array([[120.0, 160.0]]))


def test_rectify_puts_each_ideal_pixel_where_the_camera_imaged_it():
    # a camera image of a linear ramp in ideal coordinates, I(ideal) = 2 col + 3 row, sampled
    # where each camera pixel looks: rectifying it must give the ramp back on the ideal grid
    height, width = 320, 240
    cols, rows = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    seen = BARREL.undistort(np.stack([cols, rows], axis=-1))
    camera = (2 * seen[..., 0] + 3 * seen[..., 1]).astype(np.float32)
    rectified = BARREL.rectify(camera)
    truth = 2 * cols + 3 * rows
    # up to bilinear interpolation of the camera image, which the lens curves slightly
    np.testing.assert_allclose(rectified, truth, atol=0.02)


def test_rectify_keeps_dtype_and_batch_and_refuses_another_frame_size():
    frames = np.random.default_rng(0).integers(0, 255, (2, 320, 240, 3), dtype=np.uint8)
    out = BARREL.rectify(frames)
    assert out.shape == frames.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[1], BARREL.rectify(frames[1]))
    assert rectify_if(None, frames) is frames
    with pytest.raises(ConfigError, match=r"\(240, 320\)"):
        BARREL.rectify(np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(ConfigError, match=r"got \(0, 320, 240, 3\)"):
        BARREL.rectify(np.zeros((0, 320, 240, 3), np.uint8))
    # integers other than uint8 are rounded back, not truncated
    ramp = (np.arange(320 * 240, dtype=np.uint16).reshape(320, 240) % 1000) * 60
    np.testing.assert_array_equal(
        BARREL.rectify(ramp), np.rint(BARREL.rectify(ramp.astype(np.float32))).astype(np.uint16)
    )


def test_record_round_trips_and_a_malformed_one_names_the_problem():
    assert RadialLens.from_record(BARREL.record()) == BARREL
    assert RadialLens.from_record(None) is None
    with pytest.raises(ConfigError, match="kappa1_per_px2"):
        RadialLens.from_record({"centre_px": [0, 0]})
    with pytest.raises(ConfigError, match="two numbers each"):
        RadialLens.from_record({"centre_px": [0, 0, 1], "kappa1_per_px2": 0.0})
    with pytest.raises(ConfigError, match="malformed"):
        RadialLens.from_record(["not", "a", "mapping"])
    with pytest.raises(ConfigError, match="finite"):
        RadialLens(centre_px=(0.0, math.nan), kappa1=0.0)


def test_digit_profile_lens_has_tactos_focal_length_in_opencv_units():
    # 60 degrees across 320 rows: f = 160 / tan(30 deg) = 277.1 px, and κ₁ = k1 / f²
    digit = load_profile("sensor", "digit")
    lens = RadialLens.from_profile(digit)
    focal = 160 / math.tan(math.radians(30))
    assert lens.kappa1 == pytest.approx(digit["lens"]["k1"] / focal**2, rel=1e-12)
    assert lens.centre_px == (119.5, 159.5) and lens.shape == (320, 240)
    assert RadialLens.from_profile({"image": {}, "lens": None}) is None


def test_the_lens_is_opencvs_camera_matrix_and_distortion():
    """OpenCV's own answers for the lens as `opencv()` writes it: projectPoints distorts as
    `distort`, undistortPoints inverts as `undistort`, initUndistortRectifyMap gives the maps
    `rectify` uses; and the form round-trips."""
    lens = RadialLens(centre_px=(121.3, 157.8), kappa1=-1.1e-6, kappa2=0.0, shape=(320, 240))
    matrix, coeffs = lens.opencv(focal_px=250.0)
    assert RadialLens.from_opencv(matrix, coeffs, lens.shape) == lens
    cols, rows = np.meshgrid(np.linspace(0, 239, 9), np.linspace(0, 319, 11))
    ideal = np.stack([cols.ravel(), rows.ravel()], axis=-1)
    rays = np.column_stack([(ideal - matrix[:2, 2]) / matrix[0, 0], np.ones(len(ideal))])
    projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), matrix, coeffs)
    np.testing.assert_allclose(lens.distort(ideal), projected[:, 0], atol=1e-9)
    camera = lens.distort(ideal)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    back = cv2.undistortPoints(camera[:, None], matrix, coeffs, None, None, matrix, criteria)
    np.testing.assert_allclose(lens.undistort(camera), back[:, 0], atol=1e-6)
    map_x, map_y = lens.rectify_maps(lens.shape)
    grid = np.stack(np.meshgrid(np.arange(240.0), np.arange(320.0)), axis=-1)
    np.testing.assert_allclose(np.stack([map_x, map_y], axis=-1), lens.distort(grid), atol=1e-3)
    with pytest.raises(ConfigError, match="p1, p2, k3 zero"):
        RadialLens.from_opencv(matrix, [0.1, 0.0, 0.01, 0.0, 0.0])


def test_camera_info_is_what_ros_reads():
    info = BARREL.camera_info(focal_px=300.0)
    assert (info["image_width"], info["image_height"]) == (240, 320)
    assert info["distortion_model"] == "plumb_bob"
    matrix = np.array(info["camera_matrix"])
    assert matrix[0, 0] == matrix[1, 1] == 300.0 and tuple(matrix[:2, 2]) == BARREL.centre_px
    k1, k2, *rest = info["distortion_coefficients"]
    assert k1 == pytest.approx(-1e-6 * 300**2) and k2 == pytest.approx(2e-12 * 300**4)
    assert rest == [0.0, 0.0, 0.0] and np.array(info["projection_matrix"]).shape == (3, 4)
