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

import torch

from threedcal.errors import ConfigError

DRIFT_MODES = ("median", "none")
# Every STRIDE-th pixel along rows and columns: 4800 samples at 240x320, a fixed, cheap estimate.
STRIDE = 4


def drift_offset(diff: torch.Tensor) -> torch.Tensor:
    """(N, 3, 1, 1) median of each colour channel of (N, >=3, H, W) inputs (frame - blank)/255."""
    sample = diff[:, :3, ::STRIDE, ::STRIDE].reshape(diff.shape[0], 3, -1)
    return sample.median(dim=2).values[..., None, None]


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
