"""Frame sources for `threedcal live`: the sensor's camera, a video file, a folder of images, or a
model-ready dataset.

Each is an iterator of RGB uint8 frames (H, W, 3). The camera is opened as collection opens it
(threedcal.rig.open_camera): converted by its sensor profile (crop, rotation, size) and checked
frame by frame; a dropped or black frame is passed over with a warning, and a camera that stops
giving frames, or takes longer than the profile's timeout, ends the stream with an error.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from pathlib import Path

import cv2
import numpy as np

from threedcal.errors import ConfigError
from threedcal.hardware.camera import BlackFrame, DroppedFrame
from threedcal.images import read_rgb
from threedcal.rig import open_camera

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp"}
# A live camera may drop a frame now and then; this many in a row and the stream stops.
MAX_MISSED_FRAMES = 10


def folder_frames(path: Path) -> Iterator[np.ndarray]:
    names = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise ConfigError(f"{path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
    for name in names:
        yield read_rgb(name)


def trainset_frames(path: Path) -> Iterator[np.ndarray]:
    """The frames of a model-ready dataset, read as they are stored (frames.npy: NumPy alone, so
    the inference core reads them without the workflow's pandas)."""
    frames = np.load(path / "frames.npy", mmap_mode="r")
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ConfigError(
            f"{path / 'frames.npy'}: not a dataset's frames ((N, H, W, 3) uint8, got "
            f"{frames.shape} {frames.dtype})"
        )
    for frame in frames:
        yield np.asarray(frame)


def video_frames(path: Path) -> Iterator[np.ndarray]:
    """A video file's frames as recorded, RGB; its end ends the stream."""
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise ConfigError(f"{path}: OpenCV cannot read it as a video")
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()


def camera_frames(camera) -> Iterator[np.ndarray]:
    """Frames of an (unopened) `threedcal.hardware.camera.Camera` until it fails for good:
    `MAX_MISSED_FRAMES` dropped or black frames in a row, or one read past its timeout."""
    with camera:
        missed = 0
        while True:
            try:
                frame, _ = camera.read_one()
            except (DroppedFrame, BlackFrame) as exc:
                missed += 1
                if missed >= MAX_MISSED_FRAMES:
                    raise type(exc)(f"{exc} ({missed} in a row: live stops)") from None
                logging.getLogger("threedcal").warning("live: %s; passed over", exc)
                continue
            missed = 0
            yield frame


def is_camera(spec: str) -> bool:
    """A camera index (0) or a device (/dev/video0, /dev/v4l/by-id/...), not a file or folder."""
    return spec.isdigit() or (spec.startswith("/dev/") and not Path(spec).is_dir())


def open_source(spec: str, sensor: Mapping | None = None) -> Iterator[np.ndarray]:
    """`spec`: a camera (index such as 0, or a /dev/video device: `sensor`, its profile, is then
    needed), a video file, a folder of images, or a results/{scene}/dataset/trainset folder."""
    path = Path(spec)
    if path.is_dir() and (path / "frames.npy").is_file():
        return trainset_frames(path)
    if path.is_dir():
        return folder_frames(path)
    if is_camera(spec):
        if sensor is None:
            raise ConfigError(
                f"live source {spec!r} is a camera: give --sensor (the sensor profile says how "
                "its frames are cropped, turned and sized, as at collection)"
            )

        return camera_frames(open_camera(sensor, spec))
    if path.is_file():
        return video_frames(path)
    raise ConfigError(f"live source {spec!r}: not a camera index or device, folder or video file")
