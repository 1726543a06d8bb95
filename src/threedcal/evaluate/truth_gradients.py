"""A perfect model of the pressed test objects, for checking the scoring protocols: never a result."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from threedcal.depth import integrate
from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import dome_rise, surface_height
from threedcal.evaluate.object_presses import read_presses
from threedcal.evaluate.press_plan import object_mesh
from threedcal.lens import RadialLens, rectify_if


class TruthGradients:
    """A perfect model, for checking the protocols (never used by the stage): the exact gradients
    of the true surface of every rendered press — the CAD mesh where the bench's truth.json says
    it put it, differentiated at the pixel centres — integrated as a model's would be. It reads
    the simulator's hidden truth, so it can only diagnose, never be reported as a model."""

    def __init__(
        self,
        pressing_dir: str | Path,
        px_per_mm: float,
        step_px: float = 0.05,
        lens: RadialLens | None = None,
        dome: Mapping | None = None,
    ):
        """`lens`: the registration's (registration.json), through which `evaluate_objects`
        rectifies each frame before it asks for its depth; `dome`: the sensor's gel.dome, which
        the depth is measured from."""
        self.dome = dome
        plan, frames, _, truth = read_presses(pressing_dir)
        frames = rectify_if(lens, frames)
        if not truth.get("simulated"):
            raise ConfigError(f"{pressing_dir}: no bench truth (a real rig's presses)")
        self.px_per_mm = float(px_per_mm)
        self.image_shape = tuple(frames.shape[1:3])
        self._gradients = {}
        for row, frame, true in zip(plan.itertuples(), frames, truth["presses"], strict=True):
            mesh = object_mesh(row.object)
            # central differences well inside every facet: the gradient at the pixel centre
            at = [self._depth(mesh, true, d) for d in ((step_px, 0), (-step_px, 0))]
            at += [self._depth(mesh, true, d) for d in ((0, step_px), (0, -step_px))]
            scale = self.px_per_mm / (2 * step_px)
            self._gradients[frame.tobytes()] = ((at[0] - at[1]) * scale, (at[2] - at[3]) * scale)

    def _depth(self, mesh, true: Mapping, shift: tuple[float, float]) -> np.ndarray:
        """The true depth map sampled at (x, y) + `shift` px (the object moved by -shift; the dome,
        which stays put, sampled at the shifted points)."""
        cx, cy = true["center_px"]
        surface = surface_height(
            mesh,
            self.image_shape,
            self.px_per_mm,
            (cx - shift[0], cy - shift[1]),
            true["rotation_deg"],
        )
        height = surface.height_mm
        if self.dome:
            height = height + dome_rise(
                self.dome, (cx, cy), self.image_shape, self.px_per_mm, shift
            )
        return np.maximum(true["depth_mm"] - height, 0.0)

    def depth(self, frame: np.ndarray, method: str = "poisson_dst") -> np.ndarray:
        gx, gy = self._gradients[np.asarray(frame).tobytes()]
        return integrate(gx, gy, method=method, px_per_mm=self.px_per_mm)
