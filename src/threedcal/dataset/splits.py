"""Train/validation split by probe coordinate, nested P subsets, and the field-of-view filter.

As in the paper, P is a fraction of *all* probe coordinates (P=80 is the whole training set, since
20 % are held out), drawn from the training coordinates, and subsets are nested: every coordinate of
P=5 is also in P=20. Splitting by coordinate (not by frame) keeps the repeated frames of one
indentation on the same side.

Replicates (`ablation.replicates`) share the validation coordinates, so every model of a study is
scored on the same ones; each replicate draws its own nested subsets from the training coordinates.
Replicate 0 takes them in the order of the split's own shuffle (a study with one replicate is the
single-model study); replicate r >= 1 reshuffles the training coordinates with
numpy.random.default_rng(replicate_seed(seed, r)), the seed its model also trains with.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError
from threedcal.seeds import replicate_seed

VALIDATION_FRACTION = 0.2


def subset_size(n_points: int, percent: int) -> int:
    """Coordinates in the P=percent subset: round(P/100 · N), at least one."""
    return max(1, int(round(n_points * percent / 100.0)))


def min_p_column(replicate: int) -> str:
    """The splits/samples column of replicate r's subsets: min_p for r = 0, min_p_r{r} after."""
    return "min_p" if replicate == 0 else f"min_p_r{replicate}"


def split_points(
    points: pd.DataFrame,
    fractions: Sequence[int],
    seed: int,
    validation_fraction: float = VALIDATION_FRACTION,
    replicates: int = 1,
) -> pd.DataFrame:
    """`points` (columns point, x_mm, y_mm; one row per coordinate) → the splits table.

    Columns: point, x_mm, y_mm, split ('train' / 'val'), min_p (smallest P in `fractions` whose
    subset holds the point; 0 for validation points and training points in no subset), and for
    replicates r = 1 .. R-1 the same of replicate r's subsets in min_p_r{r}.
    """
    if replicates < 1:
        raise ConfigError(f"split_points: replicates must be 1 or more, got {replicates}")
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
    # Nested subsets: a prefix of one shuffle of the training coordinates per replicate.
    for replicate in range(replicates):
        order = train_index
        if replicate > 0:
            order = np.random.default_rng(replicate_seed(seed, replicate)).permutation(
                np.sort(train_index)
            )
        column = min_p_column(replicate)
        table[column] = 0
        for p in sorted(fractions, reverse=True):
            table.loc[order[: subset_size(n, p)], column] = p
    return table.sort_values("point").reset_index(drop=True)


def subset(table: pd.DataFrame, percent: int, replicate: int = 0) -> pd.DataFrame:
    """Training coordinates of replicate r's P=percent subset."""
    column = min_p_column(replicate)
    if column not in table:
        raise ConfigError(
            f"the splits hold no replicate {replicate} (no column {column!r}); "
            "rebuild the dataset with the study's ablation.replicates"
        )
    chosen = (table["split"] == "train") & (table[column] > 0) & (table[column] <= percent)
    return table[chosen]


def in_field_of_view(x_px, y_px, width: int, height: int, margin_px: float = 0.0) -> np.ndarray:
    """True where a probe centre (pixel coordinates) lies inside the image, `margin_px` from its edge."""
    x = np.asarray(x_px, dtype=float)
    y = np.asarray(y_px, dtype=float)
    lo = -0.5 + margin_px
    return (x >= lo) & (x <= width - 0.5 - margin_px) & (y >= lo) & (y <= height - 0.5 - margin_px)
