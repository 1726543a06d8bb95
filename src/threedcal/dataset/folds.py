"""Grouped cross-validation folds of an imported scene's frames (docs/explanation/real-data.md).

Presses whose centres lie closer than ``group_fraction`` x their contact radius (and the frames of
one probe coordinate) form a group, and a group never straddles two folds: a nearly repeated press
is never tested against a model that saw its twin. Groups are joined transitively (single
linkage). Each fold's training set (`fold_trainset`, `n_train` images nested: 4 within 8 within
16) and a nested split of a fold's training images (`inner_folds`) come from the same table.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.sparse.csgraph import connected_components

from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.schema import section

FOLD_COLUMNS = ("frame", "image", "group", "fold", "center_x_px", "center_y_px", "contact_px")
# A fold's model needs at least this many training images (and every fold a test image).
MIN_TRAIN_IMAGES = 3


@dataclass(frozen=True)
class CVSettings:
    """The scene's `cv:` section; no defaults of its own (`of` fills them from the config schema)."""

    folds: int
    group_fraction: float
    bootstrap: int
    radius_sigma_px: float
    centre_sigma_px: float
    label_draws: int

    @classmethod
    def of(cls, **settings) -> CVSettings:
        return cls(**section("cv", settings))


# ------------------------------------------------------------------------------------ the folds
def contact_radius_px(ts: TrainingSet) -> np.ndarray:
    """(N,) contact radius of each press in px, from its depth: sqrt(2Rd - d²)."""
    r = ts.sphere_radius_mm
    d = np.minimum(ts.depth_mm, r)
    return np.sqrt(np.maximum(2 * r * d - d * d, 0.0)) * ts.px_per_mm


def press_groups(
    center_px: np.ndarray, contact_px: np.ndarray, fraction: float, point: np.ndarray | None = None
) -> np.ndarray:
    """(N,) group id: presses closer than `fraction` x their mean contact radius, joined transitively.

    Frames of one probe coordinate (`point`) always share a group. Ids are numbered by first frame.
    """
    centres = np.asarray(center_px, dtype=float)
    radius = np.asarray(contact_px, dtype=float)
    n = len(centres)
    if not (math.isfinite(fraction) and fraction >= 0):
        raise ConfigError(f"cv.group_fraction must be a number >= 0, got {fraction!r}")
    distance = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    linked = distance < fraction * 0.5 * (radius[:, None] + radius[None, :])
    if point is not None:
        point = np.asarray(point)
        linked |= point[:, None] == point[None, :]
    return linked_groups(linked) if n else np.zeros(0, dtype=np.int32)


def linked_groups(linked: np.ndarray) -> np.ndarray:
    """(N,) group id of each of N items, given which pairs are linked ((N, N) bool, symmetric):
    linked items share a group, transitively. Ids are numbered by first item."""
    _, labels = connected_components(linked, directed=False)
    # Renumber by first appearance, so ids do not depend on scipy's traversal order.
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(np.argsort(first))
    return order[labels]


def grouped_folds(groups: np.ndarray, folds: int, seed: int, where: str = "dataset") -> np.ndarray:
    """(N,) fold id 0..folds-1: whole groups, folds as equal in size as the groups allow.

    Groups are shuffled (seeded), then placed largest first, each in the fold with the fewest
    images so far. Raises a ConfigError naming `where` when the data cannot make `folds` folds.
    """
    groups = np.asarray(groups)
    n = len(groups)
    if not isinstance(folds, int | np.integer) or folds < 2:
        raise ConfigError(f"cv.folds must be a whole number >= 2, got {folds!r}")
    n_groups = len(np.unique(groups))
    if n < folds or n_groups < folds:
        raise ConfigError(
            f"{where}: {n} labelled image(s) in {n_groups} independent press group(s) cannot make "
            f"{folds} folds (each fold needs its own group); use fewer folds or label more images"
        )
    if n - n / folds < MIN_TRAIN_IMAGES:
        raise ConfigError(
            f"{where}: {n} labelled images leave fewer than {MIN_TRAIN_IMAGES} training images per "
            f"fold with {folds} folds; label more images"
        )
    ids, sizes = np.unique(groups, return_counts=True)
    rng = np.random.default_rng([seed, 0xF01D])
    shuffled = rng.permutation(len(ids))
    order = shuffled[np.argsort(-sizes[shuffled], kind="stable")]
    load = np.zeros(folds, dtype=int)
    fold_of_group = {}
    for g in order:
        target = int(np.argmin(load))
        fold_of_group[ids[g]] = target
        load[target] += sizes[g]
    fold = np.array([fold_of_group[g] for g in groups], dtype=int)
    # A fold far above its share would test many images with a model trained on few.
    if (
        load.min() == 0
        or n - load.max() < MIN_TRAIN_IMAGES
        or load.max() > 2 * math.ceil(n / folds)
    ):
        raise ConfigError(
            f"{where}: the press groups (largest {sizes.max()} of {n} images) cannot be spread over "
            f"{folds} folds; lower cv.group_fraction or cv.folds"
        )
    return fold


def make_folds(
    ts: TrainingSet, settings: CVSettings, seed: int, where: str = "dataset"
) -> pd.DataFrame:
    """The folds table (FOLD_COLUMNS): one row per frame of the model-ready set."""
    contact = contact_radius_px(ts)
    groups = press_groups(ts.center_px, contact, settings.group_fraction, ts.point)
    fold = grouped_folds(groups, settings.folds, seed, where)
    names = (ts.meta or {}).get("names") or [f"frame{i}" for i in range(len(ts.frames))]
    return pd.DataFrame(
        {
            "frame": np.arange(len(groups)),
            "image": names,
            "group": groups,
            "fold": fold,
            "center_x_px": ts.center_px[:, 0],
            "center_y_px": ts.center_px[:, 1],
            "contact_px": contact,
        },
        columns=list(FOLD_COLUMNS),
    )


def read_folds(path: str | Path, ts: TrainingSet) -> pd.DataFrame:
    table = pd.read_csv(path)
    missing = [c for c in FOLD_COLUMNS if c not in table]
    if missing or len(table) != len(ts.frames):
        raise ConfigError(
            f"{path}: not the folds table of this dataset ({len(table)} rows for {len(ts.frames)} "
            f"frames; missing {missing or 'nothing'})"
        )
    return table


def training_images(folds: pd.DataFrame, fold: int, n_train: int | None, seed: int) -> np.ndarray:
    """Frames a fold trains on: all other folds' frames, or the first n_train of a seeded shuffle.

    The shuffle depends on (seed, fold) only, so the subsets are nested (n = 4 within 8 within 16).
    """
    pool = folds.loc[folds["fold"] != fold, "frame"].to_numpy()
    if n_train is None:
        return np.sort(pool)
    if not 1 <= n_train <= len(pool):
        raise ConfigError(
            f"fold {fold}: n_train={n_train} images requested, {len(pool)} training images exist"
        )
    order = np.random.default_rng([seed, fold, 0x5EB5E7]).permutation(pool)
    return np.sort(order[:n_train])


def fold_trainset(
    ts: TrainingSet, folds: pd.DataFrame, fold: int, n_train: int | None = None, seed: int = 0
) -> TrainingSet:
    """A copy of `ts` whose split marks the fold's training frames 'train' (at P = 80) and its test
    frames 'test'; frames outside `folds` or left out of a subset are 'unused'. No frame is 'val':
    training records no validation loss, so nothing about the test fold reaches the model."""
    if fold not in set(folds["fold"]):
        raise ConfigError(f"fold {fold} does not exist (folds: {sorted(set(folds['fold']))})")
    train_frames = training_images(folds, fold, n_train, seed)
    frames = folds["frame"].to_numpy()
    samples = ts.samples.copy()
    split = np.full(len(samples), "unused", dtype=object)
    split[train_frames] = "train"
    split[frames[folds["fold"].to_numpy() == fold]] = "test"
    samples["split"] = split
    samples["min_p"] = np.where(split == "train", 80, 0)
    return dataclasses.replace(ts, samples=samples)


def inner_folds(folds: pd.DataFrame, fold: int, k: int, seed: int) -> pd.DataFrame:
    """The folds table of outer fold `fold`'s training frames only, split again into k grouped folds:
    what a nested choice of settings may look at (never the outer test fold)."""
    inner = folds[folds["fold"] != fold].copy()
    inner["fold"] = grouped_folds(
        inner["group"].to_numpy(), k, seed, where=f"training images of fold {fold}"
    )
    return inner


def write_folds(
    trainset_dir: str | Path, cv: Mapping, seed: int, out_path: str | Path, where: str | None = None
) -> pd.DataFrame:
    """folds.csv of a model-ready set; `where` (the imported folder) names the data in errors."""
    ts = TrainingSet.load(trainset_dir)
    where = where or str(trainset_dir)
    table = make_folds(ts, CVSettings.of(**cv), seed, where)
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out_path, index=False, float_format="%.6g")
    return table
