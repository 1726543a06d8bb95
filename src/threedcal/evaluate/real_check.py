"""Real frames read by the shipped weights: depth only where the ball is?

For a folder of real ball presses (images, background.png, dataset.yaml; labels.csv optional) the
frames are read in the orientation of the weights' frame, which is the sensor profile's (turned a
quarter where the folder stores them on their side: threedcal.orientation), pooled to the weights'
size (threedcal.dataset.reframe) and read with the folder's own blank. Each frame gives
(threedcal.model.contact_guard):

- its contact area against the ball's physical bound πR²;
- its contact centroid against the located contact: a labelled folder's circles refined from the
  images, as the dataset stage refines them (threedcal.dataset.refine); in an unlabelled folder,
  the contact the dataset stage's locator finds in the frame minus the blank
  (threedcal.dataset.contacts.locate_contact), and no centroid where it finds none;
- its peak depth against what the press allows: the cap depth of the located contact's radius
  (never more than the ball's radius).

The frames are split into two halves by place (threedcal.realism.folder.split_halves, seed 0: the
realism check's and the fitted optics' split). A quick fine-tune of the weights trains on the
first half only; both read the second.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.importers import load_imported
from threedcal.dataset.refine import refine_labels
from threedcal.dataset.reframe import reframe
from threedcal.dataset.trainset import TrainingSet, from_imported, samples_table
from threedcal.errors import ConfigError
from threedcal.evaluate.sim2real import shipped_settings
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.contact_guard import contact_figures
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import train
from threedcal.orientation import orientation_of
from threedcal.pretrained import provenance, shipped_weights
from threedcal.realism.check import load_ball_dataset
from threedcal.realism.folder import split_halves

SPLIT_SEED = 0  # the realism check's split: the DIGIT optics were fitted on half 0
FIT, CHECK = "fit", "check"


def load_real_set(
    folder: str | Path, orientation: str | None = None, seed: int = SPLIT_SEED
) -> tuple:
    """(TrainingSet at the folder's own size, turned into the sensor's `orientation` where it is
    stored on its side; how its contacts were located): split 'train' is the fitting half, 'val'
    the other."""

    folder = Path(folder)
    data = load_ball_dataset(folder, orientation)
    fit, _ = split_halves(data.labels, seed, where=str(folder))
    fit_names = {label.image for label in fit}
    if data.labelled:
        ts = refine_labels(from_imported(load_imported("ball_folder", folder, orientation), seed))
        names = list(ts.meta["names"])
        located = "labels.csv, refined from the images (threedcal.dataset.refine)"
    else:
        ts = _located_set(folder, data)
        names = list(ts.meta["names"])
        located = (
            "the dataset stage's contact locator (threedcal.dataset.contacts.locate_contact); "
            f"{int(ts.samples['located'].sum())} of {len(names)} frames"
        )
    in_fit = np.isin(names, sorted(fit_names))
    samples = ts.samples.assign(
        split=np.where(in_fit, "train", "val"), min_p=np.where(in_fit, 80, 0)
    )
    return dataclasses.replace(ts, samples=samples), located


def _located_set(folder: Path, data):
    """An unlabelled folder's frames, each contact where the dataset stage's locator finds a whole
    one (column `located`); elsewhere the realism check's (threedcal.realism.check.locate_ball),
    for its radius only: such a frame's centroid is not scored."""

    blank = data.read("background.png")
    r_mm, px = data.ball_radius_mm, data.px_per_mm
    names = [label.image for label in data.labels]
    frames = np.stack([data.read(name) for name in names])
    centres, radii, found = [], [], []
    for frame, label in zip(frames, data.labels, strict=True):
        contact = locate_contact(frame, blank)
        found.append(contact is not None)
        centres.append(label.center_px if contact is None else (contact.x_px, contact.y_px))
        radii.append(label.radius_px if contact is None else contact.radius_px)
    a_mm = np.minimum(np.asarray(radii) / px, r_mm)
    depth = r_mm - np.sqrt(r_mm * r_mm - a_mm * a_mm)
    n = len(names)
    samples = samples_table(np.arange(n), centres, depth, a_mm * px, ["val"] * n, [0] * n)
    return TrainingSet(
        frames=frames,
        blank=blank.astype(np.float32),
        samples=samples.assign(located=found),
        px_per_mm=px,
        sphere_radius_mm=r_mm,
        meta={"source": str(folder), "names": names},
    )


def allowed_depth_mm(ts) -> np.ndarray:
    """Per frame, the deepest a ball of the set's radius can press and leave its located contact:
    the cap depth of that contact's radius."""
    return np.minimum(ts.samples["depth_mm"].to_numpy(float), ts.sphere_radius_mm)


def read_frames(ts, model_path: str | Path, frames: Sequence[int], threads: int = 1):
    """Per frame: depth (mm) in the model's frame, the set brought there, and px/mm there."""

    torch.set_num_threads(int(threads))
    checkpoint = read_checkpoint(model_path)
    shape = tuple(checkpoint.get("image_shape") or np.shape(checkpoint["blank"])[:2])
    framed, _ = reframe(ts, shape, f"{model_path}")
    estimator = DepthEstimator(
        checkpoint, device="cpu", blank=framed.blank, px_per_mm=framed.px_per_mm
    )
    frames = [int(f) for f in frames]
    depth = estimator.depth(np.asarray(framed.frames)[frames]) if frames else np.zeros((0, *shape))
    return depth, framed


def frame_rows(ts, model_path: str | Path, frames: Sequence[int], threads: int = 1) -> pd.DataFrame:
    """One row per frame: area_px, bound_px, area_ratio, within_bound, centroid_error_mm,
    peak_mm, allowed_mm, peak_within."""

    depth, framed = read_frames(ts, model_path, frames, threads)
    allowed = allowed_depth_mm(ts)
    located = ts.samples["located"].to_numpy(bool) if "located" in ts.samples else None
    rows = []
    for k, frame in enumerate(frames):
        figures = contact_figures(depth[k], framed.sphere_radius_mm, framed.px_per_mm)
        cx, cy = framed.center_px[int(frame)]
        error_px = math.hypot(figures.centroid_x_px - cx, figures.centroid_y_px - cy)
        if located is not None and not located[int(frame)]:
            error_px = math.nan  # no contact the dataset stage would locate: not scored
        rows.append(
            {
                "frame": int(frame),
                "area_px": figures.area_px,
                "bound_px": round(figures.bound_px, 1),
                "area_ratio": figures.area_ratio,
                "within_bound": figures.area_px <= figures.bound_px,
                "centroid_error_mm": error_px / framed.px_per_mm,
                "peak_mm": figures.peak_mm,
                "allowed_mm": float(allowed[int(frame)]),
                "peak_within": bool(figures.peak_mm <= allowed[int(frame)] + PEAK_SLACK_MM),
            }
        )
    return pd.DataFrame(rows)


# The located contact's radius is measured to about a pixel; its cap depth moves by up to this much
# for a pixel of radius near the ball's edge (2.35 mm ball at 19.6 px/mm): peaks that deep pass.
PEAK_SLACK_MM = 0.1


def quick_finetune(
    ts,
    weights: str | Path,
    record: Mapping,
    out_dir: str | Path,
    steps: int,
    lr: float,
    seed: int,
    threads: int,
    progress: bool = False,
) -> Path:
    """The weights fine-tuned on the fitting half ('train') in their own frame, as the quick
    calibration fine-tunes them: one cosine cycle of `steps` at `lr`, nothing held out."""

    if steps < 1:
        raise ConfigError(f"real_check.finetune_steps must be >= 1, got {steps}")
    framed, _ = reframe(ts, tuple(record["image_shape"]), "real_check")
    settings = shipped_settings(record, lr, seed, threads, weights)
    fixed = {"rule": "doubling", "holdout": 0.0, "first_cycle": steps, "min_gain": 0.0}
    settings = dataclasses.replace(settings, stopping={**fixed, "max_steps": int(steps)})
    train(framed, out_dir, 80, settings, progress)
    return Path(out_dir) / "model.pt"


def table_figures(rows: pd.DataFrame) -> dict:
    """The per-frame rows of one (set, weights, half) reduced to the table's figures."""
    ratio = rows["area_ratio"].to_numpy(float)
    error = rows["centroid_error_mm"].to_numpy(float)
    scored = error[np.isfinite(error)]
    return {
        "frames": int(len(rows)),
        "within_bound": float(rows["within_bound"].mean()) if len(rows) else math.nan,
        "area_ratio_median": float(np.median(ratio)) if len(rows) else math.nan,
        "area_ratio_p90": float(np.percentile(ratio, 90)) if len(rows) else math.nan,
        "centroid_error_mm_median": float(np.median(scored)) if scored.size else math.nan,
        "centroid_error_mm_p90": float(np.percentile(scored, 90)) if scored.size else math.nan,
        "centroid_frames": int(scored.size),
        "centroid_within_0p2mm": float(np.mean(scored <= 0.2)) if scored.size else math.nan,
        "peak_mm_median": float(rows["peak_mm"].median()) if len(rows) else math.nan,
        "allowed_mm_median": float(rows["allowed_mm"].median()) if len(rows) else math.nan,
        "peak_within": float(rows["peak_within"].mean()) if len(rows) else math.nan,
    }


TABLE_COLUMNS = (
    "set",
    "sensor",
    "weights",
    "frames_read",
    "located",
    "frames",
    "within_bound",
    "area_ratio_median",
    "area_ratio_p90",
    "centroid_error_mm_median",
    "centroid_error_mm_p90",
    "centroid_frames",
    "centroid_within_0p2mm",
    "peak_mm_median",
    "allowed_mm_median",
    "peak_within",
)
SHIPPED, FINETUNED = "shipped", "shipped, fine-tuned on the fitting half"


def check_sets(
    sets: Sequence[Mapping],
    work_dir: str | Path,
    finetune_steps: int,
    finetune_lr: float,
    seed: int,
    threads: int,
    weights_dir: Path | None = None,
    progress: bool = False,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(table, per-frame rows) of every {real, sensor} set: the shipped weights on all its frames
    and on the held-out half; where it has labels, those weights fine-tuned on its fitting half
    (`finetune_steps`; 0: none) on the held-out half."""

    table, frames = [], []
    for entry in sets:
        real, sensor = str(entry["real"]), str(entry["sensor"])
        record = provenance(sensor, weights_dir)
        # the weights' frame is the profile's, in which they were trained
        ts, located = load_real_set(real, orientation_of(*record["image_shape"]))
        weights = shipped_weights(sensor, None, weights_dir)
        models = [(SHIPPED, weights)]
        labelled = (Path(real) / "labels.csv").is_file()
        if labelled and finetune_steps > 0:
            out = Path(work_dir) / Path(real).name
            tuned = quick_finetune(
                ts, weights, record, out, finetune_steps, finetune_lr, seed, threads, progress
            )
            models.append((FINETUNED, tuned))
        held_out = np.flatnonzero(ts.split == "val")
        for name, path in models:
            rows = frame_rows(ts, path, range(len(ts.frames)), threads)
            rows.insert(0, "half", np.where(ts.split == "train", FIT, CHECK))
            rows.insert(0, "weights", name)
            rows.insert(0, "set", real)
            frames.append(rows)
            reads = [("held-out half", rows.iloc[held_out])]
            if name == SHIPPED:
                reads.append(("all", rows))
            for which, chosen in reads:
                table.append(
                    {
                        "set": real,
                        "sensor": sensor,
                        "weights": name,
                        "frames_read": which,
                        "located": located,
                        **table_figures(chosen),
                    }
                )
    return pd.DataFrame(table, columns=list(TABLE_COLUMNS)), pd.concat(frames, ignore_index=True)
