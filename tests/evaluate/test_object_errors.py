"""Alignment, indentation fit and Type 1 / Type 2 errors: known shifts, known depths, hand-made arrays."""

from __future__ import annotations

import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.evaluate.align import align_xy, shift_image
from threedcal.evaluate.groundtruth import surface_height
from threedcal.evaluate.object_errors import (
    ERROR_COLUMNS,
    depth_errors_um,
    error_row,
    evaluate_press,
    fit_indentation,
    pixel_errors_um,
)
from threedcal.evaluate.objects import make_object

PX_PER_MM = 19.5
SHAPE = (140, 240)


@pytest.fixture(scope="module")
def pawn():
    return make_object("pawn")


def blob(shape=SHAPE, center=(60.0, 50.0)) -> np.ndarray:
    rows, cols = np.indices(shape, dtype=float)
    r2 = (cols - center[0]) ** 2 + ((rows - center[1]) / 1.7) ** 2
    return np.maximum(0.0, 1.0 - r2 / 400.0) + 0.3 * np.exp(-((cols - center[0] - 15) ** 2) / 20)


def brute_force(pred, h, lo, hi, n=200_001):
    d = np.linspace(lo, hi, n)
    cost = [((pred - np.maximum(0, x - h)) ** 2).sum() for x in d[::100]]
    i = int(np.argmin(cost)) * 100
    fine = d[max(0, i - 100) : i + 101]
    cost = [((pred - np.maximum(0, x - h)) ** 2).sum() for x in fine]
    return fine[int(np.argmin(cost))], min(cost)


def test_align_recovers_an_integer_shift_exactly():
    gt = blob()
    pred = shift_image(gt, 7, -4)
    (dx, dy), shifted = align_xy(pred, gt)
    assert (dx, dy) == (7.0, -4.0)
    np.testing.assert_array_equal(shifted, pred)
    (dx, dy), _ = align_xy(pred, gt, subpixel=True)
    assert dx == pytest.approx(7, abs=0.15) and dy == pytest.approx(-4, abs=0.15)


def test_align_recovers_a_subpixel_shift_of_a_rendered_object(pawn):
    gt = surface_height(pawn, SHAPE, PX_PER_MM, (120.0, 70.0)).depth(1.2)
    pred = surface_height(pawn, SHAPE, PX_PER_MM, (122.3, 68.6)).depth(1.2)
    (dx, dy), shifted = align_xy(pred, gt, subpixel=True)
    assert dx == pytest.approx(2.3, abs=0.2) and dy == pytest.approx(-1.4, abs=0.2)
    assert np.abs(shifted - pred).mean() < np.abs(gt - pred).mean() / 3


def test_align_respects_max_shift_and_checks_input():
    gt = blob()
    pred = shift_image(gt, 12, 0)
    (dx, dy), _ = align_xy(pred, gt, max_shift_px=5)
    assert abs(dx) <= 5 and abs(dy) <= 5
    with pytest.raises(ConfigError, match="one shape"):
        align_xy(pred, gt[:-1])
    with pytest.raises(ConfigError, match="finite"):
        align_xy(np.full(SHAPE, np.nan), gt)


def test_shift_image_fills_with_zeros():
    img = np.arange(12.0).reshape(3, 4) + 1
    out = shift_image(img, 1, 2)
    np.testing.assert_array_equal(out[2, 1:], img[0, :3])
    assert out[:2].sum() == 0 and out[:, 0].sum() == 0
    assert not shift_image(img, 10, 0).any()


def test_fit_recovers_a_known_depth(pawn):
    surface = surface_height(pawn, SHAPE, PX_PER_MM)
    for depth in (0.05, 0.8, 1.37):
        pred = surface.depth(depth)
        assert fit_indentation(pred, surface, bounds=(0, 2.0)) == pytest.approx(depth, abs=1e-9)
    noisy = surface.depth(1.1) + np.random.default_rng(0).normal(0, 0.02, SHAPE)
    assert fit_indentation(noisy, surface, bounds=(0, 2.0)) == pytest.approx(1.1, abs=0.01)
    # the optimum outside the bounds lands on the bound; no contact in the prediction → low bound
    assert fit_indentation(surface.depth(1.5), surface, bounds=(0, 1.0)) == 1.0
    assert fit_indentation(np.zeros(SHAPE), surface, bounds=(0.1, 1.0)) == 0.1


def test_fit_is_the_global_minimum_of_a_nonconvex_cost():
    rng = np.random.default_rng(3)
    for _ in range(5):
        h = rng.uniform(0, 1, 40)
        h[rng.random(40) < 0.2] = np.inf
        pred = rng.uniform(0, 1, 40) * (rng.random(40) < 0.5)
        d = fit_indentation(pred, h, bounds=(0.0, 1.2))
        cost = ((pred - np.maximum(0, d - h)) ** 2).sum()
        d_bf, cost_bf = brute_force(pred, h, 0.0, 1.2)
        assert cost <= cost_bf + 1e-12
    # hand-made: two pixels, h = (0, 1), prediction (0.5, 0) → d = 0.5 exactly
    assert fit_indentation(np.array([0.5, 0.0]), np.array([0.0, 1.0]), bounds=(0, 2)) == 0.5
    with pytest.raises(ConfigError, match="bounds"):
        fit_indentation(np.zeros(2), np.zeros(2), bounds=(1.0, 0.5))


def test_metrics_on_hand_made_arrays():
    pred = np.array([[0.1, 0.0], [0.5, 1.0]])
    gt = np.array([[0.0, 0.0], [0.4, 1.2]])
    errors = depth_errors_um(pred, gt)
    assert errors["overall_um"] == pytest.approx(100.0)
    assert errors["type1_um"] == pytest.approx(50.0)
    assert errors["type2_um"] == pytest.approx(150.0)
    assert (errors["n_type1"], errors["n_type2"]) == (2, 2)
    row = error_row("pill", 80, pred, gt)
    assert tuple(row) == ERROR_COLUMNS and row["P"] == 80
    assert np.isnan(depth_errors_um(pred, np.zeros((2, 2)))["type2_um"])
    table = pixel_errors_um("pill", pred, gt)
    assert list(table["type"]) == ["Type 1", "Type 1", "Type 2", "Type 2"]
    np.testing.assert_allclose(table["error_um"], [100, 0, 100, -200])
    with pytest.raises(ConfigError, match="shape"):
        depth_errors_um(pred, gt[:1])


def test_evaluate_press_recovers_pose_and_depth(pawn):
    true = surface_height(pawn, SHAPE, PX_PER_MM, (121.4, 67.2), rotation_deg=0.0)
    pred = true.depth(1.23) + np.random.default_rng(1).normal(0, 0.005, SHAPE)
    result = evaluate_press(
        pred,
        pawn,
        px_per_mm=PX_PER_MM,
        nominal_indentation_mm=1.0,
        max_penetration_mm=2.0,
        center_px=(119.5, 69.5),
    )
    # sampled at pixel centres, a vertical wall pins the pose only to within a pixel
    assert result.shift_px[0] == pytest.approx(1.9, abs=0.5)
    assert result.shift_px[1] == pytest.approx(-2.3, abs=0.5)
    assert result.indentation_mm == pytest.approx(1.23, abs=0.01)
    assert result.errors["type2_um"] < 20  # noise alone: 4 µm
