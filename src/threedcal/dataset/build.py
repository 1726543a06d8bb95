"""The `dataset` stage: a scene's raw data (or imported folder) → splits.csv + the model-ready set."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from threedcal.dataset.importers import load_imported
from threedcal.dataset.trainset import TrainingSet, downscale, from_imported


def write_splits(trainset: TrainingSet, path: str | Path, xy_mm=None) -> None:
    samples = trainset.samples.drop_duplicates("point").sort_values("point")
    table = samples[["point", "split", "min_p"]].copy()
    if xy_mm is not None:
        table.insert(1, "x_mm", xy_mm[table["point"].to_numpy(), 0])
        table.insert(2, "y_mm", xy_mm[table["point"].to_numpy(), 1])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False)


def build_imported(
    scene: Mapping, trainset_dir: str | Path, splits_path: str | Path
) -> TrainingSet:
    data = load_imported(scene["import"]["format"], scene["import"]["path"])
    trainset = from_imported(data, seed=scene["seed"])
    trainset.max_slope_deg = float(scene["dataset"]["max_slope_deg"])
    trainset = downscale(trainset, int(scene["dataset"]["downscale"]))
    trainset.save(trainset_dir)
    xy = np.full((int(data.point.max()) + 1, 2), np.nan)
    xy[data.point] = data.xy_mm
    write_splits(trainset, splits_path, xy_mm=xy)
    return trainset
