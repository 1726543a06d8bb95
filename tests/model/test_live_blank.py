"""`live` recovers: the blank re-taken on request (SIGUSR1 here, the b key in the window), a warning
when the no-contact region drifts from it, and each frame's points as PLY."""

import os
import signal

import cv2
import numpy as np
import pytest
import torch
import trimesh
from conftest import DATA, write_untrained_model

import threedcal.cli.handlers.model as live_handler  # where `live` looks its source up
from threedcal.cli import main
from threedcal.images import read_rgb
from threedcal.model import BACKGROUND_DRIFT_WARN_DN
from threedcal.model.drift import DRIFT_CELL_PX, background_drift_dn
from threedcal.model.inference import DepthEstimator
from threedcal.model.presets import build_model

BLANK = read_rgb(DATA / "digit_frames_fots" / "background.png")  # a real DIGIT's, 320 x 240


def shifted(frame, change):
    """`frame` with its lighting changed by `change` grey levels (broadcast), as uint8."""
    out = frame.astype(np.float64) + change
    assert out.min() >= 0 and out.max() <= 255  # no clipping: the change is exact
    return out.astype(np.uint8)


def ramp(amplitude, width=BLANK.shape[1]):
    """A lighting gradient across the columns, -amplitude .. +amplitude grey levels: one side's
    LED dimmer, the other's brighter. (1, W, 1), whole grey levels."""
    return np.round(np.linspace(-amplitude, amplitude, width))[None, :, None]


def test_a_uniform_shift_is_no_drift_and_a_gradient_is_its_rms():
    """The model removes a per-channel offset itself (the median), so a uniform shift is 0; a
    linear ramp across the columns is the RMS of its cell means (computed here exactly)."""
    assert background_drift_dn(shifted(BLANK, -10), BLANK) == pytest.approx(0.0, abs=1e-6)
    change = ramp(6)
    cells = change[0, :, 0].reshape(-1, DRIFT_CELL_PX).mean(axis=1)
    expected = np.sqrt(np.mean((cells - np.median(change[0, ::4, 0])) ** 2))
    got = background_drift_dn(shifted(BLANK, change), BLANK)
    assert got == pytest.approx(expected, rel=1e-4) and got > 3.0


def test_the_contact_and_its_halo_are_left_out_and_odd_sizes_work():
    frame = BLANK.astype(np.float64)
    frame[100:140, 80:120] += 60  # a contact's colour change
    frame = frame.clip(0, 255).astype(np.uint8)
    contact = np.zeros(BLANK.shape[:2], bool)
    contact[104:136, 84:116] = True  # its depth > threshold only inside: the rim is halo
    assert background_drift_dn(frame, BLANK) > 5.0
    assert background_drift_dn(frame, BLANK, contact) < 1e-6
    assert np.isnan(background_drift_dn(frame, BLANK, np.ones_like(contact)))
    small = BLANK[:13, :21]
    assert background_drift_dn(shifted(small, 5), small) == pytest.approx(0.0, abs=1e-6)


@pytest.fixture
def flat_model(tmp_path):
    """A model that reads no depth anywhere (zero weights) on the real blank: what drifts is only
    the lighting."""
    model = build_model("compact_tiny")
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.zero_()
    return write_untrained_model(tmp_path / "model.pt", "compact_tiny", BLANK, model)


def test_retake_blank_compares_later_frames_with_the_new_one(flat_model):
    estimator = DepthEstimator.from_checkpoint(flat_model, device="cpu")
    drifted = shifted(BLANK, ramp(6))
    assert background_drift_dn(drifted, estimator.blank) > BACKGROUND_DRIFT_WARN_DN
    estimator.retake_blank(drifted)
    np.testing.assert_array_equal(estimator.blank, drifted.astype(np.float32))
    assert background_drift_dn(drifted, estimator.blank) == 0.0
    with pytest.raises(ValueError, match="frame"):
        estimator.retake_blank(drifted[:100])


def test_live_warns_on_drift_and_a_signal_retakes_the_blank(
    tmp_path, monkeypatch, capsys, flat_model
):
    """Frames: the lighting shifted uniformly (no warning: the model removes it), then a lighting
    gradient (one warning, not one per frame), SIGUSR1 (that frame becomes the blank: no warning
    for the same lighting), then the gradient doubled (a warning again, against the new blank)."""
    frames = [shifted(BLANK, 12), *[shifted(BLANK, ramp(6))] * 4, shifted(BLANK, ramp(12))]

    def source(spec, sensor=None):
        for count, frame in enumerate(frames):
            if count == 3:
                os.kill(os.getpid(), signal.SIGUSR1)  # as `kill -USR1 PID` from a shell
            yield frame

    monkeypatch.setattr(live_handler, "open_source", source)
    before = signal.getsignal(signal.SIGUSR1)
    points = tmp_path / "points"
    args = ["live", "--checkpoint", flat_model, "--source", "stream", "--device", "cpu"]
    assert main([*args, "--points", str(points)]) == 0
    out = capsys.readouterr().out
    warnings = [line for line in out.splitlines() if "warning" in line]
    assert len(warnings) == 2, out
    assert warnings[0].startswith("live: warning: frame 1: the no-contact region has drifted")
    assert "press b or send SIGUSR1" in warnings[0]
    assert "frame 3 is the blank from now on" in out
    assert warnings[1].startswith("live: warning: frame 5:")
    assert signal.getsignal(signal.SIGUSR1) == before  # the handler is put back
    # one PLY per frame, every pixel a point, none in contact (the model reads no depth)
    clouds = sorted(points.glob("frame_*.ply"))
    assert [p.name for p in clouds] == [f"frame_{i:06d}.ply" for i in range(6)]
    cloud = trimesh.load(clouds[0])
    assert len(cloud.vertices) == BLANK.shape[0] * BLANK.shape[1]
    np.testing.assert_allclose(cloud.vertices[:, 2], 0.0, atol=1e-6)
    # an earlier run's clouds are never replaced without --force
    assert main([*args, "--points", str(points)]) == 1
    assert "holds 6 point clouds of an earlier run" in capsys.readouterr().err
    assert main([*args, "--points", str(points), "--force", "--drift-warn-dn", "50"]) == 0
    assert "warning" not in capsys.readouterr().out  # the threshold is the user's


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--drift-warn-dn", "0"], "--drift-warn-dn must be a number > 0"),
        (["--points", "model.pt"], "is a file; give a folder"),
        (["--points", "out", "--frame-of", "printer"], "carries none"),
        (["--contact-mm", "-1"], "--contact-mm must be a number >= 0"),
    ],
)
def test_live_checks_its_new_options_before_the_first_frame(
    tmp_path, monkeypatch, capsys, flat_model, extra, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "frames").mkdir()
    read = tmp_path / "frames" / "0.png"

    cv2.imwrite(str(read), BLANK)
    args = ["live", "--checkpoint", flat_model, "--source", str(tmp_path / "frames")]
    extra = [str(tmp_path / "model.pt") if e == "model.pt" else e for e in extra]
    assert main([*args, "--device", "cpu", *extra]) == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_live_reads_a_datasets_frames_with_numpy_alone(tmp_path, capsys, flat_model):
    """A model-ready dataset's frames.npy is a source (no pandas: the core reads it); anything but
    (N, H, W, 3) uint8 there is refused, naming the file."""
    dataset = tmp_path / "trainset"
    dataset.mkdir()
    np.save(dataset / "frames.npy", np.stack([BLANK, shifted(BLANK, 3)]))
    args = ["live", "--checkpoint", flat_model, "--source", str(dataset), "--device", "cpu"]
    assert main(args + ["--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "2 frames, depth at" in out
    assert "cpu, 1 threads, " in out and "float32)" in out  # how this machine runs it
    np.save(dataset / "frames.npy", np.zeros((2, 8, 8), np.float32))
    assert main(args) == 1
    assert "frames.npy: not a dataset's frames" in capsys.readouterr().err


def test_a_camera_needs_its_sensor_profile_before_anything_loads(tmp_path, capsys):
    """A camera's frames are converted by its profile (as at collection): without --sensor, live
    stops before it reads the model (here none exists) or opens the camera."""
    missing = str(tmp_path / "missing.pt")
    assert main(["live", "--checkpoint", missing, "--source", "0"]) == 1
    assert "--source 0 is a camera: give --sensor" in capsys.readouterr().err


def test_live_with_a_stated_probe_warns_when_the_contact_outgrows_it(
    tmp_path, monkeypatch, capsys, flat_model
):
    """A model that reads depth over the whole frame (its lighting read as depth) covers more
    than a 2 mm ball can touch: one warning naming the unit and the fix, none again until a frame
    comes back within; with no probe stated, or one large enough, no warning."""
    frames = [BLANK] * 4
    reads = iter([0.0, 0.3, 0.3, 0.0] * 3)

    def depth(self, frame):
        return np.full(frame.shape[:2], next(reads), np.float32)

    monkeypatch.setattr(DepthEstimator, "depth", depth)
    monkeypatch.setattr(live_handler, "open_source", lambda spec, sensor=None: frames)
    args = ["live", "--checkpoint", flat_model, "--source", "stream", "--device", "cpu"]
    assert main([*args, "--probe-radius-mm", "2"]) == 0
    warnings = [line for line in capsys.readouterr().out.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith("live: warning: frame 1: --source stream")
    assert "the most a 2 mm probe can touch" in warnings[0]
    assert "Calibrate this unit" in warnings[0] and "retake the blank" in warnings[0]
    assert main(args) == 0  # no probe stated: no bound to check
    assert "warning" not in capsys.readouterr().out
    assert main([*args, "--probe-radius-mm", "100"]) == 0  # a ball larger than the frame
    assert "warning" not in capsys.readouterr().out
    assert main([*args, "--probe-radius-mm", "-2"]) == 1
    assert "--probe-radius-mm must be a number > 0" in capsys.readouterr().err
