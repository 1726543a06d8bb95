"""ReSkin figures: sample readings of a collection, and held-out predictions (like the paper's Fig. 7B)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from threedcal.plotting import pyplot


def _chip_positions_plan(sensor: Mapping) -> np.ndarray:
    """Magnetometer positions in plan-relative mm (the profile gives them from the area's centre)."""
    width, height = sensor["probing"]["plan_area_mm"]
    return np.asarray(sensor["magnetometers"]["positions_mm"], float) + [width / 2, height / 2]


def readings_figure(dataset, sensor: Mapping, path: str | Path, title: str = "") -> None:
    """Top: the change of bx, by, bz of every chip over the run (no-contact mean subtracted).
    Bottom: the largest change at each probe point of the shallowest depth, over the probe area."""
    plt = pyplot()
    names = [str(v) for v in dataset["value"].values]
    readings = dataset["readings"].values.astype(float)
    change = readings - dataset["blank_readings"].values.astype(float).mean(axis=0)
    fig = plt.figure(figsize=(12, 7.5), dpi=110)
    grid = fig.add_gridspec(2, 3, height_ratios=[1, 1.3])
    for column, axis in enumerate(("bx", "by", "bz")):
        ax = fig.add_subplot(grid[0, column])
        for i, name in enumerate(names):
            if name.startswith(axis):
                ax.plot(change[:, i], lw=0.5, label=f"chip {name[len(axis) :]}")
        ax.set(xlabel="reading", ylabel=f"Δ{axis} (µT)", title=f"{axis} − no-contact mean")
        if column == 0:
            ax.legend(fontsize=7, loc="upper right")
    fields = [i for i, name in enumerate(names) if name.startswith("b")]
    depth = dataset["depth_mm"].values
    shallow = np.isclose(depth, depth.min())
    ax = fig.add_subplot(grid[1, 1])
    magnitude = np.abs(change[:, fields]).max(axis=1)
    points = ax.scatter(
        dataset["x_mm"].values[shallow],
        dataset["y_mm"].values[shallow],
        c=magnitude[shallow],
        s=30,
        cmap="magma",
    )
    chips = _chip_positions_plan(sensor)
    ax.scatter(chips[:, 0], chips[:, 1], marker="s", s=80, facecolor="none", edgecolor="tab:blue")
    for i, (x, y) in enumerate(chips):
        ax.annotate(str(i), (x, y), xytext=(5, 5), textcoords="offset points", color="tab:blue")
    fig.colorbar(points, ax=ax, label="largest |Δb| over the chips (µT)")
    ax.set(
        xlabel="plan x (mm)",
        ylabel="plan y (mm)",
        aspect="equal",
        title=f"depth {depth.min():g} mm; squares: magnetometers",
    )
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def eval_figure(
    table,
    errors_mm: np.ndarray,
    metrics: Mapping,
    sensor: Mapping,
    path: str | Path,
    title: str = "",
) -> None:
    """Left (Fig. 7B): held-out probe points — ground truth as circles, the mean prediction of each
    point's readings as a cross, one colour per depth. Right: distribution of per-reading errors."""
    plt = pyplot()
    fig, (ax, ax_cdf) = plt.subplots(
        1, 2, figsize=(12, 5.6), dpi=110, gridspec_kw={"width_ratios": [1.25, 1]}
    )
    depths = sorted(table["depth_mm"].round(4).unique())
    colours = plt.cm.viridis(np.linspace(0.1, 0.85, max(len(depths), 1)))
    width, height = sensor["probing"]["plan_area_mm"]
    ax.add_patch(plt.Rectangle((0, 0), width, height, fill=False, lw=1, ec="0.6", ls="--"))
    for depth, colour in zip(depths, colours, strict=True):
        rows = table[np.isclose(table["depth_mm"], depth)]
        ax.scatter(rows.x_mm, rows.y_mm, s=70, facecolor="none", edgecolor=colour, lw=1.2)
        ax.scatter(
            rows.pred_x_mm, rows.pred_y_mm, s=40, marker="x", color=colour, label=f"{depth:g} mm"
        )
    chips = _chip_positions_plan(sensor)
    ax.scatter(chips[:, 0], chips[:, 1], marker="s", s=60, color="0.75", zorder=0)
    ax.set(
        xlabel="plan x (mm)",
        ylabel="plan y (mm)",
        aspect="equal",
        title="held-out points: truth ○, prediction ×",
    )
    ax.legend(title="depth", fontsize=8)
    errors = np.sort(np.asarray(errors_mm, dtype=float))
    ax_cdf.plot(errors, np.arange(1, len(errors) + 1) / len(errors), color="k")
    for key, style in (("median_error_mm", "--"), ("p90_error_mm", ":")):
        ax_cdf.axvline(metrics[key], ls=style, color="tab:red", label=f"{key} {metrics[key]:.3f}")
    ax_cdf.set(
        xlabel="(x, y) error per held-out reading (mm)",
        ylabel="fraction of readings",
        title=f"depth MAE {metrics['depth_mae_mm']:.3f} mm",
    )
    ax_cdf.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
