"""models/inference.json: depth frames/s of a scene's model on this host's CPU, the figure the
results page and the summary quote."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from threedcal.dataset.trainset import TrainingSet
from threedcal.model.inference import DepthEstimator


def measure_inference(
    model_path: str | Path, trainset_dir: str | Path, out: str | Path, frames: int = 30
) -> dict:
    """Depth frames/s of a checkpoint on real frames of its dataset (the figure the summary quotes)."""
    estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
    trainset = TrainingSet.load(trainset_dir)
    picks = np.linspace(0, len(trainset.frames) - 1, frames).round().astype(int)
    batch = np.asarray(trainset.frames[picks])
    estimator.depth(batch[0])  # warm-up
    start = time.perf_counter()
    for frame in batch:
        estimator.depth(frame)
    seconds = (time.perf_counter() - start) / len(batch)
    record = {
        "preset": estimator.preset,
        "frames_per_s": round(1.0 / seconds, 2),
        "ms_per_frame": round(seconds * 1000, 2),
        "image_shape": list(estimator.image_shape),
        "torch_threads": torch.get_num_threads(),
    }
    Path(out).write_text(json.dumps(record, indent=2) + "\n")
    return record
