"""The stages whose rules compose several domain steps: each takes the rule's files and settings as
plain values and writes the rule's outputs (the statistics, the presets comparison, ReSkin)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation_figure import tests_figure
from threedcal.evaluate.power import power_figure, power_table
from threedcal.evaluate.presets_study import compare_presets, presets_figure
from threedcal.evaluate.validation import (
    cost_figure,
    cost_table,
    kde_figure,
    loss_curves_figure,
    mse_map_figure,
    probe_spacing_mm,
    read_ablation,
    write_reading,
)
from threedcal.model.checkpoint import save_checkpoint
from threedcal.model.train import TrainSettings
from threedcal.reskin.data import load_readings, split_by_coordinate, splits_table
from threedcal.reskin.evaluate import evaluate_split
from threedcal.reskin.figures import eval_figure
from threedcal.reskin.model import ReSkinSettings, predict, read_reskin_model, train_mlp


def twice_stage(
    scene_name: str,
    models: Mapping[tuple[int, int], str | Path],
    trainset_dir: str | Path,
    splits_path: str | Path,
    settings: Mapping,
    seed: int,
    out: Mapping[str, str | Path],
) -> str:
    """The `stats_twice` rule: the ablation read again on the models trained on to twice the
    budget (stats/twice/)."""
    reading = read_ablation(
        models, TrainingSet.load(trainset_dir), pd.read_csv(splits_path), settings, seed
    )
    write_reading(reading, out, f"{scene_name}, twice the budget: error against points probed")
    return reading.recommendation


def stats_stage(
    scene_name: str,
    models: Mapping[tuple[int, int], str | Path],
    losses: Mapping[tuple[int, int], str | Path],
    trainset_dir: str | Path,
    splits_path: str | Path,
    summary_path: str | Path | None,
    settings: Mapping,
    seed: int,
    out: Mapping[str, str | Path],
) -> str:
    """The `stats` rule: validation_mse.csv, tests.csv (+ figure), the recommendation, the learning
    curve (+ figure), the power table (+ figure), costs and the Fig. 3B/4 figures. `settings` is
    the config's `stats` section."""
    trainset = TrainingSet.load(trainset_dir)
    splits = pd.read_csv(splits_path)
    reading = read_ablation(models, trainset, splits, settings, seed)
    write_reading(reading, out, f"{scene_name}: error against points probed")
    table, tests = reading.table, reading.tests
    tests_figure(
        tests,
        out["tests_figure"],
        f"{scene_name}: each P against P = 80 %",
        margin=settings["equivalence_margin"],
    )
    power = power_table(
        table,
        reading.block_mm,
        probe_spacing_mm(splits),
        margin=settings["equivalence_margin"],
        alpha=settings["alpha"],
        equivalence_alpha=settings["equivalence_alpha"],
        simulations=settings["power_simulations"],
        seed=seed,
    )
    power.to_csv(out["power"], index=False, float_format="%.4g")
    power_figure(power, out["power_figure"], f"{scene_name}: power of the design")
    loss_tables = {key: pd.read_csv(path) for key, path in losses.items()}
    hardware_s = None
    if summary_path is not None and Path(summary_path).is_file():
        hardware_s = json.loads(Path(summary_path).read_text()).get("estimated_hardware_s")
    costs = cost_table(table, loss_tables, len(splits), hardware_s)
    costs.to_csv(out["costs"], index=False)
    loss_curves_figure(loss_tables, out["loss_figure"], f"{scene_name}: loss against epoch")
    mse_map_figure(table, splits, out["map_figure"], f"{scene_name}: validation MSE over the gel")
    kde_figure(table, out["kde_figure"], f"{scene_name}: validation MSE distributions")
    cost_figure(costs, out["cost_figure"], f"{scene_name}: error against cost")
    return reading.recommendation


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
