"""Per-coordinate validation error of every model of an ablation, and the paper's Fig. 3B/4 figures.

The error of a model at a validation coordinate is the gradient MSE over the frames pressed there,
inside a disc of 1.5 contact radii around the probe centre: the contact and its immediate
surroundings, where the sensor's signal is (a whole-frame mean would mostly average zeros).
Coordinates are those of the dataset stage, already restricted to probe centres inside the image.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.trainset import TrainingSet

WINDOW_SCALE = 1.5


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def coordinate_mse(estimator, trainset: TrainingSet, split: str = "val") -> pd.DataFrame:
    """One row per coordinate of `split`: point, mse (mean over its frames)."""
    indices = trainset.indices(split)
    rows = []
    height, width = trainset.image_shape
    for i in indices:
        radius = max(WINDOW_SCALE * float(trainset.eval_radius_px[i]), 3.0)
        cx, cy = trainset.center_px[i]
        window = (
            slice(max(int(cy - radius), 0), min(int(cy + radius) + 2, height)),
            slice(max(int(cx - radius), 0), min(int(cx + radius) + 2, width)),
        )
        predicted = estimator.gradients(np.asarray(trainset.frames[i]))[window].transpose(2, 0, 1)
        label = trainset.labels(i, window)
        rows_idx, cols_idx = np.mgrid[window[0], window[1]]
        disc = (cols_idx - cx) ** 2 + (rows_idx - cy) ** 2 <= radius**2
        error = ((predicted - label) ** 2).sum(axis=0)[disc].mean() / 2.0
        rows.append({"point": int(trainset.point[i]), "mse": float(error)})
    table = pd.DataFrame(rows, columns=["point", "mse"])
    return table.groupby("point", as_index=False)["mse"].mean()


def ablation_table(
    model_paths: Mapping[int, str | Path], trainset: TrainingSet, splits: pd.DataFrame
) -> pd.DataFrame:
    """validation_mse.csv: P, point, x_mm, y_mm, mse for every model P and validation coordinate."""
    from threedcal.model.inference import DepthEstimator

    tables = []
    coords = splits.set_index("point")[["x_mm", "y_mm"]]
    for p, path in sorted(model_paths.items()):
        estimator = DepthEstimator.from_checkpoint(path, device="cpu")
        table = coordinate_mse(estimator, trainset)
        table.insert(0, "P", p)
        tables.append(table.join(coords, on="point"))
    return pd.concat(tables, ignore_index=True)[["P", "point", "x_mm", "y_mm", "mse"]]


def loss_curves_figure(losses: Mapping[int, pd.DataFrame], path: str | Path, title: str) -> None:
    """Fig. 3B: training and validation loss against epoch for every P."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(losses)))
    for colour, (p, table) in zip(colours, sorted(losses.items()), strict=True):
        checked = table.dropna(subset=["val_loss"])  # validation runs on a subset of epochs
        ax.plot(checked["epoch"], checked["val_loss"], c=colour, label=f"P = {p} %")
        ax.plot(table["epoch"], table["train_loss"], c=colour, ls=":", lw=1)
    ax.set(xlabel="epoch", ylabel="gradient MSE", yscale="log", title=title)
    ax.legend(fontsize=7, title="validation (solid), training (dotted)", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def mse_map_figure(table: pd.DataFrame, splits: pd.DataFrame, path: str | Path, title: str) -> None:
    """Fig. 4A: validation MSE over the gel for each P, the training coordinates of that P marked."""
    plt = _pyplot()
    fractions = sorted(table["P"].unique())
    columns = min(len(fractions), 3)
    rows = int(np.ceil(len(fractions) / columns))
    fig, axes = plt.subplots(
        rows,
        columns,
        figsize=(3.4 * columns, 3.4 * rows),
        dpi=110,
        squeeze=False,
        layout="constrained",
    )
    vmin, vmax = np.percentile(table["mse"], [2, 98])
    for ax, p in zip(axes.ravel(), fractions, strict=False):
        part = table[table["P"] == p]
        points = ax.scatter(
            part["x_mm"], part["y_mm"], c=part["mse"], cmap="magma", vmin=vmin, vmax=vmax, s=18
        )
        train = splits[
            (splits["split"] == "train") & (splits["min_p"] > 0) & (splits["min_p"] <= p)
        ]
        ax.scatter(train["x_mm"], train["y_mm"], marker="x", c="tab:cyan", s=10, lw=0.8)
        ax.set(
            title=f"P = {p} % ({len(train)} training points)",
            aspect="equal",
            xlabel="x (mm)",
            ylabel="y (mm)",
        )
        ax.title.set_fontsize(8)
    for ax in axes.ravel()[len(fractions) :]:
        ax.axis("off")
    fig.colorbar(points, ax=axes.ravel().tolist(), label="validation gradient MSE", shrink=0.8)
    fig.suptitle(title)
    fig.savefig(path)
    plt.close(fig)


def kde_figure(table: pd.DataFrame, path: str | Path, title: str) -> None:
    """Fig. 4B: Gaussian KDEs of each P's validation MSE distribution, means dashed."""
    from scipy.stats import gaussian_kde

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    fractions = sorted(table["P"].unique())
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(fractions)))
    grid = np.linspace(0, np.percentile(table["mse"], 99.5) * 1.1, 400)
    for colour, p in zip(colours, fractions, strict=True):
        values = table.loc[table["P"] == p, "mse"].to_numpy()
        if values.size > 2 and np.ptp(values) > 0:
            ax.plot(grid, gaussian_kde(values)(grid), c=colour, label=f"P = {p} %")
        ax.axvline(values.mean(), c=colour, ls="--", lw=0.8)
    ax.set(xlabel="validation gradient MSE", ylabel="density", title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def std_figure(tables: Mapping[str, pd.DataFrame], path: str | Path) -> None:
    """Fig. 4C: standard deviation of validation MSE against P, every scene on one axis."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=120)
    for scene, table in sorted(tables.items()):
        spread = table.groupby("P")["mse"].std()
        ax.plot(spread.index, spread.values, "o-", label=scene)
    ax.set(
        xscale="log",
        xlabel="P (% of probe points)",
        ylabel="std of validation MSE",
        title="spread of the error against training fraction",
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def cost_table(
    table: pd.DataFrame, losses: Mapping[int, pd.DataFrame], n_points: int, hardware_s: float | None
) -> pd.DataFrame:
    """Per P: mean validation MSE, probe points, estimated probing hours and measured training minutes."""
    rows = []
    for p in sorted(table["P"].unique()):
        from threedcal.dataset.splits import subset_size

        points = subset_size(n_points, int(p))
        rows.append(
            {
                "P": int(p),
                "points": points,
                "mean_mse": float(table.loc[table["P"] == p, "mse"].mean()),
                "probing_h": None
                if hardware_s is None
                else round(hardware_s * points / n_points / 3600, 4),
                "training_min": round(float(losses[p]["seconds"].sum()) / 60, 3),
            }
        )
    return pd.DataFrame(rows)


def cost_figure(costs: pd.DataFrame, path: str | Path, title: str) -> None:
    """Validation error against the estimated probing time and the measured training time."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, sharey=True)
    for ax, column, label in zip(
        axes,
        ("probing_h", "training_min"),
        ("estimated probing time (h)", "training time (min)"),
        strict=True,
    ):
        ax.plot(costs[column], costs["mean_mse"], "o-")
        for _, row in costs.iterrows():
            ax.annotate(
                f"P={int(row['P'])}",
                (row[column], row["mean_mse"]),
                fontsize=7,
                xytext=(3, 3),
                textcoords="offset points",
            )
        ax.set(xlabel=label, yscale="log")
    axes[0].set_ylabel("mean validation MSE")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def read_losses(paths: Mapping[int, str | Path]) -> dict[int, pd.DataFrame]:
    return {p: pd.read_csv(path) for p, path in paths.items()}


def fractions_of(paths: Sequence[str]) -> list[int]:
    return sorted(int(Path(p).parent.name.lstrip("P")) for p in paths)


def stats_stage(
    scene_name: str,
    models: Mapping[int, str | Path],
    losses: Mapping[int, str | Path],
    trainset_dir: str | Path,
    splits_path: str | Path,
    summary_path: str | Path | None,
    out: Mapping[str, str | Path],
) -> str:
    """The `stats` rule: validation_mse.csv, tests.csv, recommendation, costs and the figures."""
    import json

    from threedcal.evaluate.ablation import compare_fractions, recommend

    trainset = TrainingSet.load(trainset_dir)
    splits = pd.read_csv(splits_path)
    table = ablation_table(models, trainset, splits)
    table.to_csv(out["validation_mse"], index=False)
    tests = compare_fractions({p: table.loc[table["P"] == p, "mse"] for p in models})
    tests.to_csv(out["tests"], index=False)
    n_points = len(splits)
    points_by_p = {p: subset_size_for(n_points, p) for p in models}
    line = recommend(tests, points_by_p)
    Path(out["recommendation"]).write_text(line + "\n")
    loss_tables = read_losses(losses)
    hardware_s = None
    if summary_path is not None and Path(summary_path).is_file():
        hardware_s = json.loads(Path(summary_path).read_text()).get("estimated_hardware_s")
    costs = cost_table(table, loss_tables, n_points, hardware_s)
    costs.to_csv(out["costs"], index=False)
    loss_curves_figure(loss_tables, out["loss_figure"], f"{scene_name}: loss against epoch")
    mse_map_figure(table, splits, out["map_figure"], f"{scene_name}: validation MSE over the gel")
    kde_figure(table, out["kde_figure"], f"{scene_name}: validation MSE distributions")
    cost_figure(costs, out["cost_figure"], f"{scene_name}: error against cost")
    return line


def subset_size_for(n_points: int, percent: int) -> int:
    from threedcal.dataset.splits import subset_size

    return subset_size(n_points, percent)
