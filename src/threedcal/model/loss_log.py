"""A training's loss log: losses.csv (one row per epoch or check, with the seconds and learning
rate a convergence curve reads) and its figure."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from threedcal.plotting import pyplot

LOSS_COLUMNS = ("epoch", "step", "train_loss", "val_loss", "seconds", "lr")


def write_losses(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=LOSS_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow(
                {k: (f"{v:.8g}" if isinstance(v, float) else v) for k, v in row.items()}
            )


def plot_losses(path: Path, rows: list[dict], title: str) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=100)
    epochs = [r["epoch"] for r in rows]
    for key, label in (("train_loss", "train"), ("val_loss", "validation")):
        points = [(e, r[key]) for e, r in zip(epochs, rows, strict=True) if math.isfinite(r[key])]
        if points:
            ax.plot(*zip(*points, strict=True), marker="o", ms=3, label=label)
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE of gradients")
    if all(r["train_loss"] > 0 for r in rows):
        ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
