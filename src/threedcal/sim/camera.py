"""The simulated sensor's camera: the gel's ideal image seen through the profile's lens.

`GelSimulator` renders the gel as an ideal camera would: one millimetre of the rest plane is
`px_per_mm` pixels everywhere. A real sensor's camera looks through a wide-angle lens a few
millimetres under the gel: the field's edge is pulled inward (radial distortion) and darkened
(vignetting). `LensedGel` renders the ideal image on a canvas wide enough for every camera pixel,
resamples it through the lens (threedcal.lens.RadialLens, the same model the dataset stage fits),
darkens it by the lens's relative illumination, and only then adds the camera's noise.

Poses stay in ideal-frame pixels (what the bench's printer → pixel affine gives): the lens decides
where the camera images them. Not modelled: the parallax of the pressed surface (a point pushed
toward the camera is imaged as though it lay on the rest plane).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from threedcal.errors import ConfigError
from threedcal.lens import RadialLens
from threedcal.sim.optics import GelSimulator


def relative_illumination(shape: tuple[int, int], vignetting: float) -> np.ndarray:
    """(H, W, 1) float32 light the lens passes: 1 at the centre, 1 − `vignetting` at the corners,
    falling with the squared radius."""
    height, width = shape
    cy, cx = (height - 1) / 2, (width - 1) / 2
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    rho2 = ((cols - cx) ** 2 + (rows - cy) ** 2) / (cx * cx + cy * cy or 1.0)
    return (1.0 - vignetting * rho2).astype(np.float32)[..., None]


class LensedGel:
    """A `GelSimulator` imaged through the sensor profile's `lens` (same constructor, same frames API
    for the bench: `render`, `blank`, `background`, `axis_mm`, `sag_mm`, `effective_depth_mm`)."""

    def __init__(
        self,
        profile: Mapping[str, Any],
        seed: int = 0,
        *,
        noise_seed: int | None = None,
        gain_rgb=None,
        lens: RadialLens | None = None,
    ):
        """`lens`: the lens as built (the bench's hidden draw); by default the profile's nominal one."""
        nominal = RadialLens.from_profile(profile)
        if nominal is None:
            raise ConfigError(f"sensor profile {profile.get('name')!r} has no lens block")
        lens = lens or nominal
        if lens.shape != nominal.shape:
            raise ConfigError(
                f"the lens is for {lens.shape} frames, the profile's are {nominal.shape}"
            )
        self.lens = lens
        self.profile = profile
        self.height, self.width = lens.shape
        vignetting = float(profile["lens"].get("vignetting", 0.0))
        if not 0 <= vignetting < 1:
            raise ConfigError(
                f"sensor profile {profile.get('name')!r}: lens.vignetting must lie in [0, 1), got {vignetting}"
            )
        cols, rows = np.meshgrid(
            np.arange(self.width, dtype=float), np.arange(self.height, dtype=float)
        )
        ideal = lens.undistort(np.stack([cols, rows], axis=-1))
        # the canvas reaches every ideal point a camera pixel sees, plus the bilinear footprint
        reach = max(
            -float(ideal[..., 0].min()),
            float(ideal[..., 0].max()) - (self.width - 1),
            -float(ideal[..., 1].min()),
            float(ideal[..., 1].max()) - (self.height - 1),
            0.0,
        )
        self.pad = int(math.ceil(reach)) + 2
        self.inner = GelSimulator(
            profile, seed, margin_px=self.pad, noise_seed=noise_seed, gain_rgb=gain_rgb
        )
        self._map_x = (ideal[..., 0] + self.pad).astype(np.float32)
        self._map_y = (ideal[..., 1] + self.pad).astype(np.float32)
        self._light = relative_illumination((self.height, self.width), vignetting)
        self._background = self._camera(self.inner.ideal())  # with the gel's markers, if any

    # what the bench reads from the gel, unchanged by the lens
    @property
    def px_per_mm(self) -> float:
        return self.inner.px_per_mm

    @property
    def max_penetration_mm(self) -> float:
        return self.inner.max_penetration_mm

    def sag_mm(self, x_mm, y_mm):
        return self.inner.sag_mm(x_mm, y_mm)

    def effective_depth_mm(self, depth_mm: float, hold_frame: int = 0) -> float:
        return self.inner.effective_depth_mm(depth_mm, hold_frame)

    def check_depth(self, depth_mm: float) -> None:
        self.inner.check_depth(depth_mm)

    def axis_mm(self, center_px) -> tuple[float, float]:
        """An ideal-frame pixel → mm from the gel's centre."""
        return self.inner.axis_mm(self._canvas(center_px))

    def _canvas(self, center_px) -> tuple[float, float]:
        return float(center_px[0]) + self.pad, float(center_px[1]) + self.pad

    def _camera(self, ideal: np.ndarray) -> np.ndarray:
        image = cv2.remap(
            ideal, self._map_x, self._map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        image *= self._light
        return image

    @property
    def background(self) -> np.ndarray:
        """The noiseless no-contact camera image (float32, DN)."""
        return self._background

    def blank(self, frame_index: int = 0) -> np.ndarray:
        return self.inner._finish(self._background.copy(), frame_index)

    def render(
        self,
        indenter,
        center_px: tuple[float, float],
        rotation_deg: float = 0.0,
        depth_mm: float = 0.0,
        *,
        frame_index: int = 0,
        hold_frame: int = 0,
    ) -> np.ndarray:
        """A camera frame of `indenter` pressed `depth_mm` into the gel, its axis at the ideal-frame
        pixel `center_px` (the camera images it at `lens.distort(center_px)`)."""
        ideal = self.inner.ideal(
            indenter, self._canvas(center_px), rotation_deg, depth_mm, hold_frame=hold_frame
        )
        return self.inner._finish(self._camera(ideal), frame_index)


def make_gel(profile: Mapping[str, Any], seed: int = 0, lens: RadialLens | None = None, **kwargs):
    """The bench's gel and camera: a `LensedGel` when the profile has a lens, else a `GelSimulator`."""
    if profile.get("lens"):
        return LensedGel(profile, seed, lens=lens, **kwargs)
    return GelSimulator(profile, seed, **kwargs)
