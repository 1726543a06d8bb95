"""Frame sources for `threedcal live`: a camera, a folder of images, or a model-ready dataset.

Each is an iterator of RGB uint8 frames (H, W, 3). The simulated bench becomes one more source when
it lands.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from threedcal.errors import ConfigError

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp"}


def folder_frames(path: Path) -> Iterator[np.ndarray]:
    from threedcal.dataset.importers import read_rgb

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


def camera_frames(index: int | str) -> Iterator[np.ndarray]:
    import cv2

    capture = cv2.VideoCapture(index)
    if not capture.isOpened():
        raise ConfigError(f"camera {index!r}: cannot open (OpenCV device index or path)")
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()


def open_source(spec: str) -> Iterator[np.ndarray]:
    """`spec`: a camera index (0), a folder of images, or a results/{scene}/dataset/trainset folder."""
    if spec.isdigit():
        return camera_frames(int(spec))
    path = Path(spec)
    if path.is_dir() and (path / "frames.npy").is_file():
        return trainset_frames(path)
    if path.is_dir():
        return folder_frames(path)
    if path.exists():  # a video file
        return camera_frames(str(path))
    raise ConfigError(f"live source {spec!r}: not a camera index, folder or video file")
