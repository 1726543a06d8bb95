"""Train/validation split by probe coordinate, nested P subsets, and the field-of-view filter.

As in the paper, P is a fraction of *all* probe coordinates (P=80 is the whole training set, since
20 % are held out), drawn from the training coordinates, and subsets are nested: every coordinate of
P=5 is also in P=20. Splitting by coordinate (not by frame) keeps the repeated frames of one
indentation on the same side.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError

VALIDATION_FRACTION = 0.2


def subset_size(n_points: int, percent: int) -> int:
    """Coordinates in the P=percent subset: round(P/100 · N), at least one."""
    return max(1, int(round(n_points * percent / 100.0)))


def split_points(
    points: pd.DataFrame,
    fractions: Sequence[int],
    seed: int,
    validation_fraction: float = VALIDATION_FRACTION,
) -> pd.DataFrame:
    """`points` (columns point, x_mm, y_mm; one row per coordinate) → the splits table.

    Columns: point, x_mm, y_mm, split ('train' / 'val'), min_p (smallest P in `fractions` whose
    subset holds the point; 0 for validation points and training points in no subset).
    """
    for column in ("point", "x_mm", "y_mm"):
        if column not in points:
            raise ConfigError(f"split_points: points table lacks column {column!r}")
    if points["point"].duplicated().any():
        raise ConfigError(
            "split_points: each probe coordinate must appear once (duplicate `point`)"
        )
    n = len(points)
    n_val = int(round(n * validation_fraction))
    if n < 2 or n_val < 1 or n_val >= n:
        raise ConfigError(
            f"split_points: {n} probe coordinates are too few for a train/validation split"
        )
    max_train_percent = 100 * (n - n_val) / n
    for p in fractions:
        if not 1 <= p <= 100 or subset_size(n, p) > n - n_val:
            raise ConfigError(
                f"split_points: P={p} % needs {subset_size(n, p)} training coordinates, "
                f"only {n - n_val} exist (P <= {max_train_percent:.0f} %)"
            )
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    val_index, train_index = order[:n_val], order[n_val:]
    table = points[["point", "x_mm", "y_mm"]].reset_index(drop=True).copy()
    table["split"] = "train"
    table.loc[val_index, "split"] = "val"
    table["min_p"] = 0
    # Nested subsets: a prefix of one fixed shuffle of the training coordinates.
    for p in sorted(fractions, reverse=True):
        members = train_index[: subset_size(n, p)]
        table.loc[members, "min_p"] = p
    return table.sort_values("point").reset_index(drop=True)


def subset(table: pd.DataFrame, percent: int) -> pd.DataFrame:
    """Training coordinates of the P=percent subset."""
    chosen = (table["split"] == "train") & (table["min_p"] > 0) & (table["min_p"] <= percent)
    return table[chosen]


def in_field_of_view(x_px, y_px, width: int, height: int, margin_px: float = 0.0) -> np.ndarray:
    """True where a probe centre (pixel coordinates) lies inside the image, `margin_px` from its edge."""
    x = np.asarray(x_px, dtype=float)
    y = np.asarray(y_px, dtype=float)
    lo = -0.5 + margin_px
    return (x >= lo) & (x <= width - 0.5 - margin_px) & (y >= lo) & (y <= height - 0.5 - margin_px)
