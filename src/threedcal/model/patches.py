"""What a training step sees: patches of the training frames (around the contact and anywhere),
their drift-corrected network inputs, and their batches."""

from __future__ import annotations

import numpy as np
import torch

from threedcal.dataset.trainset import TrainingSet
from threedcal.model.drift import drift_offset, remove_drift
from threedcal.model.train_settings import TrainSettings


def _window(top: int, left: int, size: tuple[int, int]) -> tuple[slice, slice]:
    return slice(top, top + size[0]), slice(left, left + size[1])


def sample_windows(
    ts: TrainingSet, indices: np.ndarray, settings: TrainSettings, rng: np.random.Generator
) -> list[tuple[int, tuple[slice, slice]]]:
    """Contact patches (centre jittered by up to a third of the patch) and background patches."""
    height, width = ts.image_shape
    size = (min(settings.patch_px, height), min(settings.patch_px, width))
    out = []
    for i in indices:
        cx, cy = ts.center_px[i]
        # skirt_reach > 0 lets patches cover the gel outside the contact too: it deforms and changes
        # colour there, while its label is flat (and integrating wrong slopes there biases depth).
        reach = settings.skirt_reach * float(ts.eval_radius_px[i])
        jitter = (max(size[0] / 3, reach), max(size[1] / 3, reach))
        for _ in range(settings.contact_patches):
            jx, jy = rng.uniform(-jitter[1], jitter[1]), rng.uniform(-jitter[0], jitter[0])
            top = int(np.clip(round(cy + jy - size[0] / 2), 0, height - size[0]))
            left = int(np.clip(round(cx + jx - size[1] / 2), 0, width - size[1]))
            out.append((int(i), _window(top, left, size)))
        for _ in range(settings.background_patches):
            top = int(rng.integers(0, height - size[0] + 1))
            left = int(rng.integers(0, width - size[1] + 1))
            out.append((int(i), _window(top, left, size)))
    return out


class ModelInputs:
    """Network inputs of a TrainingSet's frames or windows, with the frame's lighting drift removed.

    The drift offset is estimated once per frame on the full frame (as inference does), then
    subtracted from every window of it.
    """

    def __init__(self, ts: TrainingSet, mode: str) -> None:
        self.ts, self.mode = ts, mode
        self._offsets: dict[int, torch.Tensor] = {}

    def offset(self, i: int) -> torch.Tensor:
        if i not in self._offsets:
            self._offsets[i] = drift_offset(torch.from_numpy(self.ts.inputs(i))[None])[0]
        return self._offsets[i]

    def __call__(self, i: int, window: tuple[slice, slice] | None = None) -> torch.Tensor:
        x = torch.from_numpy(self.ts.inputs(i, window))[None]
        if self.mode == "none":
            return x[0]
        return remove_drift(x, self.mode, self.offset(i)[None])[0]


def input_batches(ts, windows, batch_size, inputs: ModelInputs):
    for start in range(0, len(windows), batch_size):
        chunk = windows[start : start + batch_size]
        x = torch.stack([inputs(i, w) for i, w in chunk])
        y = np.stack([ts.labels(i, w) for i, w in chunk])
        yield x, torch.from_numpy(y)


class FramePairs:
    """Re-iterable (inputs, labels) of full frames, read lazily (the lookup fit reads them twice)."""

    def __init__(self, ts: TrainingSet, indices: np.ndarray, inputs: ModelInputs):
        self.ts, self.indices, self.inputs = ts, indices, inputs

    def __iter__(self):
        for i in self.indices:
            yield self.inputs(int(i)).numpy(), self.ts.labels(int(i))
