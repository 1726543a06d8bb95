"""Depth maps → metric 3D points in a stated frame, and the contact mask; PLY through trimesh.

Two frames (docs/how-to/deploy.md, with a figure):

- **sensor**: the gel's rest plane, origin under the model frame's centre pixel ((W - 1) / 2,
  (H - 1) / 2), x along image columns (right), y along image rows (down), z into the gel, mm.
  A point is the deformed gel surface: z = the undeformed gel's sag below its apex (a domed gel,
  the checkpoint's `dome`; 0 on a flat one) + the depth map.
- **printer**: the G-code axes (X right, Y toward the back, Z up, mm) of the probing printer: x, y
  through the inverse of the registration's printer → pixel affine, Z = the first-touch height of
  the gel's apex (`contact_z_mm`) − the sensor frame's z.

The registration maps printer mm to pixels of the rectified camera frame (before the dataset's
`downscale`, as `registration.json` holds it); a model pixel c is camera pixel (c + 0.5) f − 0.5 for
a downscale f (the pixel-centre convention the dataset's pooling uses).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from threedcal.dataset.labels import local_dome
from threedcal.errors import ConfigError
from threedcal.model import CONTACT_DEPTH_MM, POINT_FRAMES

FRAMES = POINT_FRAMES


class PointCloud(NamedTuple):
    """`points` (N, 3) float64 mm, one per model pixel in row-major order (so `points.reshape(H, W,
    3)` is the image grid); `contact` (N,) bool: pressed deeper than the contact threshold."""

    points: np.ndarray
    contact: np.ndarray


@dataclass(frozen=True)
class Registration:
    """Printer (X, Y) mm → rectified camera (column, row) px, and the Z of the gel apex's first touch."""

    affine_px_per_mm: np.ndarray  # (2, 3)
    contact_z_mm: float

    @classmethod
    def from_record(cls, record: Mapping[str, Any], where: str = "registration") -> Registration:
        """From registration.json (or the checkpoint's copy of it); errors name `where` and the key."""
        try:
            affine = np.asarray(record["affine_px_per_mm"], dtype=float)
            contact_z = float(record["contact_z_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(
                f"{where}: needs affine_px_per_mm (2 x 3) and contact_z_mm ({exc!r})"
            ) from None
        if affine.shape != (2, 3) or not np.all(np.isfinite(affine)):
            raise ConfigError(f"{where}: affine_px_per_mm must be a finite 2 x 3 matrix")
        if abs(np.linalg.det(affine[:, :2])) < 1e-9:
            raise ConfigError(f"{where}: affine_px_per_mm is singular (no inverse)")
        if not np.isfinite(contact_z):
            raise ConfigError(f"{where}: contact_z_mm must be finite, got {contact_z}")
        return cls(affine, contact_z)

    def record(self) -> dict:
        return {
            "affine_px_per_mm": self.affine_px_per_mm.tolist(),
            "contact_z_mm": self.contact_z_mm,
        }


@dataclass(frozen=True)
class SensorGeometry:
    """What turns a model's depth map into points: its frame, scale, gel dome and registration."""

    image_shape: tuple[int, int]  # the model's frame (H, W)
    px_per_mm: float  # of the model's frame
    dome: Mapping | None = None  # profile gel.dome (mm about the image centre); None: flat
    registration: Registration | None = None
    downscale: int = 1  # model pixels per rectified camera pixel, per axis

    def sensor_xy_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) x and y of every model pixel centre in the sensor frame."""
        height, width = self.image_shape
        x = (np.arange(width, dtype=np.float64) - (width - 1) / 2) / self.px_per_mm
        y = (np.arange(height, dtype=np.float64) - (height - 1) / 2) / self.px_per_mm
        return np.broadcast_to(x[None, :], self.image_shape), np.broadcast_to(
            y[:, None], self.image_shape
        )

    def sag_mm(self) -> np.ndarray:
        """(H, W) how far the undeformed gel lies below its apex at every pixel (0: flat gel)."""
        x, y = self.sensor_xy_mm()
        if not self.dome:
            return np.zeros(self.image_shape)
        apex_x, apex_y = (float(self.dome.get(k, 0.0)) for k in ("apex_x_mm", "apex_y_mm"))
        height, width = self.image_shape
        apex_px = (
            (width - 1) / 2 + apex_x * self.px_per_mm,
            (height - 1) / 2 + apex_y * self.px_per_mm,
        )
        about_apex = local_dome(self.dome, apex_px, self.image_shape, self.px_per_mm)
        return about_apex.sag_mm(x - apex_x, y - apex_y)

    def check_frame(self, frame_of: str) -> None:
        """A ConfigError when points cannot be given in `frame_of` (unknown; printer without a
        registration), saying what to pass instead."""
        if frame_of not in FRAMES:
            raise ConfigError(
                f"frame_of {frame_of!r} is not allowed (allowed: {', '.join(FRAMES)})"
            )
        if frame_of == "printer" and self.registration is None:
            raise ConfigError(
                "frame_of='printer' needs the registration (printer → pixel affine and the "
                "first-touch height): this checkpoint carries none (trained before threedcal "
                "recorded it, or on an imported dataset); pass the dataset's registration.json "
                "(DepthEstimator(registration=...), --registration), or use the sensor frame"
            )

    def points(self, depth_mm: np.ndarray, frame_of: str = "sensor") -> np.ndarray:
        """(H * W, 3) points of a depth map (H, W) mm in `frame_of` ('sensor' or 'printer')."""
        depth = np.asarray(depth_mm, dtype=np.float64)
        if depth.shape != tuple(self.image_shape):
            raise ConfigError(
                f"a depth map of {depth.shape}; this model's frame is {tuple(self.image_shape)}"
            )
        self.check_frame(frame_of)
        x, y = self.sensor_xy_mm()
        z = self.sag_mm() + depth
        if frame_of == "sensor":
            return np.stack([x, y, z], axis=-1).reshape(-1, 3)
        height, width = self.image_shape
        cols, rows = np.meshgrid(
            np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
        )
        f = float(self.downscale)
        camera = np.stack([(cols + 0.5) * f - 0.5, (rows + 0.5) * f - 0.5], axis=-1)
        affine = self.registration.affine_px_per_mm
        printer_xy = (camera - affine[:, 2]) @ np.linalg.inv(affine[:, :2]).T
        printer_z = self.registration.contact_z_mm - z
        return np.concatenate([printer_xy, printer_z[..., None]], axis=-1).reshape(-1, 3)


def contact_mask(depth_mm: np.ndarray, threshold_mm: float = CONTACT_DEPTH_MM) -> np.ndarray:
    """(N,) bool, row-major like `points`: pixels pressed deeper than `threshold_mm` (NaN: not)."""
    if not (np.isfinite(threshold_mm) and threshold_mm >= 0):
        raise ConfigError(f"the contact threshold must be a number >= 0 mm, got {threshold_mm}")
    depth = np.asarray(depth_mm, dtype=np.float64).reshape(-1)
    with np.errstate(invalid="ignore"):
        return depth > threshold_mm


# PLY colours: contact orange, the rest of the gel grey.
CONTACT_RGB = (255, 120, 0)
GEL_RGB = (160, 160, 160)


def write_ply(path: str | Path, cloud: PointCloud) -> None:
    """A binary PLY of every point (float32 x, y, z in mm), coloured by contact, through trimesh.

    Points that are not finite (a NaN depth) are left out. Written to a temporary name first, then
    renamed: a reader never sees half a file."""
    import trimesh  # local: only a PLY needs it; `predict` and `live` start 0.7 s sooner

    path = Path(path)
    finite = np.all(np.isfinite(cloud.points), axis=1)
    if not finite.any():
        raise ConfigError(f"{path}: no finite point to write (the depth map is NaN everywhere)")
    colours = np.where(cloud.contact[finite, None], CONTACT_RGB, GEL_RGB).astype(np.uint8)
    data = trimesh.PointCloud(cloud.points[finite], colors=colours).export(file_type="ply")
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_name(path.name + ".tmp")
    staging.write_bytes(data)
    staging.replace(path)
