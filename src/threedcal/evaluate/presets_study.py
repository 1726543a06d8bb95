"""Depth error against inference time for every CPU preset, trained alike on one imported scene.

The report's "which preset when": each preset trains with the scene's `model:` settings (preset
swapped) at P = 80 and is scored on the held-out images (threedcal.evaluate.ball_eval.evaluate);
the time is DepthEstimator.depth per frame on this machine, integration included. The scene's own
preset is the scene's model at P = 80 (replicate 0) where the study trains it: the same training,
not done twice. `train_s` is each training's seconds as its losses.csv records them.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ball_eval import evaluate
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import TrainSettings, train
from threedcal.plotting import pyplot

COLUMNS = ["preset", "ms_per_frame", "gradient_rmse", "cap_depth_mae_um", "train_s"]
# Patch training on imported ball images: the benchmarks' and diagnostics' common yardstick
# (fots_ball's own `model:` section is multiscale, chosen on an inner split of its training images).
PATCH_BALL_SETTINGS = dict(
    lr=3e-3,
    lr_schedule="cosine",
    epochs_base=20,
    batch_size=16,
    patch_px=48,
    contact_patches=16,
    background_patches=32,
    skirt_reach=2.5,
)


def depth_ms_per_frame(estimator: DepthEstimator, frames: np.ndarray, repeats: int = 3) -> float:
    estimator.depth(frames[0])  # warm-up
    times = []
    for _ in range(repeats):
        for frame in frames:
            start = time.perf_counter()
            estimator.depth(frame)
            times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def compare_presets(
    trainset: TrainingSet,
    settings: TrainSettings,
    presets: Sequence[str],
    trained: Mapping[str, str | Path] | None = None,
) -> pd.DataFrame:
    """One row per preset; `trained` maps a preset to a model.pt already trained with these
    settings at P = 80 on this set (its losses.csv beside it), used instead of training again."""
    test = trainset.indices("val")
    frames = np.asarray(trainset.frames[test[: min(len(test), 4)]])
    rows = []
    trained = dict(trained or {})
    with tempfile.TemporaryDirectory() as tmp:
        for preset in tqdm(presets, desc="presets", unit="preset"):
            if preset in trained:
                model_dir = Path(trained[preset]).parent
                checkpoint = read_checkpoint(model_dir / "model.pt")
            else:
                model_dir = Path(tmp) / preset
                checkpoint = train(
                    trainset,
                    model_dir,
                    80,
                    dataclasses.replace(settings, preset=preset),
                    progress=False,
                )
            seconds = float(pd.read_csv(model_dir / "losses.csv")["seconds"].sum())
            estimator = DepthEstimator(checkpoint, device="cpu", batch_size=1)
            figures = evaluate(estimator, trainset, test)
            rows.append(
                {
                    "preset": preset,
                    "ms_per_frame": round(depth_ms_per_frame(estimator, frames), 3),
                    "gradient_rmse": figures["gradient_rmse"],
                    "cap_depth_mae_um": figures["cap_depth_mae_um"],
                    "train_s": round(seconds, 2),
                }
            )
    return pd.DataFrame(rows, columns=COLUMNS)


def presets_figure(table: pd.DataFrame, path: str | Path, title: str) -> None:
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, layout="constrained")
    for ax, column, label in zip(
        axes,
        ("cap_depth_mae_um", "gradient_rmse"),
        ("cap depth MAE (µm)", "gradient RMSE"),
        strict=True,
    ):
        ax.scatter(table["ms_per_frame"], table[column], s=30)
        for row in table.itertuples():
            ax.annotate(
                row.preset,
                (row.ms_per_frame, getattr(row, column)),
                fontsize=8,
                xytext=(4, 3),
                textcoords="offset points",
            )
        ax.set(xscale="log", xlabel="depth inference, ms per frame (CPU)", ylabel=label)
    fig.suptitle(title)
    fig.savefig(path)
    plt.close(fig)
