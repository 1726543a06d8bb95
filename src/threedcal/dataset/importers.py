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

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from threedcal.errors import ConfigError
from threedcal.images import read_rgb
from threedcal.orientation import TURN_KEY, folder_turn, turn_image, turn_points
from threedcal.schema import load_yaml, plain

# pandas (the workflow extra) loads where a table is read
if TYPE_CHECKING:
    import pandas as pd

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


def _member(folder: Path, name: object, where: str, what: str = "image name") -> Path:
    """A file named in a table, which must lie inside `folder` (no absolute paths, no `..`)."""
    text = str(name).strip()
    parts = Path(text).parts
    if not text or Path(text).is_absolute() or ".." in parts or "\x00" in text:
        raise ConfigError(
            f"{where}: {what} {text!r} must be a relative file name inside {folder} "
            "(no absolute path, no '..')"
        )
    return folder / text


def _unique_names(names: list[str], where: str, first_row: int = 2) -> None:
    seen: dict[str, int] = {}
    for row, name in enumerate(names, start=first_row):
        if name in seen:
            raise ConfigError(
                f"{where}, row {row}: image {name!r} is listed again (first on row {seen[name]}); "
                "each image may be labelled once"
            )
        seen[name] = row


def _centres_inside(table: pd.DataFrame, columns, shape, where: str) -> None:
    """A labelled contact's centre (column, row) lies on its image: 0 ≤ x ≤ W − 1, 0 ≤ y ≤ H − 1.
    (py3DCal tables are not held to it: a probe grid may reach past the camera's view.)"""
    height, width = shape[:2]
    xs, ys = (table[c].to_numpy(float) for c in columns)
    bad = np.flatnonzero((xs < 0) | (xs > width - 1) | (ys < 0) | (ys > height - 1))
    if bad.size:
        i = int(bad[0])
        row = i + 2
        raise ConfigError(
            f"{where}, row {row}: contact centre ({columns[0]}={plain(xs[i]):g}, "
            f"{columns[1]}={plain(ys[i]):g}) px lies outside the {width} x {height} px image "
            f"(allowed: 0..{width - 1}, 0..{height - 1})"
        )


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        raise ConfigError(f"{path}: missing ({what})")
    return path


def _read_csv(path: Path, columns) -> pd.DataFrame:
    import pandas as pd  # optional (workflow extra), loaded where a table is read

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
    import pandas as pd  # optional (workflow extra), loaded where a table is read

    for column in columns:
        values = pd.to_numeric(table[column], errors="coerce")
        for row, value in zip(table.index, values, strict=True):
            if not np.isfinite(value) or (column in positive and value <= 0):
                rule = "a positive number" if column in positive else "a finite number"
                raw = plain(table.at[row, column])
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


def _positive_number(meta: dict, key: str, meta_path: Path) -> None:
    """A finite number > 0; YAML's and JSON's `true` is not one, though Python counts it as 1."""
    value = meta.get(key)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise ConfigError(f"{meta_path}: {key} must be a positive number, got {value!r}")


def load_ball_folder(folder: str | Path) -> ImportedDataset:
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: not a folder (expected a ball-image dataset)")
    meta_path = _require(folder / "dataset.yaml", "dataset description: px_per_mm, ball_radius_mm")
    meta = load_yaml(meta_path)
    if not isinstance(meta, dict):
        raise ConfigError(f"{meta_path}: must be a mapping")
    for key in ("px_per_mm", "ball_radius_mm"):
        _positive_number(meta, key, meta_path)
    px_per_mm = float(meta["px_per_mm"])
    radius_mm = float(meta["ball_radius_mm"])
    labels_name = meta.get("labels", "labels.csv")
    if not isinstance(labels_name, str):
        raise ConfigError(
            f"{meta_path}: labels must be the labels table's file name, got {labels_name!r}"
        )
    labels_path = _member(folder, labels_name, f"{meta_path}: labels", "file name")
    labels = _read_csv(labels_path, BALL_LABEL_COLUMNS)
    if labels.empty:
        raise ConfigError(f"{labels_path}: no labelled image")
    _numeric(labels, labels_path, BALL_LABEL_COLUMNS[1:], positive=("radius_px",))
    names = [str(n).strip() for n in labels["image"]]
    paths = [_member(folder, n, f"{labels_path}, row {i + 2}") for i, n in enumerate(names)]
    _unique_names(names, str(labels_path))
    radius_px = radius_mm * px_per_mm
    too_big = labels["radius_px"] >= radius_px
    if too_big.any():
        row = int(np.flatnonzero(too_big)[0])
        raise ConfigError(
            f"{labels_path}, row {row + 2}: radius_px={labels['radius_px'].iloc[row]} is not smaller "
            f"than the ball's radius ({radius_px:.1f} px)"
        )
    background = _member(
        folder, meta.get("background", "background.png"), f"{meta_path}: background"
    )
    blank = read_rgb(_require(background, "blank frame"))
    _centres_inside(labels, ("center_x_px", "center_y_px"), blank.shape, str(labels_path))
    frames = [read_rgb(path) for path in paths]
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
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{meta_path}: not valid JSON ({exc})") from exc
    except OSError as exc:
        raise ConfigError(f"{meta_path}: cannot read ({exc.strerror})") from exc
    if not isinstance(meta, dict):
        raise ConfigError(
            f"{meta_path}: must be a JSON object (px_per_mm, probe_radius_mm, ...), "
            f"got a {type(meta).__name__}"
        )
    for key in ("px_per_mm", "probe_radius_mm"):
        _positive_number(meta, key, meta_path)
    table_path = annotations / "annotations.csv"
    columns = ("img_name", "x_mm", "y_mm", "penetration_depth_mm", "x_px", "y_px")
    table = _read_csv(table_path, columns)
    # py3DCal writes a "---" row for a point whose capture failed: no image, skip it. Rows keep
    # their number in the file (+2: the header, and counting from 1) for messages.
    kept = table["img_name"].astype(str).str.strip() != "---"
    rows = (np.flatnonzero(kept) + 2).tolist()
    table = table[kept].reset_index(drop=True)
    if table.empty:
        raise ConfigError(f"{table_path}: no annotated probe image")
    table.index = np.asarray(rows) - 2
    _numeric(table, table_path, columns[1:], positive=("penetration_depth_mm",))
    table = table.reset_index(drop=True)
    names = [str(n).strip() for n in table["img_name"]]
    images_dir = folder / "probe_images"
    paths = [
        _member(images_dir, n, f"{table_path}, row {r}") for n, r in zip(names, rows, strict=True)
    ]
    seen: dict[str, int] = {}
    for name, row in zip(names, rows, strict=True):
        if name in seen:
            raise ConfigError(
                f"{table_path}, row {row}: image {name!r} is listed again (first on row "
                f"{seen[name]}); each image may be annotated once"
            )
        seen[name] = row
    blank = read_rgb(_require(folder / "blank_images" / "blank.png", "blank frame"))
    frames = [read_rgb(_require(path, "probe image")) for path in paths]
    _check_shapes(frames, names, blank, images_dir)
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


def check_import(format_name: str, path: str | Path) -> None:
    """Everything the import stage would refuse, found now (`threedcal config check`): the folder,
    its description and tables row by row, and every image it names. Nothing is written."""
    if not Path(path).exists():
        raise ConfigError(f"{path}: does not exist (the folder of the dataset to import)")
    load_imported(format_name, path)


def load_imported(
    format_name: str, path: str | Path, orientation: str | None = None
) -> ImportedDataset:
    """The dataset as a sensor of `orientation` (its profile's image.orientation) sees it: frames
    stored on their side are turned a quarter the way its description states (`turn_to_sensor`:
    threedcal.orientation), with their contact centres."""
    try:
        loader = IMPORTERS[format_name]
    except KeyError:
        raise ConfigError(
            f"unknown import format {format_name!r} (allowed: {', '.join(IMPORTERS)})"
        ) from None
    data = loader(path)
    height, width = data.blank.shape[:2]
    where = (
        f"{path}/{'dataset.yaml' if format_name == 'ball_folder' else 'annotations/metadata.json'}"
    )
    turn = folder_turn(height, width, orientation, data.metadata.get(TURN_KEY), where)
    if turn is None:
        return data
    return dataclasses.replace(
        data,
        frames=turn_image(data.frames, axes=(1, 2), turn=turn),
        blank=turn_image(data.blank, turn=turn),
        center_px=turn_points(data.center_px, width, height, turn),
        metadata={**data.metadata, "read_turned": turn},
    )
