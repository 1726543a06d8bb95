"""ReSkin readings as a learning problem: baseline-subtracted field values → (x, y, depth) in mm.

The board's absolute values carry each chip's constant offset (Earth's field, hard iron) and the
magnet's rest field; the contact is in the change. So every reading has the mean of the store's
no-contact readings subtracted (the authors' `subtract_no_contact`); temperatures are dropped.
Splits are by probe coordinate (x, y): every depth and repetition of a coordinate lands on the same
side, so a held-out coordinate is one the model has never felt.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.collect.store_read import open_checked
from threedcal.errors import ConfigError


@dataclass
class ReSkinSet:
    inputs: np.ndarray  # (N, F) float32: baseline-subtracted bx, by, bz of every chip (uT)
    targets: np.ndarray  # (N, 3) float32: x_mm, y_mm, depth_mm (plan-relative, commanded)
    point: np.ndarray  # (N,) plan point of each reading
    names: list[str]  # the F input names (bx0, by0, ...)
    baseline: np.ndarray  # (F,) the subtracted no-contact mean

    def subset(self, mask: np.ndarray) -> ReSkinSet:
        return ReSkinSet(
            self.inputs[mask], self.targets[mask], self.point[mask], self.names, self.baseline
        )


def load_readings(store_path: str | Path) -> ReSkinSet:
    """The ReSkin readings of a complete collection store, baseline subtracted."""
    raw = open_checked(store_path)  # whole and checked: every record, every chunk
    if "readings" not in raw:
        raise ConfigError(
            f"{store_path}: holds no ReSkin readings (variables: {', '.join(map(str, raw.data_vars))})"
        )
    if not raw.attrs.get("complete", False):
        raise ConfigError(f"{store_path}: the collection is not complete; rerun `collect` first")
    names = [str(v) for v in raw["value"].values]
    fields = [i for i, name in enumerate(names) if name.startswith("b")]
    if not fields:
        raise ConfigError(f"{store_path}: the readings have no field values (names: {names})")
    readings = raw["readings"].values[:, fields].astype(np.float64)
    baseline = raw["blank_readings"].values[:, fields].astype(np.float64).mean(axis=0)
    targets = np.column_stack([raw[c].values for c in ("x_mm", "y_mm", "depth_mm")])
    return ReSkinSet(
        inputs=(readings - baseline).astype(np.float32),
        targets=targets.astype(np.float32),
        point=raw["point"].values.astype(np.int64),
        names=[names[i] for i in fields],
        baseline=baseline.astype(np.float32),
    )


def split_by_coordinate(
    x_mm: np.ndarray, y_mm: np.ndarray, test_fraction: float, seed: int
) -> np.ndarray:
    """True for readings whose (x, y) coordinate is held out: round(test_fraction · coordinates)
    coordinates drawn without replacement (at least one on each side when there are two or more)."""
    if not 0 < test_fraction < 1:
        raise ConfigError(f"reskin test_fraction must lie in (0, 1), got {test_fraction}")
    keys = np.round(np.column_stack([x_mm, y_mm]).astype(np.float64), 6)
    coords, inverse = np.unique(keys, axis=0, return_inverse=True)
    n = len(coords)
    n_test = min(max(int(round(test_fraction * n)), 1), n - 1) if n > 1 else 0
    rng = np.random.default_rng([int(seed), 0x5C1])
    held = np.zeros(n, dtype=bool)
    held[rng.permutation(n)[:n_test]] = True
    return held[inverse.ravel()]


def splits_table(data: ReSkinSet, test: np.ndarray) -> pd.DataFrame:
    """One row per (x, y) coordinate: x_mm, y_mm, split (train/test), readings."""
    frame = pd.DataFrame(
        {
            "x_mm": np.round(data.targets[:, 0].astype(float), 6),
            "y_mm": np.round(data.targets[:, 1].astype(float), 6),
            "split": np.where(test, "test", "train"),
        }
    )
    table = frame.groupby(["x_mm", "y_mm", "split"]).size().rename("readings").reset_index()
    return table.sort_values(["y_mm", "x_mm"]).reset_index(drop=True)
