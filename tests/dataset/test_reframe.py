"""Bringing a set to another network's frame (threedcal.dataset.reframe): pooled, turned a quarter
when it stands on its side, and gradients brought back exactly."""

import numpy as np
import pytest

from threedcal.dataset.reframe import Reframe, reframe, reframe_problem, turn_quarter
from threedcal.dataset.trainset import TrainingSet, samples_table
from threedcal.errors import ConfigError

PX_PER_MM, BALL_MM = 10.0, 2.0


def portrait_set(height=40, width=30, centres=((11.0, 17.5), (20.25, 9.0))):
    """A portrait set: frames whose pixel values encode their position, two sphere presses."""
    rows, cols = np.mgrid[0:height, 0:width]
    frame = np.stack([rows % 256, cols % 256, (rows + 3 * cols) % 256], axis=-1).astype(np.uint8)
    n = len(centres)
    return TrainingSet(
        frames=np.stack([frame] * n),
        blank=frame.astype(np.float32) / 2,
        samples=samples_table(np.arange(n), centres, [0.5] * n, [6.0] * n, ["train"] * n, [80] * n),
        px_per_mm=PX_PER_MM,
        sphere_radius_mm=BALL_MM,
        meta={"sensor": "gelsight_mini", "downscale": 1},
    )


def test_a_quarter_turn_moves_pixels_and_centres_and_turns_the_labels_back_exactly():
    ts = portrait_set()
    turned = turn_quarter(ts)
    height, width = ts.image_shape
    assert turned.image_shape == (width, height)
    # pixel (x, y) goes to (y, W - 1 - x): frame, blank and centres alike
    for x, y in ((0, 0), (7, 31), (29, 39)):
        assert np.array_equal(turned.frames[0][width - 1 - x, y], ts.frames[0][y, x])
        assert turned.blank[width - 1 - x, y, 0] == ts.blank[y, x, 0]
    assert np.allclose(turned.center_px, [[17.5, 18.0], [9.0, 8.75]])
    how = Reframe(full_shape=(height, width), factor=1, turned=True)
    for i in range(2):
        # the exact sphere labels of the turned press, turned back, are the press's own
        back = how.gradients_back(turned.labels(i).transpose(1, 2, 0))
        assert np.allclose(back, ts.labels(i).transpose(1, 2, 0), atol=1e-6)
        assert np.abs(back).max() > 0.1


def linear_field(height, width):
    """(H, W, 2) gradients linear in x and y: what bilinear interpolation reproduces exactly."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([0.01 * cols - 0.02 * rows + 0.3, -0.015 * cols + 0.005 * rows - 0.1], -1)


def test_pooled_and_turned_gradients_come_back_at_the_original_pixels():
    height, width = 40, 30
    field = linear_field(height, width)
    # what a network in the pooled, turned frame would see: the 2x2 block means, turned a quarter
    pooled = field.reshape(height // 2, 2, width // 2, 2, 2).mean(axis=(1, 3))
    turned = np.rot90(pooled, axes=(0, 1))
    in_network = np.stack([turned[..., 1], -turned[..., 0]], -1)  # d/dx' = d/dy, d/dy' = -d/dx
    how = Reframe(full_shape=(height, width), factor=2, turned=True)
    assert how.shape == (15, 20)
    back = how.gradients_back(in_network)
    assert back.shape == (height, width, 2)
    # exact inside (bilinear on a linear field); the outermost pixels are clamped to the edge
    assert np.allclose(back[1:-1, 1:-1], field[1:-1, 1:-1], atol=1e-5)
    with pytest.raises(ValueError, match="expected"):
        how.gradients_back(pooled)


def test_reframe_pools_by_the_whole_factor_and_turns_only_a_frame_on_its_side():
    ts = portrait_set()
    framed, how = reframe(ts, (15, 20), "sim_to_real.shipped")
    assert (how.factor, how.turned, framed.image_shape) == (2, True, (15, 20))
    assert framed.px_per_mm == PX_PER_MM / 2 and framed.meta["downscale"] == 2
    assert how.describe() == "15x20 px (40x30 pooled 2x, turned a quarter)"
    # centre (11, 17.5) pools to (5.25, 8.5), then turns to (8.5, 15 - 1 - 5.25)
    assert np.allclose(framed.center_px[0], [8.5, 8.75])
    same, how = reframe(ts, (20, 15), "k")
    assert (how.factor, how.turned) == (2, False) and how.describe() == "20x15 px (40x30 pooled 2x)"
    assert reframe(ts, (40, 30), "k")[1].describe() == "40x30 px"
    # a frame a few px larger than a whole multiple is cropped by the pooling, padded back
    odd = portrait_set(height=41, width=31)
    framed, how = reframe(odd, (15, 20), "k")
    assert how.factor == 2 and how.gradients_back(np.zeros((15, 20, 2))).shape == (41, 31, 2)
    with pytest.raises(ConfigError, match=r"sim_to_real.shipped: 40 x 30 px frames .* 16 x 16"):
        reframe(ts, (16, 16), "sim_to_real.shipped")
    assert reframe_problem((240, 320), (120, 160)) is None
    assert reframe_problem((320, 240), (120, 160)) is None
    assert "cannot be pooled" in reframe_problem((100, 100), (120, 160))
