"""The camera's lens: radial distortion about the principal point, and the rectification it implies.

A tactile sensor's camera sits a few millimetres under the gel behind a wide-angle lens. The gel's
rest plane is imaged by a pinhole (a homography of the plane: with the camera axis normal to the gel,
a scale) and then bent by the lens's radial distortion. In pixel units, with d = p − c the ideal
(pinhole) position p relative to the principal point c:

    camera = c + d · (1 + κ₁ |d|² + κ₂ |d|⁴)

which is OpenCV's model with k₁ = κ₁ f², k₂ = κ₂ f⁴ for a focal length of f pixels: a calibrated
lens's k₁, k₂ can be written into a sensor profile as they are. κ < 0 is barrel distortion (a
wide-angle lens pulls the field's edge inward).

Everything the library does after registration works in the *ideal* frame, where one millimetre
of the gel is the same number of pixels everywhere: the dataset stage fits the lens together with
the printer → pixel affine (threedcal.dataset.registration) and resamples every frame into the
ideal frame (`RadialLens.rectify`), so labels stay exact sphere geometry.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from threedcal.errors import ConfigError


@dataclass(frozen=True)
class RadialLens:
    """Radial distortion κ₁, κ₂ (px⁻², px⁻⁴) about `centre_px` (column, row) of a frame `shape` (H, W)."""

    centre_px: tuple[float, float]
    kappa1: float
    kappa2: float = 0.0
    shape: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        values = (*self.centre_px, self.kappa1, self.kappa2)
        if not all(math.isfinite(float(v)) for v in values):
            raise ConfigError(f"lens parameters must be finite, got {values}")

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_profile(cls, sensor: Mapping) -> RadialLens | None:
        """The profile's `lens` block (None: an ideal camera). The focal length comes from the field
        of view across the image's rows, so k₁, k₂ are in OpenCV's normalised units."""
        block = sensor.get("lens")
        if not block:
            return None
        height = int(sensor["image"]["height_px"])
        width = int(sensor["image"]["width_px"])
        fov = float(block["fov_deg"])
        if not 0 < fov < 180:
            raise ConfigError(
                f"sensor profile {sensor.get('name')!r}: lens.fov_deg must lie in (0, 180), got {fov}"
            )
        focal = (height / 2) / math.tan(math.radians(fov) / 2)
        return cls(
            centre_px=((width - 1) / 2, (height - 1) / 2),
            kappa1=float(block.get("k1", 0.0)) / focal**2,
            kappa2=float(block.get("k2", 0.0)) / focal**4,
            shape=(height, width),
        )

    @classmethod
    def from_record(cls, record: Mapping | None) -> RadialLens | None:
        """Inverse of `record` (None or an empty record: no lens)."""
        if not record:
            return None
        try:
            shape = record.get("shape")
            centre = tuple(float(v) for v in record["centre_px"])
            if len(centre) != 2 or (shape is not None and len(shape) != 2):
                raise ValueError("centre_px and shape take two numbers each")
            return cls(
                centre_px=centre,
                kappa1=float(record["kappa1_per_px2"]),
                kappa2=float(record.get("kappa2_per_px4", 0.0)),
                shape=None if shape is None else tuple(int(v) for v in shape),
            )
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"lens record {record!r} is malformed ({exc})") from exc

    def record(self) -> dict:
        """JSON-ready parameters (registration.json, the trainset's meta, a checkpoint)."""
        return {
            "centre_px": [float(v) for v in self.centre_px],
            "kappa1_per_px2": float(self.kappa1),
            "kappa2_per_px4": float(self.kappa2),
            "shape": None if self.shape is None else [int(v) for v in self.shape],
        }

    # ----------------------------------------------------------------- mappings
    def _factor(self, r2):
        return 1.0 + self.kappa1 * r2 + self.kappa2 * r2 * r2

    def distort(self, xy) -> np.ndarray:
        """Ideal positions (..., 2) px → where the camera images them."""
        xy = np.asarray(xy, dtype=float)
        c = np.asarray(self.centre_px, dtype=float)
        d = xy - c
        r2 = (d * d).sum(axis=-1, keepdims=True)
        return c + d * self._factor(r2)

    def undistort(self, xy, iterations: int = 30) -> np.ndarray:
        """Camera positions (..., 2) px → ideal ones: the radius solved by Newton's method.

        The radial map r ↦ r (1 + κ₁r² + κ₂r⁴) is inverted along each ray; it must be increasing
        over the radii asked for (`ConfigError` otherwise: the lens folds the image there)."""
        xy = np.asarray(xy, dtype=float)
        c = np.asarray(self.centre_px, dtype=float)
        d = xy - c
        rc = np.sqrt((d * d).sum(axis=-1))
        r = rc.copy()
        for _ in range(iterations):
            r2 = r * r
            f = r * self._factor(r2) - rc
            slope = 1.0 + 3 * self.kappa1 * r2 + 5 * self.kappa2 * r2 * r2
            if np.any(slope <= 0):
                raise ConfigError(
                    f"the lens (kappa1 {self.kappa1:.3g}, kappa2 {self.kappa2:.3g}) folds the image "
                    f"within {float(rc.max()):.0f} px of its centre: no unique undistortion"
                )
            step = f / slope
            r = r - step
            if float(np.max(np.abs(step), initial=0.0)) < 1e-10:
                break
        scale = np.where(rc > 0, r / np.where(rc > 0, rc, 1.0), 1.0)
        return c + d * scale[..., None]

    def max_shift_px(self, shape: tuple[int, int]) -> float:
        """Largest displacement between ideal and camera positions over a frame `shape` (H, W)."""
        height, width = shape
        corners = np.array(
            [[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], float
        )
        return float(np.abs(self.distort(corners) - corners).max())

    # ----------------------------------------------------------------- images
    def rectify_maps(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap tables: for each ideal pixel of a frame `shape` (H, W), the camera pixel it
        was imaged at (float32 column and row)."""
        height, width = shape
        cols, rows = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        camera = self.distort(np.stack([cols, rows], axis=-1))
        return camera[..., 0].astype(np.float32), camera[..., 1].astype(np.float32)

    def rectify(self, images: np.ndarray) -> np.ndarray:
        """Camera frames (H, W[, C]) or (N, H, W, C) → the ideal frame, bilinear, same dtype.

        Ideal pixels the camera did not see (beyond its frame: a pincushion lens's corners) repeat
        the nearest edge pixel."""
        import cv2

        images = np.asarray(images)
        if images.ndim not in (2, 3, 4) or images.size == 0:
            raise ConfigError(
                f"rectify takes a frame (H, W) or (H, W, C), or frames (N, H, W, C); got {images.shape}"
            )
        batched = images.ndim == 4
        stack = images if batched else images[None]
        shape = stack.shape[1:3]
        if self.shape is not None and tuple(shape) != tuple(self.shape):
            raise ConfigError(
                f"frames are {tuple(shape)} (H, W) but the lens was fitted on {tuple(self.shape)} frames"
            )
        map_x, map_y = self.rectify_maps(shape)
        dtype = stack.dtype
        work = stack if dtype in (np.uint8, np.float32) else stack.astype(np.float32)
        out = np.empty(work.shape, work.dtype)  # filled frame by frame: one copy of the batch
        for image, target in zip(work, out, strict=True):
            remapped = cv2.remap(
                np.ascontiguousarray(image),
                map_x,
                map_y,
                interpolation=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            target[...] = remapped.reshape(target.shape)  # cv2 drops a channel axis of length 1
        if out.dtype != dtype:  # other integer types: rounded back, not truncated
            out = np.rint(out) if np.issubdtype(dtype, np.integer) else out
            out = out.astype(dtype)
        return out if batched else out[0]


def rectify_if(lens: RadialLens | None, images: np.ndarray) -> np.ndarray:
    """`lens.rectify(images)`, or `images` unchanged when there is no lens."""
    return images if lens is None else lens.rectify(images)
