"""Lighting drift between the blank and a frame: the per-channel median colour change of the frame.

LEDs and camera exposure drift between the blank (no-contact) capture and later frames. On the real
GelSight ball set (data/gelsight_ball_fots) the whole background of a frame is offset from
the blank by up to 30 grey levels in one channel, while the residual after removing one offset per
channel is 2-4 levels; the contact covers under 10 % of the frame. The median of (frame - blank)
over the frame ignores any contact that covers less than half of it, so it estimates that global
offset; subtracting it from the colour channels leaves the change caused by the indentation.

The step is part of the input normalisation: the same function runs in training and inference, for
every preset (the lookup table too), and the checkpoint records it as normalisation["drift"] =
"median" ("none" for the authors' weights and older checkpoints).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from threedcal.errors import ConfigError

DRIFT_MODES = ("median", "none")
# Every STRIDE-th pixel along rows and columns: 4800 samples at 240x320, a fixed, cheap estimate.
STRIDE = 4


def drift_offset(diff: torch.Tensor) -> torch.Tensor:
    """(N, 3, 1, 1) median of each colour channel of (N, >=3, H, W) inputs (frame - blank)/255."""
    sample = diff[:, :3, ::STRIDE, ::STRIDE].reshape(diff.shape[0], 3, -1)
    # on the CPU: CUDA has no deterministic median, and a process that trained (deterministic
    # algorithms on) would refuse to run inference there; a few thousand values cross
    return sample.cpu().median(dim=2).values.to(diff.device)[..., None, None]


def remove_drift(x: torch.Tensor, mode: str, offset: torch.Tensor | None = None) -> torch.Tensor:
    """Inputs with the lighting drift removed from the colour channels (a new tensor for 'median').

    `offset` (N, 3, 1, 1) overrides the estimate: training passes the offset of the full frame when
    it feeds a patch of it.
    """
    if mode == "none":
        return x
    if mode != "median":
        raise ConfigError(f"model.drift: mode {mode!r} (allowed: {', '.join(DRIFT_MODES)})")
    offset = drift_offset(x) if offset is None else offset
    return torch.cat([x[:, :3] - offset, x[:, 3:]], 1)


# Cells over which the background drift is averaged: camera noise (2-3 grey levels a pixel) falls
# below 0.4 levels, a lighting change stays.
DRIFT_CELL_PX = 8
HALO_CELLS = 2


def background_drift_dn(
    frame: np.ndarray, blank: np.ndarray, contact: np.ndarray | None = None
) -> float:
    """How far the no-contact region has drifted from the blank that `remove_drift` cannot undo:
    the RMS, in grey levels, of (frame - blank) less its per-channel median, averaged over
    DRIFT_CELL_PX cells at least HALO_CELLS cells from any `contact` pixel (H, W). A uniform shift of the lighting
    gives 0 (the model removes it); an LED dimmed or brightened alone, or a shadow, does not.
    NaN when every cell touches the contact."""
    diff = np.asarray(frame, np.float32) - np.asarray(blank, np.float32)
    sample = diff[::STRIDE, ::STRIDE].reshape(-1, diff.shape[-1])
    residual = diff - np.median(sample, axis=0)  # the offset remove_drift takes out
    height, width = diff.shape[:2]
    rows, cols = max(height // DRIFT_CELL_PX, 1), max(width // DRIFT_CELL_PX, 1)
    crop = (slice(0, rows * DRIFT_CELL_PX), slice(0, cols * DRIFT_CELL_PX))
    cells = cv2.resize(
        np.ascontiguousarray(residual[crop]), (cols, rows), interpolation=cv2.INTER_AREA
    )
    free = np.ones((rows, cols), bool)
    if contact is not None:
        touched = np.asarray(contact, np.float32)[crop]
        touched = cv2.resize(touched, (cols, rows), interpolation=cv2.INTER_AREA) > 0
        # and their neighbours: the shading halo reaches past where the depth crosses contact
        reach = np.ones((2 * HALO_CELLS + 1,) * 2, np.uint8)
        free = cv2.dilate(touched.astype(np.uint8), reach) == 0
    if not free.any():
        return float("nan")
    return float(np.sqrt(np.mean(cells.reshape(rows, cols, -1)[free] ** 2)))
