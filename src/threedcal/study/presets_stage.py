"""The `presets` rule as a function: every CPU model preset trained alike on an imported scene and
compared on depth error against inference time."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.presets_study import compare_presets, presets_figure
from threedcal.model.train import TrainSettings


def presets_stage(
    trainset_dir: str | Path,
    model: dict,
    seed: int,
    threads: int,
    presets: Sequence[str],
    csv_path: str | Path,
    png_path: str | Path,
    scene_model: str | Path | None = None,
) -> pd.DataFrame:
    """presets.csv and presets.png; `scene_model`: the scene's own model at P = 80, replicate 0
    (models/P80/r0/model.pt), which stands for the scene's preset."""
    settings = TrainSettings.of(seed=seed, torch_threads=threads, **model)
    trained = {settings.preset: scene_model} if scene_model is not None else {}
    table = compare_presets(TrainingSet.load(trainset_dir), settings, presets, trained)
    table.to_csv(csv_path, index=False)
    presets_figure(table, png_path, "presets: held-out depth error against inference time")
    return table
