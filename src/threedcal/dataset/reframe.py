"""A model-ready set brought to another network's frame, and that network's gradients brought back.

A network trained at a fixed frame size (the shipped pretrained weights: threedcal.pretrained) sees
another set's frames only at that size. `reframe` pools the set by the whole factor that brings it
there (threedcal.dataset.trainset.downscale: frames, blank, centres and px/mm together), and, when
the pooled frame is the network's frame on its side (portrait against landscape), turns it a
quarter counter-clockwise (numpy's rot90): frame, blank and every label centre, exactly. A
prediction in that frame is brought back by `Reframe.gradients_back`: turned back, its two
components exchanged as the turn exchanges the axes, and interpolated bilinearly to the original
pixels (the pixel-centre convention the pooling uses), so it is integrated and scored exactly as a
prediction made at the original size.

The turn is a geometric fact of the frame, not of the light: a sensor whose LEDs sit at the top
and bottom of its portrait frame has them at the sides once turned.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from threedcal.dataset.trainset import TrainingSet, downscale
from threedcal.errors import ConfigError
from threedcal.orientation import turn_image, turn_points


@dataclass(frozen=True)
class Reframe:
    """How a set of `full_shape` (H, W) frames was brought to a network's frame."""

    full_shape: tuple[int, int]
    factor: int  # pooled by this whole factor per axis
    turned: bool  # then a quarter turn counter-clockwise

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the network's frame."""
        h, w = self.full_shape[0] // self.factor, self.full_shape[1] // self.factor
        return (w, h) if self.turned else (h, w)

    def describe(self) -> str:
        """e.g. '120x160 px (320x240 pooled 2x, turned a quarter)': H x W, as errors.csv says it."""
        h, w = self.shape
        steps = [f"pooled {self.factor}x"] if self.factor > 1 else []
        steps += ["turned a quarter"] if self.turned else []
        how = f" ({self.full_shape[0]}x{self.full_shape[1]} {', '.join(steps)})" if steps else ""
        return f"{h}x{w} px{how}"

    def gradients_back(self, grads: np.ndarray) -> np.ndarray:
        """(h, w, 2) gradients (d/dx, d/dy) in the network's frame -> (H, W, 2) in the original.

        Turned: the network's x is the original y, its y the original (W - 1 - x), so the original
        d/dx = -(network d/dy) and d/dy = network d/dx. Gradients are dimensionless: pooling leaves
        their values alone, and they are interpolated back to the original pixel centres (rows and
        columns the pooling cropped take the nearest edge's value)."""
        grads = np.asarray(grads, dtype=np.float32)
        if grads.shape != (*self.shape, 2):
            raise ValueError(f"gradients of shape {grads.shape}, expected {(*self.shape, 2)}")
        if self.turned:
            back = np.rot90(grads, k=-1, axes=(0, 1))
            grads = np.stack([-back[..., 1], back[..., 0]], axis=-1)
        h, w = grads.shape[:2]
        if self.factor > 1:
            f = self.factor
            grads = cv2.resize(
                np.ascontiguousarray(grads), (w * f, h * f), interpolation=cv2.INTER_LINEAR
            )
        height, width = self.full_shape
        pad = ((0, height - grads.shape[0]), (0, width - grads.shape[1]), (0, 0))
        return np.pad(grads, pad, mode="edge") if any(p[1] for p in pad) else grads


def reframe_problem(shape: tuple[int, int], target: tuple[int, int]) -> str | None:
    """Why (H, W) frames cannot be brought to the network's (h, w) frame, or None."""
    return (
        None
        if _how(shape, target)
        else (
            f"{shape[0]} x {shape[1]} px frames (H x W) cannot be pooled by a whole factor to the "
            f"weights' {target[0]} x {target[1]} px, as they are or turned a quarter"
        )
    )


def _how(shape: tuple[int, int], target: tuple[int, int]) -> tuple[int, bool] | None:
    height, width = (int(v) for v in shape)
    for turned, (h, w) in ((False, target), (True, target[::-1])):
        h, w = int(h), int(w)
        factor = height // h if h > 0 else 0
        if factor >= 1 and (height // factor, width // factor) == (h, w):
            return factor, turned
    return None


def reframe(ts: TrainingSet, target: tuple[int, int], key: str) -> tuple[TrainingSet, Reframe]:
    """`ts` pooled (and turned, if it must be) to a network's (h, w) frame; refused, naming
    `key`, when no whole factor brings it there."""
    how = _how(ts.image_shape, tuple(target))
    if how is None:
        raise ConfigError(f"{key}: {reframe_problem(ts.image_shape, tuple(target))}")
    factor, turned = how
    out = downscale(ts, factor)
    if turned:
        out = turn_quarter(out)
    return out, Reframe(tuple(ts.image_shape), factor, turned)


def turn_quarter(ts: TrainingSet) -> TrainingSet:
    """The set turned a quarter counter-clockwise: pixel (x, y) goes to (y, W - 1 - x)."""
    samples = ts.samples.copy()
    centres = samples[["center_x_px", "center_y_px"]].to_numpy(float)
    samples[["center_x_px", "center_y_px"]] = turn_points(
        centres, ts.image_shape[1], ts.image_shape[0]
    )
    units = ts.unit_blanks
    return dataclasses.replace(
        ts,
        frames=turn_image(ts.frames, axes=(1, 2)),
        blank=turn_image(ts.blank),
        samples=samples,
        unit_blanks=None if units is None else turn_image(units, axes=(1, 2)),
        meta={**(ts.meta or {}), "turned_quarter": True},
    )
