"""DepthEstimator: a checkpoint → gradients, depth (mm) and 3D points of sensor frames, batched,
CPU or GPU.

`gradients` and `depth` read frames as the model was trained on them: rectified through the
camera's lens when the dataset stage fitted one. A camera's own frames go through `rectify` first
(`threedcal predict` and `live` do that). `points` places a frame's depth in the sensor's or
the printer's frame (threedcal.model.points)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from threadpoolctl import ThreadpoolController

from threedcal.dataset.trainset import pool_to
from threedcal.depth import integrate
from threedcal.errors import ConfigError
from threedcal.lens import RadialLens, rectify_if
from threedcal.model.allocator import reuse_freed_memory
from threedcal.model.checkpoint import adapt_inputs, model_from_checkpoint, read_checkpoint
from threedcal.model.drift import drift_offset, remove_drift
from threedcal.model.machine import torch_device
from threedcal.model.points import (
    CONTACT_DEPTH_MM,
    PointCloud,
    Registration,
    SensorGeometry,
    contact_mask,
)
from threedcal.model.presets import preferred_memory_format, reach_px

_blas_controller = None


def _one_blas_thread():
    """A context in which NumPy's and SciPy's BLAS run on the calling thread alone.

    `depth` integrates on the CPU right after the network ran there, and BLAS's own worker threads
    (the DST's matrix products) then compete with torch's for the same cores: on 2 cores that
    doubled the time of a 240 x 320 depth frame (docs/explanation/models.md)."""
    global _blas_controller
    if _blas_controller is None:
        _blas_controller = ThreadpoolController()  # after NumPy and SciPy have loaded their BLAS
    return _blas_controller.limit(limits=1, user_api="blas")


class DepthEstimator:
    """Frames (H, W, 3) uint8 RGB, or (N, H, W, 3) → gradients (…, H, W, 2) and depth (…, H, W) mm."""

    def __init__(
        self,
        checkpoint: Mapping[str, Any],
        device: str | torch.device | None = None,
        blank: np.ndarray | None = None,
        px_per_mm: float | None = None,
        batch_size: int = 8,
        channels_last: bool = True,
        camera_blank: bool = False,
        registration: str | Path | Mapping[str, Any] | None = None,
    ) -> None:
        """`camera_blank`: `blank` is a frame as the camera streams it, to be rectified and pooled
        like the frames (`rectify`); by default it is already the model's input. `registration`:
        registration.json (path or record) for `points(frame_of="printer")`, in place of the
        checkpoint's own (checkpoints trained before it was recorded carry none)."""
        self.device = torch_device(device, "device")
        reuse_freed_memory()
        self.preset = checkpoint["preset"]
        self.normalisation = dict(checkpoint["normalisation"])
        self.drift = self.normalisation.get("drift", "none")  # checkpoints before the drift step
        if blank is None and checkpoint.get("blank") is None:
            raise ConfigError(
                "this checkpoint carries no blank frame (the authors' weights, the shipped "
                "pretrained ones): pass blank="
            )
        camera = checkpoint.get("camera") or {}
        self.lens = RadialLens.from_record(camera.get("lens"))
        if blank is not None and camera_blank:
            blank = rectify_if(self.lens, np.asarray(blank, np.float32))
            shape = checkpoint.get("image_shape")
            if not shape and checkpoint.get("blank") is not None:
                shape = np.shape(checkpoint["blank"])[:2]
            if not shape:  # the model's frame: the camera's, pooled by the dataset's downscale
                factor = int(camera.get("downscale", 1))
                shape = (blank.shape[0] // factor, blank.shape[1] // factor)
            blank = pool_to(blank, tuple(shape))
        blank = np.asarray(checkpoint["blank"] if blank is None else blank, dtype=np.float32)
        self.px_per_mm = float(px_per_mm or checkpoint.get("px_per_mm") or 0)
        if self.px_per_mm <= 0:
            raise ConfigError("this checkpoint carries no px_per_mm: pass px_per_mm=")
        self.image_shape = tuple(blank.shape[:2])
        if checkpoint.get("image_shape") and tuple(checkpoint["image_shape"]) != self.image_shape:
            raise ConfigError(
                f"blank is {self.image_shape}, the model was trained on {tuple(checkpoint['image_shape'])}"
            )
        self.batch_size = batch_size
        self.model = model_from_checkpoint(checkpoint).to(self.device).eval()
        self.memory_format = (
            preferred_memory_format(self.model) if channels_last else torch.contiguous_format
        )
        self.model = self.model.to(memory_format=self.memory_format)
        height, width = self.image_shape
        ys = torch.linspace(-1.0, 1.0, height) if height > 1 else torch.zeros(1)
        xs = torch.linspace(-1.0, 1.0, width) if width > 1 else torch.zeros(1)
        grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")
        self._coords = torch.stack([grid_x, grid_y]).to(self.device)
        self._blank = torch.from_numpy(blank).permute(2, 0, 1).to(self.device)
        self._reach = reach_px(self.model)
        self.geometry = SensorGeometry(
            image_shape=self.image_shape,
            px_per_mm=self.px_per_mm,
            dome=checkpoint.get("dome"),
            registration=_registration(registration, checkpoint.get("registration")),
            downscale=int(camera.get("downscale", 1)),
        )

    @property
    def blank(self) -> np.ndarray:
        """The blank (no-contact) frame the model compares every frame with, (H, W, 3) float32."""
        return self._blank.permute(1, 2, 0).cpu().numpy()

    def retake_blank(self, frame: np.ndarray) -> None:
        """Compare later frames with `frame`, a no-contact frame as the camera streams it
        (rectified and pooled like the frames): after the gel or the lighting drifted."""
        blank = self.rectify(np.asarray(frame)).astype(np.float32)
        if blank.shape != (*self.image_shape, 3):
            raise ConfigError(f"a blank must be one (H, W, 3) frame, got {np.shape(frame)}")
        self._blank = torch.from_numpy(blank).permute(2, 0, 1).to(self.device)

    def describe_runtime(self) -> str:
        """How this machine runs the model: device, threads, memory layout, arithmetic."""
        layout = "channels-last" if self.memory_format == torch.channels_last else "NCHW"
        threads = f"{torch.get_num_threads()} threads, " if self.device.type == "cpu" else ""
        return f"{self.device.type}, {threads}{layout}, float32"

    def rectify(self, frames: np.ndarray) -> np.ndarray:
        """Camera frames (H, W, 3) or (N, H, W, 3), as the sensor streams them → this model's input:
        resampled through the lens the dataset stage fitted (threedcal.lens) and pooled to the
        model's frame. Without a lens and at the model's size, the frames come back unchanged."""
        frames = np.asarray(frames)
        rectified = rectify_if(self.lens, frames)
        if rectified.shape[-3:-1] == self.image_shape:
            return rectified
        if rectified.ndim == 3:
            return pool_to(rectified, self.image_shape)
        return np.stack([pool_to(f, self.image_shape) for f in rectified])

    @classmethod
    def from_checkpoint(cls, path: str | Path, **kwargs) -> DepthEstimator:
        """Load a threedcal model.pt (or the authors' TouchNet weights, with blank= and px_per_mm=)."""
        return cls(read_checkpoint(path), **kwargs)

    def _as_batch(self, frames: np.ndarray) -> tuple[np.ndarray, bool]:
        frames = np.asarray(frames)
        single = frames.ndim == 3
        if single:
            frames = frames[None]
        if frames.ndim != 4 or frames.shape[1:] != (*self.image_shape, 3):
            raise ConfigError(
                f"frames must be (H, W, 3) or (N, H, W, 3) with (H, W) = {self.image_shape}, "
                f"got {frames.shape}"
            )
        return frames, single

    @torch.inference_mode()
    def gradients(self, frames: np.ndarray) -> np.ndarray:
        """(…, H, W, 2) float32: ∂z/∂x (columns) and ∂z/∂y (rows), z positive into the gel."""
        frames, single = self._as_batch(frames)
        out = []
        sign = self.normalisation["gradient_sign"]
        for start in range(0, len(frames), self.batch_size):
            chunk = torch.from_numpy(np.array(frames[start : start + self.batch_size]))
            chunk = chunk.to(self.device).permute(0, 3, 1, 2).float()
            diff = remove_drift((chunk - self._blank) / 255.0, self.drift)
            coords = self._coords.expand(len(chunk), -1, -1, -1)
            x = adapt_inputs(torch.cat([diff, coords], 1), self.normalisation, self.image_shape)
            x = x.contiguous(memory_format=self.memory_format)
            out.append((self.model(x) * sign).permute(0, 2, 3, 1).float().cpu().numpy())
        grads = np.concatenate(out)
        return grads[0] if single else grads

    @torch.inference_mode()
    def gradients_in(self, frame: np.ndarray, window: tuple[slice, slice]) -> np.ndarray:
        """gradients(frame)[window] (h, w, 2), computed on the window plus the network's reach only.

        The lighting drift is still estimated on the whole frame. Equal to the full-frame result up
        to float rounding; a network whose output is not a window of its input (`multiscale`) runs
        on the whole frame. Scoring small discs of many frames costs a fraction of whole frames."""
        frame, _ = self._as_batch(frame)
        if frame.shape[0] != 1:
            raise ConfigError(f"gradients_in takes one frame (H, W, 3), got {frame.shape[1:]}")
        rows, cols = (range(*w.indices(n)) for w, n in zip(window, self.image_shape, strict=True))
        if (
            self._reach is None
            or not len(rows)
            or not len(cols)
            or rows.step != 1
            or cols.step != 1
        ):
            return self.gradients(frame[0])[window]
        height, width = self.image_shape
        top, left = max(rows.start - self._reach, 0), max(cols.start - self._reach, 0)
        bottom = min(rows.stop + self._reach, height)
        right = min(cols.stop + self._reach, width)
        image = torch.from_numpy(np.array(frame)).to(self.device).permute(0, 3, 1, 2).float()
        diff = (image - self._blank) / 255.0
        offset = drift_offset(diff) if self.drift == "median" else None
        crop = (slice(None), slice(None), slice(top, bottom), slice(left, right))
        coords = self._coords[None][crop]
        x = torch.cat([remove_drift(diff[crop], self.drift, offset), coords], 1)
        x = adapt_inputs(x, self.normalisation, self.image_shape)
        x = x.contiguous(memory_format=self.memory_format)
        out = (self.model(x) * self.normalisation["gradient_sign"]).permute(0, 2, 3, 1)[0]
        inner = (
            slice(rows.start - top, rows.stop - top),
            slice(cols.start - left, cols.stop - left),
        )
        return out[inner].float().cpu().numpy()

    def depth(self, frames: np.ndarray, method: str = "poisson_dst") -> np.ndarray:
        """(…, H, W) float32 depth in mm (positive into the gel), integrated per frame."""
        grads = self.gradients(frames)
        single = grads.ndim == 3
        grads = grads[None] if single else grads
        with _one_blas_thread() if self.device.type == "cpu" else contextlib.nullcontext():
            depth = np.stack(
                [
                    integrate(g[..., 0], g[..., 1], method=method, px_per_mm=self.px_per_mm)
                    for g in grads
                ]
            ).astype(np.float32)
        return depth[0] if single else depth

    def points(
        self,
        frame: np.ndarray,
        frame_of: str = "sensor",
        contact_mm: float = CONTACT_DEPTH_MM,
    ) -> PointCloud:
        """One model frame (H, W, 3) → PointCloud: (H * W, 3) points in mm in `frame_of`
        ('sensor': the gel's rest plane, x right, y down the image, z into the gel; 'printer': the
        G-code axes at the first-touch height) and the contact mask (depth > `contact_mm`)."""
        frame = np.asarray(frame)
        if frame.ndim != 3:
            raise ConfigError(f"points takes one frame (H, W, 3), got {frame.shape}")
        return self.points_of_depth(self.depth(frame), frame_of, contact_mm)

    def points_of_depth(
        self, depth_mm: np.ndarray, frame_of: str = "sensor", contact_mm: float = CONTACT_DEPTH_MM
    ) -> PointCloud:
        """`points` of a depth map (H, W) mm of this model's frame (e.g. from `depth`)."""
        mask = contact_mask(depth_mm, contact_mm)
        return PointCloud(self.geometry.points(depth_mm, frame_of), mask)


def _registration(given, recorded) -> Registration | None:
    """The registration `points` uses: the one given (a registration.json path or its record),
    else the checkpoint's; None when neither exists."""
    if given is None:
        return None if recorded is None else Registration.from_record(recorded, "checkpoint")
    if isinstance(given, Mapping):
        return Registration.from_record(given)

    path = Path(given)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot read the registration ({exc})") from None
    if not isinstance(record, Mapping):
        raise ConfigError(f"{path}: a registration is a JSON object, got {type(record).__name__}")
    return Registration.from_record(record, str(path))
