"""A depth map's contact against the probe's bound (threedcal.model.contact_guard), and its warning."""

import logging
import math

import numpy as np
import pandas as pd
import pytest

import threedcal.model.inference as inference
from threedcal.dataset.trainset import TrainingSet, samples_table
from threedcal.errors import ConfigError
from threedcal.model.contact_guard import (
    check_calibration_presses,
    contact_figures,
    oversized_message,
    probe_bound_px,
    warn_if_oversized,
)


def _cap(shape, centre, radius_px, depth_mm, px_per_mm):
    """The depth (mm) of a ball of radius radius_px / px_per_mm pressed depth_mm deep at centre."""
    yy, xx = np.mgrid[: shape[0], : shape[1]].astype(float)
    r_mm = radius_px / px_per_mm
    rho2 = ((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / px_per_mm**2
    surface = np.sqrt(np.clip(r_mm**2 - rho2, 0, None)) - (r_mm - depth_mm)
    return np.clip(surface, 0, None)


def test_the_bound_is_the_balls_disc_in_pixels():
    assert probe_bound_px(2.0, 9.75) == pytest.approx(math.pi * 19.5**2)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ConfigError, match="contact bound"):
            probe_bound_px(bad, 9.75)
        with pytest.raises(ConfigError, match="contact bound"):
            probe_bound_px(2.0, bad)


@pytest.mark.parametrize("shape", [(121, 161), (120, 160), (33, 17)])
def test_a_caps_contact_is_its_disc_above_the_threshold_centred_on_it(shape):
    centre = ((shape[1] - 1) / 2, (shape[0] - 1) / 2)
    px_per_mm, depth = 9.75, 0.6
    cap = _cap(shape, centre, 2.0 * px_per_mm, depth, px_per_mm)
    figures = contact_figures(cap, 2.0, px_per_mm)
    assert figures.area_px == int((cap > 0.05).sum()) > 0
    assert (figures.centroid_x_px, figures.centroid_y_px) == pytest.approx(centre, abs=1e-9)
    assert figures.peak_mm == pytest.approx(depth, abs=0.02)
    assert figures.area_ratio < 1  # a 0.6 mm press touches well inside the ball's disc
    assert oversized_message("unit", figures, 2.0) is None


def test_no_contact_nan_pixels_and_bad_input():
    depth = np.zeros((20, 30))
    depth[3, 4] = np.nan
    empty = contact_figures(depth, 2.0, 9.75)
    assert empty.area_px == 0 and math.isnan(empty.centroid_x_px) and empty.peak_mm == 0.0
    depth[5, 7] = 0.3  # one pixel in contact; the NaN stays out
    one = contact_figures(depth, 2.0, 9.75)
    assert (one.area_px, one.centroid_x_px, one.centroid_y_px) == (1, 7.0, 5.0)
    all_nan = contact_figures(np.full((4, 4), np.nan), 2.0, 9.75)
    assert all_nan.area_px == 0 and math.isnan(all_nan.peak_mm)
    with pytest.raises(ConfigError, match=r"one \(H, W\) depth map"):
        contact_figures(np.zeros((2, 3, 4)), 2.0, 9.75)
    with pytest.raises(ConfigError, match="threshold"):
        contact_figures(depth, 2.0, 9.75, threshold_mm=-0.1)


def test_a_contact_larger_than_the_probe_warns_naming_the_unit_and_the_fix(caplog):
    px_per_mm = 9.75
    depth = np.full((120, 160), 0.2)  # the whole frame reads as pressed: lighting read as depth
    figures = contact_figures(depth, 2.0, px_per_mm)
    assert figures.area_ratio == pytest.approx(120 * 160 / (math.pi * 19.5**2))
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        message = warn_if_oversized("DIGIT D20368 (scene digit_real)", figures, 2.0)
    assert message and message in caplog.text
    assert "DIGIT D20368 (scene digit_real)" in message
    assert "Calibrate this unit" in message and "retake the blank" in message
    assert "2 mm probe" in message and f"{figures.area_px} px" in message
    caplog.clear()
    within = contact_figures(_cap((120, 160), (80, 60), 19.5, 1.0, px_per_mm), 2.0, px_per_mm)
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        assert warn_if_oversized("unit", within, 2.0) is None
    assert not caplog.text


def test_a_trained_model_is_checked_on_its_calibrations_validation_presses(monkeypatch, caplog):
    """Up to `limit` validation presses, evenly spread, read by the model; their median contact
    over the probe's disc is returned and warned of above 1 (the training presses stand in for a
    set without validation ones)."""
    n, shape = 10, (30, 40)
    frames = np.zeros((n, *shape, 3), np.uint8)
    frames[:, 0, 0, 0] = np.arange(n)  # each frame says which it is
    read = []

    class Estimator:
        def depth(self, batch):
            read.extend(int(f[0, 0, 0]) for f in batch)
            # frame k reads a contact of 100 k px
            return np.stack(
                [
                    np.pad(
                        np.full(100 * int(f[0, 0, 0]), 0.2), (0, 1200 - 100 * int(f[0, 0, 0]))
                    ).reshape(shape)
                    for f in batch
                ]
            )

    monkeypatch.setattr(
        inference.DepthEstimator, "from_checkpoint", classmethod(lambda cls, *a, **k: Estimator())
    )
    split = ["train"] * 4 + ["val"] * 6
    samples = samples_table(np.arange(n), np.zeros((n, 2)), np.ones(n), np.ones(n), split, [80] * n)
    ts = TrainingSet(frames, np.zeros((*shape, 3), np.float32), samples, 5.0, 2.0)
    bound = math.pi * 10.0**2
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        ratio = check_calibration_presses("model.pt", ts, "scene s, P=80 r0", limit=3)
    assert read == [4, 6, 9]  # three of the six validation presses, first to last
    assert ratio == pytest.approx(600 / bound)
    assert "scene s, P=80 r0" in caplog.text and "600 px" in caplog.text
    train_only = TrainingSet(frames, ts.blank, samples.assign(split="train"), 5.0, 2.0)
    read.clear()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        assert check_calibration_presses("m.pt", train_only, "u", limit=2) == pytest.approx(
            450 / bound
        )
    assert read == [0, 9] and "u:" in caplog.text  # 900 px over 314: the median is warned of
    empty = TrainingSet(frames[:0], ts.blank, samples.iloc[:0], 5.0, 2.0)
    assert math.isnan(check_calibration_presses("m.pt", empty, "u"))
    assert isinstance(samples, pd.DataFrame)
