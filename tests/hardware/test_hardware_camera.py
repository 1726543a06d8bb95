import cv2
import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.hardware.camera import (
    BlackFrame,
    Camera,
    CameraError,
    CameraTimeout,
    DroppedFrame,
    OpenCVCamera,
    convert_frame,
    find_device,
)
from threedcal.model.sources import MAX_MISSED_FRAMES, camera_frames, open_source
from threedcal.profiles import load_profile


class FakeCapture:
    """A frame generator behind cv2.VideoCapture's interface: frame k has every pixel = k (BGR)."""

    def __init__(self, shape=(240, 320), script=None, opened=True):
        self.shape, self.k, self.opened = shape, 0, opened
        self.script = dict(script or {})  # frame number -> "drop" | "black" | "slow"
        self.props, self.grabs = {}, 0
        self.clock = 0.0

    def isOpened(self):
        return self.opened

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def grab(self):
        self.k += 1
        self.grabs += 1
        return True

    def read(self):
        self.k += 1
        self.clock += 0.033
        what = self.script.get(self.k)
        if what == "drop":
            return False, None
        if what == "slow":
            self.clock += 10.0
        value = 0 if what == "black" else 100 + self.k % 100
        frame = np.full((*self.shape, 3), value, np.uint8)
        frame[..., 0] = 10  # blue channel in BGR
        return True, frame

    def release(self):
        self.opened = False


def camera(profile="gelsight_mini", **fake):
    src = FakeCapture(**fake)
    cam = OpenCVCamera(
        load_profile("sensor", profile), 0, source_factory=lambda d: src, clock=lambda: src.clock
    )
    return cam, src


def test_capture_flushes_then_returns_fresh_rgb_frames_with_time_stamps():
    cam, src = camera(shape=(480, 640))
    assert isinstance(cam, Camera)
    with cam:
        frames, stamps = cam.capture(3)
        assert src.grabs == cam.flush_frames  # the stale buffer was dropped first
        assert frames.shape == (3, 240, 320, 3) and frames.dtype == np.uint8
        assert (frames[..., 2] == 10).all()  # BGR blue became RGB blue (last channel)
        assert list(frames[:, 0, 0, 0]) == [100 + k for k in (5, 6, 7)]  # frames 1-4 flushed
        assert np.all(np.diff(stamps) > 0)
        frames2, _ = cam.capture(1)
        assert src.grabs == 2 * cam.flush_frames
    assert not src.opened
    assert src.props  # resolution, fps and exposure/white-balance locks were requested


@pytest.mark.parametrize(
    "fault, error", [("drop", DroppedFrame), ("black", BlackFrame), ("slow", CameraTimeout)]
)
def test_faults_become_clear_errors(fault, error):
    cam, _ = camera(script={6: fault})
    with cam, pytest.raises(error, match="camera"):
        cam.capture(3)
    assert issubclass(error, CameraError)


def test_unopened_camera_and_bad_modes_fail_clearly():
    cam, _ = camera(opened=False)
    with pytest.raises(CameraError, match="cannot open"):
        cam.open()
    with pytest.raises(CameraError, match="not open"):
        camera()[0].capture(1)
    with pytest.raises(ConfigError, match="fps"):
        OpenCVCamera(load_profile("sensor", "digit"), 0, mode="VGA", fps=60)
    with pytest.raises(ConfigError, match="mode"):
        OpenCVCamera(load_profile("sensor", "digit"), 0, mode="4K")


def test_digit_frames_are_rotated_and_flipped_to_portrait():
    profile = load_profile("sensor", "digit")
    bgr = np.zeros((240, 320, 3), np.uint8)
    bgr[0, 0] = (0, 0, 255)  # red pixel, top-left of the landscape native frame
    rgb = convert_frame(bgr, profile)
    assert rgb.shape == (320, 240, 3)
    # rotate 90 clockwise puts the top-left at the top-right; the horizontal flip brings it back left
    assert tuple(rgb[0, 0]) == (255, 0, 0)


def test_find_device_by_v4l_id_name(tmp_path):
    profile = load_profile("sensor", "digit")
    assert find_device(profile, tmp_path) is None
    (tmp_path / "usb-Facebook_DIGIT_D20001-video-index1").touch()
    (tmp_path / "usb-Facebook_DIGIT_D20001-video-index0").touch()
    assert find_device(profile, tmp_path).endswith("DIGIT_D20001-video-index0")


def test_a_real_video_file_plays_through_the_same_interface(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (640, 480))
    for k in range(12):
        writer.write(np.full((480, 640, 3), 60 + 10 * k, np.uint8))
    writer.release()
    cam = OpenCVCamera(load_profile("sensor", "gelsight_mini"), str(path))
    with cam:
        frames, stamps = cam.capture(2)
    assert frames.shape == (2, 240, 320, 3)
    assert abs(float(frames[0].mean()) - (60 + 10 * 4)) < 3  # frames 0-3 were flushed


def test_live_reads_a_camera_through_its_checks():
    """`threedcal live` on a camera: frames converted by the profile; a dropped or black frame
    passed over, ten in a row or one past the timeout end the stream with the camera's error."""
    cam, _ = camera(script={2: "drop", 4: "black"})
    frames = camera_frames(cam)
    first = [next(frames) for _ in range(3)]  # reads 1, 3 and 5: 2 and 4 passed over
    assert [int(f[0, 0, 0]) for f in first] == [101, 103, 105]  # RGB: BGR's red channel first
    assert first[0].shape == (240, 320, 3)
    frames.close()
    assert not cam._src  # the camera is released when the stream ends
    dropped = {k: "drop" for k in range(2, 2 + MAX_MISSED_FRAMES)}
    cam, _ = camera(script=dropped)
    frames = camera_frames(cam)
    next(frames)
    with pytest.raises(DroppedFrame, match=f"{MAX_MISSED_FRAMES} in a row: live stops"):
        next(frames)
    cam, _ = camera(script={2: "slow"})
    frames = camera_frames(cam)
    next(frames)
    with pytest.raises(CameraTimeout):
        next(frames)
    with pytest.raises(ConfigError, match="is a camera: give --sensor"):
        open_source("0")
