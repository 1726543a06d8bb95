"""The camera's lens: radial distortion about the principal point, and the rectification it implies.

A tactile sensor's camera sits a few millimetres under the gel behind a wide-angle lens. The gel's
rest plane is imaged by a pinhole (a homography of the plane: with the camera axis normal to the gel,
a scale) and then bent by the lens's radial distortion. In pixel units, with d = p − c the ideal
(pinhole) position p relative to the principal point c:

    camera = c + d · (1 + κ₁ |d|² + κ₂ |d|⁴)

which is OpenCV's model with k₁ = κ₁ f², k₂ = κ₂ f⁴ for a focal length of f pixels: a calibrated
lens's k₁, k₂ can be written into a sensor profile as they are, and `RadialLens.opencv` gives the
camera matrix and distortion coefficients every other tool reads (cv2.undistortPoints,
cv2.initUndistortRectifyMap, a ROS camera_info). κ < 0 is barrel distortion (a wide-angle lens pulls
the field's edge inward). The rectification's maps are OpenCV's (`rectify_maps`).

Everything the library does after registration works in the *ideal* frame, where one millimetre
of the gel is the same number of pixels everywhere: the dataset stage fits the lens together with
the printer → pixel affine (threedcal.dataset.registration) and resamples every frame into the
ideal frame (`RadialLens.rectify`), so labels stay exact sphere geometry.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
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
        focal = profile_focal_px(sensor)
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

    @classmethod
    def from_opencv(cls, camera_matrix, dist_coeffs, shape: tuple[int, int] | None = None):
        """A camera matrix K (3 x 3, square pixels) and distortion coefficients (k1, k2[, p1, p2,
        k3]; tangential and higher terms must be 0: this lens is radial to fourth order)."""
        matrix = np.asarray(camera_matrix, dtype=float)
        coeffs = np.ravel(np.asarray(dist_coeffs, dtype=float))
        if matrix.shape != (3, 3) or not np.isclose(matrix[0, 0], matrix[1, 1]):
            raise ConfigError(f"camera matrix must be 3 x 3 with fx = fy, got {matrix.tolist()}")
        if coeffs.size < 2 or np.any(coeffs[2:] != 0):
            raise ConfigError(
                f"distortion coefficients must be k1, k2 (p1, p2, k3 zero), got {coeffs.tolist()}"
            )
        focal = float(matrix[0, 0])
        return cls(
            centre_px=(float(matrix[0, 2]), float(matrix[1, 2])),
            kappa1=float(coeffs[0]) / focal**2,
            kappa2=float(coeffs[1]) / focal**4,
            shape=shape,
        )

    def opencv(self, focal_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(camera matrix K, distortion coefficients k1, k2, p1, p2, k3) in OpenCV's convention.

        A registration fits the distortion in pixels and not the focal length f: any f describes
        the same lens (k₁ = κ₁ f², k₂ = κ₂ f⁴). `focal_px` (the profile's, from its lens.fov_deg)
        keeps k₁, k₂ in the profile's units; by default f is the frame's half-diagonal."""
        if focal_px is None:
            if self.shape is None:
                raise ConfigError("the lens has no frame shape: give focal_px")
            height, width = self.shape
            focal_px = math.hypot(width - 1, height - 1) / 2
        f = float(focal_px)
        matrix = np.array([[f, 0.0, self.centre_px[0]], [0.0, f, self.centre_px[1]], [0, 0, 1.0]])
        coeffs = np.array([self.kappa1 * f**2, self.kappa2 * f**4, 0.0, 0.0, 0.0])
        return matrix, coeffs

    def camera_info(self, focal_px: float | None = None) -> dict:
        """The lens as a ROS sensor_msgs/CameraInfo's fields (plumb_bob), JSON-ready: what a
        user hands to ROS, or to OpenCV as np.array(camera_matrix) and distortion_coefficients.
        The camera sees the ideal frame through it (rectification and projection: K again)."""
        if self.shape is None:
            raise ConfigError("the lens has no frame shape: camera_info needs the image size")
        matrix, coeffs = self.opencv(focal_px)
        projection = np.column_stack([matrix, np.zeros(3)])
        return {
            "image_width": int(self.shape[1]),
            "image_height": int(self.shape[0]),
            "distortion_model": "plumb_bob",
            "camera_matrix": matrix.round(9).tolist(),
            "distortion_coefficients": coeffs.round(12).tolist(),
            "rectification_matrix": np.eye(3).tolist(),
            "projection_matrix": projection.round(9).tolist(),
        }

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
        was imaged at (float32 column and row): cv2.initUndistortRectifyMap's, with the ideal
        frame's camera matrix that of the camera itself."""
        height, width = shape
        matrix, coeffs = self.opencv(math.hypot(width - 1, height - 1) / 2)
        return cv2.initUndistortRectifyMap(
            matrix, coeffs, None, matrix, (int(width), int(height)), cv2.CV_32FC1
        )

    def rectify(self, images: np.ndarray) -> np.ndarray:
        """Camera frames (H, W[, C]) or (N, H, W, C) → the ideal frame, bilinear, same dtype.

        Ideal pixels the camera did not see (beyond its frame: a pincushion lens's corners) repeat
        the nearest edge pixel."""
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


def profile_focal_px(sensor: Mapping) -> float | None:
    """The focal length (px) the profile's lens block implies: the field of view across the rows."""
    block = sensor.get("lens")
    if not block:
        return None
    fov = float(block["fov_deg"])
    if not 0 < fov < 180:
        raise ConfigError(
            f"sensor profile {sensor.get('name')!r}: lens.fov_deg must lie in (0, 180), got {fov}"
        )
    return (int(sensor["image"]["height_px"]) / 2) / math.tan(math.radians(fov) / 2)


def rectify_if(lens: RadialLens | None, images: np.ndarray) -> np.ndarray:
    """`lens.rectify(images)`, or `images` unchanged when there is no lens."""
    return images if lens is None else lens.rectify(images)
