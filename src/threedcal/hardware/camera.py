"""Sensor cameras: a small `Camera` interface and its OpenCV implementation for DIGIT / GelSight Mini.

OpenCV buffers several frames inside the driver, so a frame read right after the printer stops may
show the gel *before* it stopped; `capture` therefore flushes the buffer first. Every frame is time-
stamped (monotonic seconds) and converted once, here, to the library's RGB frame (crop, rotate,
flip, resize per the sensor profile). A failed read, an all-black frame or a read that takes longer
than the profile's timeout raises a `CameraError` subclass instead of returning a bad frame.
The simulated bench implements the same `Camera` interface.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from threedcal.errors import ConfigError, ThreedcalError


class CameraError(ThreedcalError):
    """A camera fault at run time."""


class DroppedFrame(CameraError):
    pass


class BlackFrame(CameraError):
    pass


class CameraTimeout(CameraError):
    pass


class Camera(ABC):
    """open → (flush, capture)* → close. Frames are uint8 RGB (n, H, W, 3), times monotonic seconds."""

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def flush(self) -> None:
        """Drop frames buffered before now, so the next capture shows the present."""

    @abstractmethod
    def capture(self, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Flush, then return n fresh frames (n, H, W, 3) and their time stamps (n,)."""

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> Camera:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class VideoCaptureLike(Protocol):
    """What we use of cv2.VideoCapture (a fake implements the same for tests)."""

    def isOpened(self) -> bool: ...
    def read(self) -> tuple[bool, np.ndarray | None]: ...
    def grab(self) -> bool: ...
    def set(self, prop: int, value: float) -> bool: ...
    def release(self) -> None: ...


def find_device(profile: Mapping[str, Any], by_id: str | Path = "/dev/v4l/by-id") -> str | None:
    """The /dev/v4l/by-id path whose name contains the profile's camera.device_name (Linux), or None."""
    name = profile.get("camera", {}).get("device_name")
    root = Path(by_id)
    if not name or not root.is_dir():
        return None
    key = name.replace(" ", "_").lower()
    hits = sorted(p for p in root.iterdir() if key in p.name.lower() and p.name.endswith("index0"))
    return str(hits[0]) if hits else None


def convert_frame(bgr: np.ndarray, profile: Mapping[str, Any]) -> np.ndarray:
    """Native camera frame → the library's RGB frame, by the profile's crop/rotate/flip/resize rules."""
    cam, image = profile["camera"], profile["image"]
    frame = bgr
    if cam.get("native_channel_order", "BGR") == "BGR":
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    fx, fy = cam.get("crop_fraction", [0.0, 0.0])
    h, w = frame.shape[:2]
    bx, by = int(w * fx), int(h * fy)
    frame = frame[by + cam.get("crop_extra_top_px", 0) : h - by, bx : w - bx]
    rot = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}
    if cam.get("rotate_deg", 0):
        frame = cv2.rotate(frame, rot[cam["rotate_deg"]])
    flip = {"horizontal": 1, "vertical": 0, "both": -1}.get(cam.get("flip", "none"))
    if flip is not None:
        frame = cv2.flip(frame, flip)
    size = (image["width_px"], image["height_px"])
    if (frame.shape[1], frame.shape[0]) != size:
        frame = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(frame)


class OpenCVCamera(Camera):
    """A DIGIT or GelSight Mini through OpenCV; `device` is an index, a path, or None (discover)."""

    def __init__(
        self,
        profile: Mapping[str, Any],
        device: int | str | None = None,
        *,
        mode: str | None = None,
        fps: float | None = None,
        source_factory: Callable[[int | str], VideoCaptureLike] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        cam = profile.get("camera")
        if profile.get("type") != "vision" or not cam:
            raise ConfigError(f"sensor profile {profile.get('name')!r} has no camera block")
        self.profile = profile
        modes = {m["name"]: m for m in cam["modes"]}
        mode = mode or cam.get("default_mode") or cam["modes"][0]["name"]
        if mode not in modes:
            raise ConfigError(
                f"camera mode {mode!r} not in profile {profile['name']!r} (modes: {', '.join(modes)})"
            )
        self.mode = modes[mode]
        self.fps = float(fps or cam.get("default_fps") or self.mode["fps"][0])
        if self.fps not in [float(f) for f in self.mode["fps"]]:
            raise ConfigError(
                f"{self.fps} fps not offered in mode {mode!r} (fps: {self.mode['fps']})"
            )
        self.device = device
        self.flush_frames = int(cam.get("flush_frames", 4))
        self.black_level = float(cam.get("black_level_dn", 8))
        self.timeout_s = float(cam.get("timeout_s", 2.0))
        self._factory = source_factory
        self._clock = clock
        self._src: VideoCaptureLike | None = None
        self.locked: dict[str, bool] = {}

    def open(self) -> None:
        device = self.device
        if device is None:
            device = find_device(self.profile)
            if device is None:
                raise CameraError(
                    f"no {self.profile['camera'].get('device_name', 'camera')} under /dev/v4l/by-id; "
                    "give the device index or path"
                )
        src = self._factory(device) if self._factory else cv2.VideoCapture(device)
        if not src.isOpened():
            raise CameraError(f"cannot open camera {device!r}")
        src.set(cv2.CAP_PROP_FRAME_WIDTH, self.mode["width_px"])
        src.set(cv2.CAP_PROP_FRAME_HEIGHT, self.mode["height_px"])
        src.set(cv2.CAP_PROP_FPS, self.fps)
        # Lock exposure and white balance where the backend allows (V4L2: 1 = manual exposure).
        self.locked = {
            "exposure": bool(src.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)),
            "white_balance": bool(src.set(cv2.CAP_PROP_AUTO_WB, 0)),
        }
        self._src = src

    def _source(self) -> VideoCaptureLike:
        if self._src is None:
            raise CameraError("camera is not open (call open() first)")
        return self._src

    def flush(self) -> None:
        src = self._source()
        for _ in range(self.flush_frames):
            src.grab()

    def read_one(self) -> tuple[np.ndarray, float]:
        src = self._source()
        start = self._clock()
        ok, frame = src.read()
        stamp = self._clock()
        if stamp - start > self.timeout_s:
            raise CameraTimeout(f"camera {self.device!r}: no frame within {self.timeout_s} s")
        if not ok or frame is None or frame.size == 0:
            raise DroppedFrame(f"camera {self.device!r}: frame dropped (read failed)")
        if float(frame.mean()) < self.black_level:
            raise BlackFrame(
                f"camera {self.device!r}: black frame (mean {frame.mean():.1f} DN < {self.black_level}); "
                "LEDs off or cable loose?"
            )
        return convert_frame(frame, self.profile), stamp

    def capture(self, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
        if n < 1:
            raise ValueError(f"capture needs n >= 1, got {n}")
        self.flush()
        frames, stamps = zip(*(self.read_one() for _ in range(n)), strict=True)
        return np.stack(frames), np.asarray(stamps, dtype=np.float64)

    def close(self) -> None:
        if self._src is not None:
            self._src.release()
            self._src = None
