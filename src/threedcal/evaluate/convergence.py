"""Has every model learnt what its data can teach it? Error against training time, to twice the budget.

The ablation compares fractions P by their models' validation error; that comparison is about the
data only if the models have (nearly) finished learning. Every model of the ablation trains the
same steps in cycles that end at a quarter, a half and all of the budget, then one more cycle to
twice the budget (threedcal.model.lockstep). Each cycle end is scored as the stats stage scores the
study's models (mean validation MSE per coordinate): `error_vs_time.csv` is every fraction's curve,
and `convergence.csv` compares, per P, the models at the budget with the same models at twice it,
paired by replicate and spatial block (the ratio's interval is the tests' own, Fieller's). The
validation coordinates chose nothing here: they only score.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation import block_means, ratio_interval
from threedcal.evaluate.validation import coordinate_mse
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator
from threedcal.plotting import pyplot

CURVE_COLUMNS = ("P", "replicate", "steps", "seconds", "mse")
CONVERGENCE_COLUMNS = (
    "P",
    "replicates",
    "steps",
    "budget_mse",
    "twice_steps",
    "twice_mse",
    "change",
    "ci_low",
    "ci_high",
)
# The interval of the change at twice the budget: 95 %, two-sided.
CONVERGENCE_ALPHA = 0.05


def seconds_at(losses: pd.DataFrame) -> pd.Series:
    """Training seconds spent to reach each logged step (losses.csv: seconds since the last row)."""
    return pd.Series(losses["seconds"].cumsum().to_numpy(), index=losses["step"].to_numpy())


def snapshot_scores(
    snapshots: Mapping[tuple[int, int], list[str | Path]], trainset: TrainingSet
) -> pd.DataFrame:
    """(P, replicate) -> snapshot files, each scored: P, replicate, steps, mse (mean validation MSE)."""
    rows = []
    for (p, replicate), paths in sorted(snapshots.items()):
        for path in paths:
            checkpoint = read_checkpoint(path)
            estimator = DepthEstimator(dict(checkpoint), device="cpu")
            mse = float(coordinate_mse(estimator, trainset)["mse"].mean())
            steps = int(checkpoint["training"]["steps"])
            rows.append({"P": int(p), "replicate": int(replicate), "steps": steps, "mse": mse})
    return pd.DataFrame(rows, columns=["P", "replicate", "steps", "mse"])


def _model_means(table: pd.DataFrame, steps: int) -> pd.DataFrame:
    means = table.groupby(["P", "replicate"], as_index=False)["mse"].mean()
    return means.assign(steps=int(steps))


def error_vs_time_table(
    snapshots: pd.DataFrame,
    budget: tuple[int, pd.DataFrame],
    twice: tuple[int, pd.DataFrame],
    losses: Mapping[tuple[int, int], str | Path],
) -> pd.DataFrame:
    """error_vs_time.csv: every model's mean validation MSE at every cycle end, with the training
    seconds it had taken (twice/losses.csv's clock). `budget` and `twice` are (steps, the
    validation_mse.csv of the models there); `losses` maps (P, replicate) to twice/losses.csv."""
    points = pd.concat(
        [snapshots, _model_means(budget[1], budget[0]), _model_means(twice[1], twice[0])],
        ignore_index=True,
    )
    seconds = []
    for row in points.itertuples():
        clock = seconds_at(pd.read_csv(losses[(row.P, row.replicate)]))
        seconds.append(float(clock.get(row.steps, np.nan)))
    points["seconds"] = seconds
    points = points.sort_values(["P", "replicate", "steps"], ignore_index=True)
    return points[list(CURVE_COLUMNS)]


def convergence_table(
    budget: tuple[int, pd.DataFrame], twice: tuple[int, pd.DataFrame], blocks: pd.Series
) -> pd.DataFrame:
    """Per P: mean validation MSE at the budget and at twice it, the relative change and its 95 %
    interval, the same models' errors paired by replicate and spatial block."""
    at_budget, at_twice = block_means(budget[1], blocks), block_means(twice[1], blocks)
    rows = []
    for p in sorted(at_budget):
        low, high = ratio_interval(at_twice[p], at_budget[p], CONVERGENCE_ALPHA / 2)
        before, after = float(np.mean(at_budget[p])), float(np.mean(at_twice[p]))
        rows.append(
            {
                "P": int(p),
                "replicates": int(at_budget[p].shape[0]),
                "steps": int(budget[0]),
                "budget_mse": before,
                "twice_steps": int(twice[0]),
                "twice_mse": after,
                "change": after / before - 1.0,
                "ci_low": low - 1.0,
                "ci_high": high - 1.0,
            }
        )
    return pd.DataFrame(rows, columns=list(CONVERGENCE_COLUMNS))


def curve_figure(curve: pd.DataFrame, budget_steps: int, path: str | Path, title: str) -> None:
    """Mean validation MSE against training steps, one line per P (the replicates' range shaded),
    the budget marked."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=120)
    cmap = plt.get_cmap("viridis")
    fractions = sorted(curve["P"].unique())
    for index, p in enumerate(fractions):
        colour = cmap(index / max(len(fractions) - 1, 1))
        per_step = curve[curve["P"] == p].groupby("steps")["mse"]
        mean, low, high = per_step.mean(), per_step.min(), per_step.max()
        ax.fill_between(mean.index, low, high, color=colour, alpha=0.15, lw=0)
        ax.plot(mean.index, mean.values, "-o", ms=3, color=colour, label=f"P = {p} %")
    ax.axvline(budget_steps, color="k", ls=":", lw=1)
    ax.text(budget_steps, 0.02, " the budget", transform=ax.get_xaxis_transform(), fontsize=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("optimiser steps (every model the same)")
    ax.set_ylabel("mean validation MSE")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
