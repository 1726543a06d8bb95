"""The `dataset` stage: a scene's raw data (or imported folder) → splits.csv + the model-ready set."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.importers import load_imported
from threedcal.dataset.trainset import TrainingSet, downscale, from_imported


def write_splits(trainset: TrainingSet, path: str | Path, xy_mm=None) -> None:
    samples = trainset.samples.drop_duplicates("point").sort_values("point")
    table = samples[["point", "split", "min_p"]].copy()
    if xy_mm is not None:
        table.insert(1, "x_mm", xy_mm[table["point"].to_numpy(), 0])
        table.insert(2, "y_mm", xy_mm[table["point"].to_numpy(), 1])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False)


def build_imported(
    scene: Mapping, trainset_dir: str | Path, splits_path: str | Path
) -> TrainingSet:
    data = load_imported(scene["import"]["format"], scene["import"]["path"])
    trainset = from_imported(data, seed=scene["seed"])
    trainset.max_slope_deg = float(scene["dataset"]["max_slope_deg"])
    if scene["dataset"].get("refine_labels"):
        from threedcal.dataset.refine import refine_labels

        trainset = refine_labels(trainset)
    trainset = downscale(trainset, int(scene["dataset"]["downscale"]))
    trainset.save(trainset_dir)
    xy = np.full((int(data.point.max()) + 1, 2), np.nan)
    xy[data.point] = data.xy_mm
    write_splits(trainset, splits_path, xy_mm=xy)
    return trainset


def _registration_figure(
    trainset: TrainingSet, samples: list[int], path: str | Path, title: str
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(samples), figsize=(2.4 * len(samples), 3.4), dpi=110)
    for ax, i in zip(np.atleast_1d(axes), samples, strict=True):
        ax.imshow(np.asarray(trainset.frames[i]))
        cx, cy = trainset.center_px[i]
        ax.add_patch(plt.Circle((cx, cy), trainset.eval_radius_px[i], fill=False, ec="white", lw=1))
        ax.plot(cx, cy, "+", c="white", ms=6)
        ax.set_title(f"point {trainset.point[i]}", fontsize=8)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def build_collected(
    scene: Mapping,
    store_path: str | Path,
    trainset_dir: str | Path,
    splits_path: str | Path,
    registration_path: str | Path,
    figure_path: str | Path,
    truth_path: str | Path | None = None,
    progress: bool = True,
    expect_digest: str | None = None,
) -> dict:
    """Raw store → registration (affine + touch height) → exact labels → splits → model-ready set.

    Labels use only what a real user knows: the sphere, the plan and the registration fitted here.
    The bench's hidden truth (simulated scenes) is read only to report the registration's error.
    The store is read back whole and checked first (complete, every point captured, every chunk
    present and readable; `expect_digest`: the frame settings collect/summary.json recorded).
    """
    import json

    from threedcal.collect.plan import dome_sag_mm
    from threedcal.collect.store import open_checked
    from threedcal.config import training_fractions
    from threedcal.dataset.labels import contact_radius_mm
    from threedcal.dataset.registration import estimate_touch, register
    from threedcal.dataset.splits import in_field_of_view, split_points
    from threedcal.profiles import load_profile

    sensor = load_profile("sensor", scene["sensor"])
    radius_mm = float(scene["probe"]["radius_mm"])
    raw = open_checked(store_path, expect_digest)
    frames = raw["frames"]
    height, width = frames.shape[1:3]
    blank = raw["blank_frames"].values.astype(np.float32).mean(axis=0)
    point_of_frame = raw["point"].values
    n_points = int(point_of_frame.max()) + 1
    cmd_xy = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])
    plan_xy = np.column_stack([raw["x_mm"].values, raw["y_mm"].values])
    nominal_depth = raw["depth_mm"].values - dome_sag_mm(sensor, plan_xy[:, 0], plan_xy[:, 1])
    # One contact per point, from the mean of its frames (less noise than any single frame).
    first = np.searchsorted(point_of_frame, np.arange(n_points))
    last = np.searchsorted(point_of_frame, np.arange(n_points), side="right")
    means = [
        np.clip(
            frames[first[p] : last[p]].values.astype(np.float32).mean(axis=0) + 0.5, 0, 255
        ).astype(np.uint8)
        for p in range(n_points)
    ]

    def whole(contact) -> bool:  # the rim and a margin inside the image
        margin = contact.radius_px + 5
        return (
            margin <= contact.x_px <= width - 1 - margin
            and margin <= contact.y_px <= height - 1 - margin
        )

    flat = sensor["gel"].get("dome") is None
    registration = register(
        cmd_xy[first], means, blank, accept=whole, flat_gel=flat, progress=progress
    )
    fit = registration.fit
    inlier_points = np.flatnonzero(fit.inliers)
    estimate = estimate_touch(
        nominal_depth[first][inlier_points],
        np.array([registration.contacts[p].radius_px for p in inlier_points])
        / np.mean(fit.px_per_mm),
        radius_mm,
    )
    touch = estimate.offset_mm
    # Labels for every frame whose probe centre the registration puts inside the image.
    centres = fit.apply(cmd_xy)
    depth = np.clip(nominal_depth + touch, 0.0, None)
    inside = in_field_of_view(centres[:, 0], centres[:, 1], width, height) & (depth > 0)
    keep = np.flatnonzero(inside)
    px_per_mm = float(np.mean(fit.px_per_mm))
    coords = pd.DataFrame({"x_mm": plan_xy[keep, 0], "y_mm": plan_xy[keep, 1]})
    coordinate_id = coords.groupby(["x_mm", "y_mm"], sort=True).ngroup().to_numpy()
    unique = coords.assign(point=coordinate_id).drop_duplicates("point").sort_values("point")
    table = split_points(unique, training_fractions(scene), seed=scene["seed"]).set_index("point")
    samples = pd.DataFrame(
        {
            "frame": keep,
            "point": coordinate_id,
            "center_x_px": centres[keep, 0],
            "center_y_px": centres[keep, 1],
            "depth_mm": depth[keep],
            "eval_radius_px": [contact_radius_mm(radius_mm, d) * px_per_mm for d in depth[keep]],
            "split": table.loc[coordinate_id, "split"].to_numpy(),
            "min_p": table.loc[coordinate_id, "min_p"].to_numpy(),
        }
    )
    trainset = TrainingSet(
        frames=frames.values[keep],
        blank=blank,
        samples=samples.assign(frame=np.arange(len(keep))),
        px_per_mm=px_per_mm,
        sphere_radius_mm=radius_mm,
        max_slope_deg=float(scene["dataset"]["max_slope_deg"]),
        meta={"source": "collected", "store_frames": keep.tolist()},
    )
    trainset = downscale(trainset, int(scene["dataset"]["downscale"]))
    trainset.save(trainset_dir)
    xy = unique[["x_mm", "y_mm"]].to_numpy()
    write_splits(trainset, splits_path, xy_mm=xy)

    linear = fit.matrix[:, :2]
    record = {
        "affine_px_per_mm": fit.matrix.round(9).tolist(),
        "residual_px": round(fit.residual_px, 4),
        "px_per_mm": [round(v, 5) for v in fit.px_per_mm],
        "rotation_deg": round(float(np.degrees(np.arctan2(linear[1, 0], linear[0, 0]))), 4),
        "contacts_found": int(sum(c is not None for c in registration.contacts)),
        "contacts_used": int(fit.inliers.sum()),
        "locator": registration.locator,
        "residual_px_by_locator": {k: round(v, 4) for k, v in registration.residual_px.items()},
        "channel_unmixing": None
        if registration.unmixing is None
        else registration.unmixing.round(4).tolist(),
        "touch_offset_mm": round(touch, 4),
        "contact_z_mm": round(float(sensor["mount"]["z_touch_mm"]) + touch, 4),
        "rim_edge_offset_mm": None if estimate.edge_mm is None else round(estimate.edge_mm, 4),
        "frames_in_view": int(len(keep)),
        "probe_points_in_view": int(len(unique)),
    }
    if truth_path is not None and Path(truth_path).is_file():
        truth = json.loads(Path(truth_path).read_text())
        if "affine_px_per_mm" in truth:
            true_affine = np.asarray(truth["affine_px_per_mm"])
            probe = np.unique(cmd_xy[inside], axis=0)
            true_px = probe @ true_affine[:, :2].T + true_affine[:, 2]
            error = np.linalg.norm(fit.apply(probe) - true_px, axis=1)
            record["error_px"] = round(float(np.sqrt(np.mean(error**2))), 4)
            record["error_px_max"] = round(float(error.max()), 4)
            record["touch_offset_error_mm"] = round(touch - float(truth["touch_offset_mm"]), 4)
    Path(registration_path).write_text(json.dumps(record, indent=2) + "\n")
    picks = (
        np.linspace(0, len(trainset.samples) - 1, min(5, len(trainset.samples))).round().astype(int)
    )
    _registration_figure(
        trainset,
        list(picks),
        figure_path,
        f"registration: residual {fit.residual_px:.2f} px, touch offset {touch:+.3f} mm",
    )
    return record
