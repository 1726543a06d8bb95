"""Lighting-drift removal (threedcal.model.drift) in training and inference."""

import numpy as np
import pytest
import torch
from test_model import TINY, synthetic_set

from threedcal.errors import ConfigError
from threedcal.model.drift import drift_offset, remove_drift
from threedcal.model.inference import DepthEstimator
from threedcal.model.patches import ModelInputs
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings


def test_offset_is_the_global_shift_despite_a_contact():
    blank = torch.full((1, 3, 40, 48), 0.4)
    frame = blank + torch.tensor([0.1, -0.05, 0.0]).view(1, 3, 1, 1)
    frame[..., 10:25, 10:30] += 0.5  # a contact: under half of the frame
    diff = frame - blank
    torch.testing.assert_close(drift_offset(diff).flatten(), torch.tensor([0.1, -0.05, 0.0]))
    x = torch.cat([diff, torch.ones(1, 2, 40, 48)], 1)
    out = remove_drift(x, "median")
    assert torch.equal(out[:, 3:], x[:, 3:])  # coordinate channels untouched
    assert float(out[:, :3, 0, 0].abs().max()) < 1e-6
    assert remove_drift(x, "none") is x
    with pytest.raises(ConfigError, match="allowed: median, none"):
        remove_drift(x, "mean")


def test_extreme_inputs_all_contact_and_single_pixel():
    diff = torch.full((2, 3, 1, 1), 0.25)
    torch.testing.assert_close(drift_offset(diff), diff)
    assert remove_drift(diff, "median").abs().max() == 0


def test_training_uses_the_full_frame_offset_for_every_window():
    ts = synthetic_set()
    frames = np.asarray(ts.frames).astype(int)
    ts.frames = np.clip(frames + np.array([12, -7, 3]), 0, 255).astype(np.uint8)
    inputs = ModelInputs(ts, "median")
    window = (slice(0, 9), slice(5, 17))
    full = inputs(1)
    torch.testing.assert_close(inputs(1, window), full[:, window[0], window[1]])
    torch.testing.assert_close(inputs.offset(1).flatten(), torch.tensor([12, -7, 3]) / 255.0)
    np.testing.assert_array_equal(ModelInputs(ts, "none")(1).numpy(), ts.inputs(1))


@pytest.mark.parametrize("preset", ["lookup", "compact_tiny"])
def test_depth_estimator_ignores_a_global_lighting_shift(tmp_path, preset):
    ts = synthetic_set()
    checkpoint = train(ts, tmp_path, 80, TrainSettings.of(preset=preset, **TINY), progress=False)
    assert checkpoint["normalisation"]["drift"] == "median"
    est = DepthEstimator(checkpoint, device="cpu")
    frame = np.asarray(ts.frames[4])
    shifted = np.clip(frame.astype(int) + np.array([9, -4, 6]), 0, 255).astype(np.uint8)
    np.testing.assert_allclose(est.gradients(shifted), est.gradients(frame), atol=1e-5)
    off = train(
        ts,
        tmp_path / "off",
        80,
        TrainSettings.of(preset=preset, drift="none", **TINY),
        progress=False,
    )
    assert off["normalisation"]["drift"] == "none"
    est_off = DepthEstimator(off, device="cpu")
    assert not np.allclose(est_off.gradients(shifted), est_off.gradients(frame), atol=1e-3)
