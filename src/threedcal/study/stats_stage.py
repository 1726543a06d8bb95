"""The ablation's statistics rules as functions: the tests, the recommendation, the learning curve,
the power and cost tables and their figures (`stats`), and the same read at twice the budget
(`stats_twice`)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation_figure import tests_figure
from threedcal.evaluate.power import power_figure, power_table
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
