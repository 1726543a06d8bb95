"""Importers: existing datasets become scenes with no collection stage.

- ball folder: images, background.png, labels.csv
  (image,center_x_px,center_y_px,radius_px), dataset.yaml (px_per_mm, ball_radius_mm, ...);
- py3DCal folder: annotations/{probe_data.csv,annotations.csv,metadata.json}, blank_images/blank.png,
  probe_images/*.png — what the authors' tool writes.

Both load into one in-memory form, :class:`ImportedDataset`: RGB frames, the blank, and per-frame
contact centres (px), depths (mm) and the sphere radius, from which labels are computed exactly.
Every problem is reported with the file and row before anything is written.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.config import load_yaml
from threedcal.errors import ConfigError

BALL_LABEL_COLUMNS = ("image", "center_x_px", "center_y_px", "radius_px")
# Drawn circles include part of the shading halo: evaluate inside 0.9 · min(r_drawn, 0.98 · R_px).
BALL_EVAL_SHRINK = 0.9
BALL_EVAL_RADIUS_CAP = 0.98


@dataclass
class ImportedDataset:
    frames: np.ndarray  # (N, H, W, 3) uint8 RGB
    blank: np.ndarray  # (H, W, 3) uint8 RGB
    names: list[str]  # image file name per frame
    center_px: np.ndarray  # (N, 2) contact centre (column, row)
    depth_mm: np.ndarray  # (N,) indentation depth of the sphere
    px_per_mm: float
    sphere_radius_mm: float
    eval_radius_px: np.ndarray  # (N,) radius inside which labels are trusted
    point: np.ndarray  # (N,) probe coordinate index (frames of one coordinate share it)
    xy_mm: np.ndarray  # (N, 2) probe coordinate in printer mm (NaN when unknown)
    metadata: dict = field(default_factory=dict)


def read_rgb(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ConfigError(f"{path}: missing or not a readable image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        raise ConfigError(f"{path}: missing ({what})")
    return path


def _read_csv(path: Path, columns) -> pd.DataFrame:
    _require(path, "table")
    try:
        table = pd.read_csv(path, comment="#", skipinitialspace=True)
    except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
        raise ConfigError(f"{path}: not a readable CSV ({exc})") from exc
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise ConfigError(
            f"{path}: missing column(s) {', '.join(missing)} (have: {', '.join(table.columns)})"
        )
    return table


def _numeric(table: pd.DataFrame, path: Path, columns, positive=()) -> None:
    for column in columns:
        values = pd.to_numeric(table[column], errors="coerce")
        for row, value in zip(table.index, values, strict=True):
            if not np.isfinite(value) or (column in positive and value <= 0):
                rule = "a positive number" if column in positive else "a finite number"
                raw = table.at[row, column]
                # +2: one for the header line, one because people count rows from 1.
                raise ConfigError(f"{path}, row {row + 2}: {column}={raw!r} must be {rule}")
        table[column] = values


def _check_shapes(
    frames: list[np.ndarray], names: list[str], blank: np.ndarray, folder: Path
) -> None:
    for name, frame in zip(names, frames, strict=True):
        if frame.shape != blank.shape:
            raise ConfigError(
                f"{folder / name}: shape {frame.shape} differs from the blank's {blank.shape}"
            )


def load_ball_folder(folder: str | Path) -> ImportedDataset:
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: not a folder (expected a ball-image dataset)")
    meta_path = _require(folder / "dataset.yaml", "dataset description: px_per_mm, ball_radius_mm")
    meta = load_yaml(meta_path)
    if not isinstance(meta, dict):
        raise ConfigError(f"{meta_path}: must be a mapping")
    for key in ("px_per_mm", "ball_radius_mm"):
        value = meta.get(key)
        if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
            raise ConfigError(f"{meta_path}: {key} must be a positive number, got {value!r}")
    px_per_mm = float(meta["px_per_mm"])
    radius_mm = float(meta["ball_radius_mm"])
    labels_path = folder / str(meta.get("labels", "labels.csv"))
    labels = _read_csv(labels_path, BALL_LABEL_COLUMNS)
    if labels.empty:
        raise ConfigError(f"{labels_path}: no labelled image")
    _numeric(labels, labels_path, BALL_LABEL_COLUMNS[1:], positive=("radius_px",))
    radius_px = radius_mm * px_per_mm
    too_big = labels["radius_px"] >= radius_px
    if too_big.any():
        row = int(np.flatnonzero(too_big)[0])
        raise ConfigError(
            f"{labels_path}, row {row + 2}: radius_px={labels['radius_px'].iloc[row]} is not smaller "
            f"than the ball's radius ({radius_px:.1f} px)"
        )
    blank = read_rgb(
        _require(folder / str(meta.get("background", "background.png")), "blank frame")
    )
    names = [str(n) for n in labels["image"]]
    frames = [read_rgb(folder / name) for name in names]
    _check_shapes(frames, names, blank, folder)
    drawn = labels["radius_px"].to_numpy(float)
    contact_mm = np.minimum(drawn, BALL_EVAL_RADIUS_CAP * radius_px) / px_per_mm
    depth = radius_mm - np.sqrt(radius_mm**2 - contact_mm**2)
    return ImportedDataset(
        frames=np.stack(frames),
        blank=blank,
        names=names,
        center_px=labels[["center_x_px", "center_y_px"]].to_numpy(float),
        depth_mm=depth,
        px_per_mm=px_per_mm,
        sphere_radius_mm=radius_mm,
        eval_radius_px=BALL_EVAL_SHRINK * np.minimum(drawn, BALL_EVAL_RADIUS_CAP * radius_px),
        point=np.arange(len(names)),
        xy_mm=np.full((len(names), 2), np.nan),
        metadata={k: v for k, v in meta.items() if isinstance(v, str | int | float)},
    )


def load_py3dcal_folder(folder: str | Path) -> ImportedDataset:
    """A dataset collected and annotated with py3DCal (its annotate() step must have run)."""
    folder = Path(folder)
    annotations = folder / "annotations"
    meta_path = _require(annotations / "metadata.json", "written by py3DCal's annotate()")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{meta_path}: not valid JSON ({exc})") from exc
    for key in ("px_per_mm", "probe_radius_mm"):
        value = meta.get(key)
        if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
            raise ConfigError(f"{meta_path}: {key} must be a positive number, got {value!r}")
    table_path = annotations / "annotations.csv"
    columns = ("img_name", "x_mm", "y_mm", "penetration_depth_mm", "x_px", "y_px")
    table = _read_csv(table_path, columns)
    # py3DCal writes a "---" row for a point whose capture failed: no image, skip it.
    table = table[table["img_name"].astype(str) != "---"].reset_index(drop=True)
    if table.empty:
        raise ConfigError(f"{table_path}: no annotated probe image")
    _numeric(table, table_path, columns[1:], positive=("penetration_depth_mm",))
    blank = read_rgb(_require(folder / "blank_images" / "blank.png", "blank frame"))
    names = [str(n) for n in table["img_name"]]
    frames = [read_rgb(_require(folder / "probe_images" / n, "probe image")) for n in names]
    _check_shapes(frames, names, blank, folder / "probe_images")
    px_per_mm = float(meta["px_per_mm"])
    radius_mm = float(meta["probe_radius_mm"])
    depth = np.minimum(table["penetration_depth_mm"].to_numpy(float), radius_mm)
    xy = table[["x_mm", "y_mm"]].to_numpy(float)
    _, point = np.unique(xy, axis=0, return_inverse=True)
    contact_px = np.sqrt(2 * radius_mm * depth - depth**2) * px_per_mm
    return ImportedDataset(
        frames=np.stack(frames),
        blank=blank,
        names=names,
        center_px=table[["x_px", "y_px"]].to_numpy(float),
        depth_mm=depth,
        px_per_mm=px_per_mm,
        sphere_radius_mm=radius_mm,
        eval_radius_px=contact_px,
        point=point.reshape(-1),
        xy_mm=xy,
        metadata={
            "source": "py3DCal",
            **{k: v for k, v in meta.items() if isinstance(v, int | float | str)},
        },
    )


IMPORTERS = {"ball_folder": load_ball_folder, "py3dcal": load_py3dcal_folder}


def load_imported(format_name: str, path: str | Path) -> ImportedDataset:
    try:
        loader = IMPORTERS[format_name]
    except KeyError:
        raise ConfigError(
            f"unknown import format {format_name!r} (allowed: {', '.join(IMPORTERS)})"
        ) from None
    return loader(path)
