"""Collection figures: where the probe pressed (coloured by depth) and a mosaic of sample frames."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.plotting import pyplot


def coverage_figure(plan, sensor: Mapping, path: str | Path, title: str = "") -> None:
    """Probe points over the gel's probe area (plan-relative mm), coloured by commanded depth."""
    plt = pyplot()
    width, height = sensor["probing"]["plan_area_mm"]
    fig, ax = plt.subplots(figsize=(5, 5 * height / width + 0.6), dpi=120)
    ax.add_patch(plt.Rectangle((0, 0), width, height, fill=False, lw=1, ec="0.5", ls="--"))
    phase = plan["phase"] if "phase" in plan else pd.Series("grid", index=plan.index)
    touch, register = phase == "touch", phase == "register"
    grid = plan[phase == "grid"]
    if register.any():
        ax.scatter(
            plan.loc[register, "x_mm"],
            plan.loc[register, "y_mm"],
            marker="+",
            c="0.55",
            s=10,
            lw=0.6,
            label=f"registration presses ({int(register.sum())})",
        )
    points = ax.scatter(grid["x_mm"], grid["y_mm"], c=grid["depth_mm"], s=12, cmap="viridis")
    ax.plot(grid["x_mm"], grid["y_mm"], lw=0.3, c="0.7", zorder=0)  # the serpentine path
    if touch.any():
        places = plan.loc[touch, ["x_mm", "y_mm"]].drop_duplicates()
        steps = int(touch.sum()) // len(places)
        ax.scatter(
            places["x_mm"],
            places["y_mm"],
            marker="x",
            c="red",
            s=40,
            label=f"touch search ({steps} steps each)",
        )
    if touch.any() or register.any():
        ax.legend(loc="upper right", fontsize=7)
    fig.colorbar(points, ax=ax, label="commanded depth (mm)")
    ax.set(
        xlabel="plan x (mm)",
        ylabel="plan y (mm)",
        aspect="equal",
        title=title or f"{len(plan)} probe points",
    )
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def mosaic_figure(dataset, path: str | Path, count: int = 9, title: str = "") -> None:
    """A grid of evenly spaced sample frames with their probe coordinate, plus the blank."""
    plt = pyplot()
    n_frames = dataset.sizes["frame"]
    picks = np.linspace(0, n_frames - 1, min(count - 1, n_frames)).round().astype(int)
    columns = 5
    rows = int(np.ceil((len(picks) + 1) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(columns * 2.0, rows * 2.6), dpi=110)
    axes = np.atleast_1d(axes).ravel()
    axes[0].imshow(dataset["blank_frames"][0].values)
    axes[0].set_title("blank", fontsize=8)
    for ax, i in zip(axes[1:], picks, strict=False):
        ax.imshow(dataset["frames"][int(i)].values)
        ax.set_title(
            f"x={float(dataset.x_mm[i]):.1f} y={float(dataset.y_mm[i]):.1f}\nd={float(dataset.depth_mm[i]):.2f} mm",
            fontsize=7,
        )
    for ax in axes:
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
