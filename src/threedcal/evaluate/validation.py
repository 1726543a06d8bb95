"""Per-coordinate validation error of every model of an ablation, and the paper's Fig. 3B/4 figures.

The error of a model at a validation coordinate is the gradient MSE over the frames pressed there,
inside a disc of 1.5 contact radii around the probe centre: the contact and its immediate
surroundings, where the sensor's signal is (a whole-frame mean would mostly average zeros).
Coordinates are those of the dataset stage, already restricted to probe centres inside the image.
Every model (each fraction P and replicate r) is scored on the same validation coordinates; the
figures show the mean over replicates and their spread (min to max).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree
from scipy.stats import gaussian_kde

from threedcal.dataset.splits import subset_size
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import spatial_blocks
from threedcal.evaluate.ablation_reading import read_validation_errors
from threedcal.evaluate.learning_curve import LearningCurve, curve_table
from threedcal.evaluate.learning_curve_figure import learning_curve_figure
from threedcal.model.inference import DepthEstimator
from threedcal.plotting import pyplot

WINDOW_SCALE = 1.5


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
        predicted = estimator.gradients_in(np.asarray(trainset.frames[i]), window)
        predicted = predicted.transpose(2, 0, 1)
        label = trainset.labels(i, window)
        rows_idx, cols_idx = np.mgrid[window[0], window[1]]
        disc = (cols_idx - cx) ** 2 + (rows_idx - cy) ** 2 <= radius**2
        error = ((predicted - label) ** 2).sum(axis=0)[disc].mean() / 2.0
        rows.append({"point": int(trainset.point[i]), "mse": float(error)})
    table = pd.DataFrame(rows, columns=["point", "mse"])
    return table.groupby("point", as_index=False)["mse"].mean()


def scoring_disc_mm(trainset: TrainingSet, split: str = "val") -> float:
    """Diameter (mm) of the typical scoring disc: 2 x 1.5 contact radii (median over the split)."""
    radius_px = np.maximum(WINDOW_SCALE * trainset.eval_radius_px[trainset.indices(split)], 3.0)
    if radius_px.size == 0:
        raise ConfigError(f"the dataset has no {split!r} frames to score")
    return float(2 * np.median(radius_px) / trainset.px_per_mm)


def probe_spacing_mm(splits: pd.DataFrame) -> float:
    """The probe grid's spacing: the median distance from each coordinate to its nearest one."""
    xy = splits[["x_mm", "y_mm"]].to_numpy(float)
    if len(xy) < 2:
        raise ConfigError("the splits hold fewer than 2 probe coordinates")
    distance, _ = cKDTree(xy).query(xy, k=2)
    return float(np.median(distance[:, 1]))


def ablation_table(
    model_paths: Mapping[tuple[int, int], str | Path],
    trainset: TrainingSet,
    splits: pd.DataFrame,
) -> pd.DataFrame:
    """validation_mse.csv: P, replicate, point, x_mm, y_mm, mse for every model and validation coordinate."""
    tables = []
    coords = splits.set_index("point")[["x_mm", "y_mm"]]
    for (p, replicate), path in sorted(model_paths.items()):
        estimator = DepthEstimator.from_checkpoint(path, device="cpu")
        table = coordinate_mse(estimator, trainset)
        table.insert(0, "P", p)
        table.insert(1, "replicate", replicate)
        tables.append(table.join(coords, on="point"))
    return pd.concat(tables, ignore_index=True)[["P", "replicate", "point", "x_mm", "y_mm", "mse"]]


def replicate_summary(table: pd.DataFrame, statistic: str = "mean") -> pd.DataFrame:
    """Per P: the statistic of the per-coordinate MSE in each replicate, then its mean, min and max
    over replicates (columns P, mean, low, high, replicates)."""
    per_model = table.groupby(["P", "replicate"])["mse"].agg(statistic)
    grouped = per_model.groupby(level="P")
    return pd.DataFrame(
        {
            "mean": grouped.mean(),
            "low": grouped.min(),
            "high": grouped.max(),
            "replicates": grouped.size(),
        }
    ).reset_index()


def loss_curves_figure(
    losses: Mapping[tuple[int, int], pd.DataFrame], path: str | Path, title: str
) -> None:
    """Fig. 3B: training and validation loss against epoch for every P (mean over replicates, band
    from the lowest to the highest replicate)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    fractions = sorted({p for p, _ in losses})
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(fractions)))
    for colour, p in zip(colours, fractions, strict=True):
        runs = pd.concat([table.assign(replicate=r) for (q, r), table in losses.items() if q == p])
        for column, style in (("val_loss", "-"), ("train_loss", ":")):
            checked = runs.dropna(subset=[column])  # validation runs on a subset of epochs
            band = checked.groupby("epoch")[column].agg(["mean", "min", "max"])
            label = f"P = {p} %" if column == "val_loss" else None
            ax.plot(
                band.index,
                band["mean"],
                c=colour,
                ls=style,
                lw=1 if style == ":" else 1.5,
                label=label,
            )
            if column == "val_loss" and runs["replicate"].nunique() > 1:
                ax.fill_between(band.index, band["min"], band["max"], color=colour, alpha=0.2, lw=0)
    ax.set(xlabel="epoch", ylabel="gradient MSE", yscale="log", title=title)
    ax.legend(
        fontsize=7,
        title="validation (solid, band: replicates), training (dotted)",
        title_fontsize=7,
    )
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def mse_map_figure(table: pd.DataFrame, splits: pd.DataFrame, path: str | Path, title: str) -> None:
    """Fig. 4A: validation MSE over the gel for each P, the mean over replicates at each coordinate;
    crosses mark replicate 0's training coordinates of that P."""
    plt = pyplot()
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
    means = table.groupby(["P", "point", "x_mm", "y_mm"], as_index=False)["mse"].mean()
    vmin, vmax = np.percentile(means["mse"], [2, 98])
    spread = replicate_summary(table).set_index("P")
    for ax, p in zip(axes.ravel(), fractions, strict=False):
        part = means[means["P"] == p]
        points = ax.scatter(
            part["x_mm"], part["y_mm"], c=part["mse"], cmap="magma", vmin=vmin, vmax=vmax, s=18
        )
        train = splits[
            (splits["split"] == "train") & (splits["min_p"] > 0) & (splits["min_p"] <= p)
        ]
        ax.scatter(train["x_mm"], train["y_mm"], marker="x", c="tab:cyan", s=10, lw=0.8)
        row = spread.loc[p]
        interval = (
            f"\n{row['mean']:.3g} ({row['low']:.3g} to {row['high']:.3g}, "
            f"{int(row['replicates'])} replicates)"
            if row["replicates"] > 1
            else f"\nmean {row['mean']:.3g}"
        )
        ax.set(
            title=f"P = {p} % ({len(train)} training points){interval}",
            aspect="equal",
            xlabel="x (mm)",
            ylabel="y (mm)",
        )
        ax.title.set_fontsize(8)
    for ax in axes.ravel()[len(fractions) :]:
        ax.axis("off")
    fig.colorbar(
        points,
        ax=axes.ravel().tolist(),
        label="validation gradient MSE (replicate mean)",
        shrink=0.8,
    )
    fig.suptitle(title)
    fig.savefig(path)
    plt.close(fig)


def kde_figure(table: pd.DataFrame, path: str | Path, title: str) -> None:
    """Fig. 4B: Gaussian KDEs of each P's validation MSE distribution (mean over replicates, band
    from the lowest to the highest), the replicates' means dashed with their range shaded."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    fractions = sorted(table["P"].unique())
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(fractions)))
    grid = np.linspace(0, np.percentile(table["mse"], 99.5) * 1.1, 400)
    spread = replicate_summary(table).set_index("P")
    for colour, p in zip(colours, fractions, strict=True):
        curves = []
        for _, part in table[table["P"] == p].groupby("replicate"):
            values = part["mse"].to_numpy()
            if values.size > 2 and np.ptp(values) > 0:
                curves.append(gaussian_kde(values)(grid))
        if curves:
            curves = np.array(curves)
            ax.plot(grid, curves.mean(axis=0), c=colour, label=f"P = {p} %")
            if len(curves) > 1:
                ax.fill_between(grid, curves.min(0), curves.max(0), color=colour, alpha=0.2, lw=0)
        row = spread.loc[p]
        ax.axvline(row["mean"], c=colour, ls="--", lw=0.8)
        if row["replicates"] > 1:
            ax.axvspan(row["low"], row["high"], color=colour, alpha=0.12, lw=0)
    ax.set(xlabel="validation gradient MSE", ylabel="density", title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def std_figure(tables: Mapping[str, pd.DataFrame], path: str | Path) -> None:
    """Fig. 4C: standard deviation of validation MSE against P, every scene on one axis (mean over
    replicates, bars from the lowest to the highest replicate)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=120)
    for scene, table in sorted(tables.items()):
        if "replicate" not in table:
            table = table.assign(replicate=0)
        spread = replicate_summary(table, "std")
        ax.errorbar(
            spread["P"],
            spread["mean"],
            yerr=[spread["mean"] - spread["low"], spread["high"] - spread["mean"]],
            fmt="o-",
            capsize=3,
            label=f"{scene} ({int(spread['replicates'].max())} replicates)",
        )
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
    table: pd.DataFrame,
    losses: Mapping[tuple[int, int], pd.DataFrame],
    n_points: int,
    hardware_s: float | None,
) -> pd.DataFrame:
    """Per P: mean validation MSE (mean over replicates, with their lowest and highest), probe
    points, estimated probing hours and measured training minutes per model (mean over replicates)."""
    spread = replicate_summary(table).set_index("P")
    rows = []
    for p in sorted(table["P"].unique()):
        points = subset_size(n_points, int(p))
        minutes = [float(t["seconds"].sum()) / 60 for (q, _), t in losses.items() if q == p]
        rows.append(
            {
                "P": int(p),
                "points": points,
                "mean_mse": float(spread.loc[p, "mean"]),
                "mean_mse_low": float(spread.loc[p, "low"]),
                "mean_mse_high": float(spread.loc[p, "high"]),
                "replicates": int(spread.loc[p, "replicates"]),
                "probing_h": None
                if hardware_s is None
                else round(hardware_s * points / n_points / 3600, 4),
                "training_min": round(float(np.mean(minutes)), 3),
            }
        )
    return pd.DataFrame(rows)


def cost_figure(costs: pd.DataFrame, path: str | Path, title: str) -> None:
    """Validation error against the estimated probing time and the measured training time."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, sharey=True)
    for ax, column, label in zip(
        axes,
        ("probing_h", "training_min"),
        ("estimated probing time (h)", "training time per model (min)"),
        strict=True,
    ):
        ax.errorbar(
            costs[column],
            costs["mean_mse"],
            yerr=[
                costs["mean_mse"] - costs["mean_mse_low"],
                costs["mean_mse_high"] - costs["mean_mse"],
            ],
            fmt="o-",
            capsize=3,
        )
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


@dataclass(frozen=True)
class AblationReading:
    """What one set of an ablation's models says: their validation errors, the spatial blocks
    the paired tests use, the tests, the learning curve and the recommendation."""

    table: pd.DataFrame  # validation_mse.csv
    blocks: pd.Series
    block_mm: float
    tests: pd.DataFrame  # tests.csv
    recommendation: str  # recommendation.txt: the TOST's line, the curve's, how the two compare
    curve: LearningCurve  # learning_curve.csv and .png


def read_ablation(
    models: Mapping[tuple[int, int], str | Path],
    trainset: TrainingSet,
    splits: pd.DataFrame,
    settings: Mapping,
    seed: int,
) -> AblationReading:
    """Score every model (P, replicate) on the validation coordinates, test each P against P = 80,
    fit the learning curve and say how many points to probe. `settings` is the config's `stats`
    section; `seed` the learning curve's bootstrap's."""
    table = ablation_table(models, trainset, splits)
    block_mm = scoring_disc_mm(trainset)
    blocks = spatial_blocks(table, block_mm)
    points_by_p = {p: subset_size(len(splits), p) for p, _ in models}
    readings = read_validation_errors(
        table,
        blocks,
        points_by_p,
        alpha=settings["alpha"],
        margin=settings["equivalence_margin"],
        equivalence_alpha=settings["equivalence_alpha"],
        bootstrap=settings["curve_bootstrap"],
        seed=seed,
    )
    return AblationReading(
        table, blocks, block_mm, readings.tests, readings.text.rstrip("\n"), readings.curve
    )


def write_reading(reading: AblationReading, out: Mapping[str, str | Path], title: str) -> None:
    """validation_mse.csv, tests.csv, recommendation.txt and the learning curve of a reading."""
    reading.table.to_csv(out["validation_mse"], index=False)
    reading.tests.to_csv(out["tests"], index=False, float_format="%.6g")
    Path(out["recommendation"]).write_text(reading.recommendation + "\n")
    curve_table(reading.curve).to_csv(out["learning_curve"], index=False, float_format="%.6g")
    learning_curve_figure(reading.curve, out["learning_curve_figure"], title)
