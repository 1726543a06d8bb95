"""The two ReSkin rules as functions: train (split by coordinate, the MLP, its losses) and evaluate
(the held-out readings' localisation errors and their figure)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from threedcal.model.checkpoint import save_checkpoint
from threedcal.reskin.data import load_readings, split_by_coordinate, splits_table
from threedcal.reskin.evaluate import evaluate_split
from threedcal.reskin.figures import eval_figure
from threedcal.reskin.model import ReSkinSettings, predict, read_reskin_model, train_mlp


def reskin_train_stage(
    store: str | Path,
    settings: Mapping[str, Any] | None,
    *,
    seed: int,
    torch_threads: int,
    model_path: str | Path,
    losses_path: str | Path,
    splits_path: str | Path,
    progress: bool = True,
) -> dict[str, Any]:
    """Split the store's readings by coordinate, train the MLP on the training side, write them."""
    config = ReSkinSettings.from_config(settings)
    data = load_readings(store)
    test = split_by_coordinate(data.targets[:, 0], data.targets[:, 1], config.test_fraction, seed)
    train = data.subset(~test)
    held = data.subset(test)
    checkpoint, rows = train_mlp(
        train.inputs,
        train.targets,
        config,
        seed=seed,
        torch_threads=torch_threads,
        names=data.names,
        monitor=(held.inputs, held.targets),
        progress=progress,
    )
    checkpoint["baseline"] = data.baseline.tolist()
    save_checkpoint(model_path, checkpoint)
    Path(losses_path).parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(losses_path, index=False, float_format="%.6g")
    splits_table(data, test).to_csv(splits_path, index=False)
    return {"train_readings": len(train.targets), "test_readings": len(held.targets)}


def reskin_eval_stage(
    store: str | Path,
    model_path: str | Path,
    splits_path: str | Path,
    sensor: Mapping[str, Any],
    *,
    out_json: str | Path,
    out_figure: str | Path,
    title: str = "",
) -> dict[str, Any]:
    """Errors on the held-out coordinates named in splits.csv; reskin_eval.json and its figure."""
    data = load_readings(store)
    checkpoint = read_reskin_model(model_path)
    splits = pd.read_csv(splits_path)
    held = splits.loc[splits["split"] == "test", ["x_mm", "y_mm"]].to_numpy(float)
    keys = np.round(data.targets[:, :2].astype(float), 6)
    test = (np.abs(keys[:, None, :] - held[None, :, :]).max(axis=2) < 1e-6).any(axis=1)
    metrics, table = evaluate_split(checkpoint, data, test)
    metrics["seed"] = checkpoint["seed"]
    metrics["settings"] = checkpoint["settings"]
    Path(out_json).parent.mkdir(parents=True, exist_ok=True)
    Path(out_json).write_text(json.dumps(metrics, indent=2, sort_keys=True) + "\n")
    predicted = predict(checkpoint, data.inputs[test])
    errors = np.hypot(*(predicted[:, :2] - data.targets[test][:, :2]).T)
    eval_figure(table, errors, metrics, sensor, out_figure, title=title)
    return metrics
