"""Cross-validated accuracy on an imported scene's real frames: scores, intervals, label noise.

Protocol (docs/explanation/real-data.md):

- Every image is tested exactly once: k folds, each fold's model trained on the other folds' images.
- Presses whose centres lie closer than ``group_fraction`` x their contact radius (and the frames of
  one probe coordinate) form a group, and a group never straddles two folds: a nearly repeated press
  is never tested against a model that saw its twin. Groups are joined transitively (single
  linkage); on the real GelSight set a whole contact radius chains all 42 presses into one group,
  so the default fraction is a quarter of it (0.5 mm there), where the largest group holds 5.
- Figures are pooled over all test images (gradient RMSE = sqrt of the mean per-image MSE; cap
  depth MAE = mean of per-image MAEs) with a 95 % percentile interval from a bootstrap that
  resamples press *groups* (neighbouring presses are not independent), and listed per fold.
- Label uncertainty: the hand-drawn contact radius and centre are perturbed by their standard
  deviation (``radius_sigma_px``, ``centre_sigma_px``) ``label_draws`` times and the figures
  recomputed against each perturbed truth with the same predictions: the spread says how far the
  figures could move with other, equally plausible labels.

The folds are threedcal.dataset.folds'. Training subsets and variants plug in through its
`fold_trainset` (``n_train``: the first n of a fixed shuffle of a fold's training images, nested: 4
within 8 within 16) and the method settings (``init`` = a checkpoint to fine-tune from): the same
folds score every variant.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from threedcal.dataset.folds import (
    CVSettings,
    contact_radius_px,
    fold_trainset,
    inner_folds,
    read_folds,
)
from threedcal.dataset.labels import sphere_depth, sphere_gradients
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import TrainSettings, train
from threedcal.plotting import pyplot

IMAGE_COLUMNS = (
    "method",
    "frame",
    "image",
    "group",
    "fold",
    "gradient_mse",
    "cap_depth_mae_um",
    "cap_depth_bias_um",
    "cap_shape_mae_um",
    "nearest_train_px",
)
METRICS = ("gradient_rmse", "cap_depth_mae_um")


# ------------------------------------------------------------------------------- scoring images
@dataclass
class Truth:
    """What a test image is scored against: contact centre (px), depth (mm), evaluation radius (px)."""

    center_px: np.ndarray  # (N, 2)
    depth_mm: np.ndarray  # (N,)
    eval_radius_px: np.ndarray  # (N,)

    @classmethod
    def of(cls, ts: TrainingSet) -> Truth:
        return cls(ts.center_px.copy(), ts.depth_mm.copy(), ts.eval_radius_px.copy())


def image_errors(
    grads: np.ndarray, depth: np.ndarray, ts: TrainingSet, i: int, truth: Truth
) -> tuple[float, float, float, float]:
    """(gradient MSE, cap depth MAE µm, bias µm, shape MAE µm) of one image inside its evaluation disc.

    The shape MAE is the depth MAE after removing the mean error inside the disc: inside the
    contact, caps of one sphere differ only by a constant, so it does not depend on the labelled
    radius (the depth label's most uncertain part) — only on the centre.
    """
    height, width = ts.image_shape
    cx, cy = truth.center_px[i]
    rows = np.arange(height)[:, None]
    cols = np.arange(width)[None, :]
    mask = (cols - cx) ** 2 + (rows - cy) ** 2 <= truth.eval_radius_px[i] ** 2
    if not mask.any():
        return math.nan, math.nan, math.nan, math.nan
    label = sphere_gradients(
        ts.image_shape,
        (cx, cy),
        ts.sphere_radius_mm,
        float(truth.depth_mm[i]),
        ts.px_per_mm,
        ts.max_slope_deg,
    )
    cap = sphere_depth(
        ts.image_shape, (cx, cy), ts.sphere_radius_mm, float(truth.depth_mm[i]), ts.px_per_mm
    )
    error = depth[mask] - cap[mask]
    return (
        float(np.mean((grads[mask] - label[mask]) ** 2)),
        1000.0 * float(np.mean(np.abs(error))),
        1000.0 * float(np.mean(error)),
        1000.0 * float(np.mean(np.abs(error - error.mean()))),
    )


def perturbed_truth(ts: TrainingSet, settings: CVSettings, rng: np.random.Generator) -> Truth:
    """The labels moved by their uncertainty: contact radius +N(0, σr), centre +N(0, σc) per axis.

    Depth follows the radius through a = sqrt(2Rd - d²) (capped at 0.98 R, as the importer caps
    it) and the evaluation radius keeps its ratio to the contact radius.
    """
    truth = Truth.of(ts)
    n = len(truth.depth_mm)
    contact = contact_radius_px(ts)
    ball_px = ts.sphere_radius_mm * ts.px_per_mm
    moved = np.clip(contact + rng.normal(0.0, settings.radius_sigma_px, n), 1.0, 0.98 * ball_px)
    ratio = np.divide(truth.eval_radius_px, contact, out=np.ones(n), where=contact > 0)
    a_mm = moved / ts.px_per_mm
    r = ts.sphere_radius_mm
    truth.depth_mm = r - np.sqrt(r * r - a_mm * a_mm)
    truth.eval_radius_px = ratio * moved
    truth.center_px = truth.center_px + rng.normal(0.0, settings.centre_sigma_px, (n, 2))
    return truth


# ------------------------------------------------------------------------------- aggregating
def pooled(table: pd.DataFrame) -> dict[str, float]:
    """Gradient RMSE (sqrt of the mean per-image MSE) and cap depth MAE (mean per image)."""
    out = {
        "gradient_rmse": float(np.sqrt(table["gradient_mse"].mean())),
        "cap_depth_mae_um": float(table["cap_depth_mae_um"].mean()),
    }
    for column in ("cap_depth_bias_um", "cap_shape_mae_um"):
        if column in table:
            out[column] = float(table[column].mean())
    return out


def group_bootstrap(
    tables: Mapping[str, pd.DataFrame], resamples: int, seed: int
) -> dict[str, dict[str, np.ndarray]]:
    """Per method, the pooled figures over `resamples` resamplings of the press groups.

    Every method is resampled with the same groups, so differences between methods are paired.
    """
    first = next(iter(tables.values()))
    groups = np.unique(first["group"])
    rng = np.random.default_rng([seed, 0xB007])
    picks = rng.integers(0, len(groups), (resamples, len(groups)))
    out = {}
    for name, table in tables.items():
        index = {g: np.flatnonzero(table["group"].to_numpy() == g) for g in groups}
        mse = table["gradient_mse"].to_numpy()
        mae = table["cap_depth_mae_um"].to_numpy()
        grads, depths = np.empty(resamples), np.empty(resamples)
        for b, pick in enumerate(picks):
            rows = np.concatenate([index[groups[g]] for g in pick])
            grads[b] = np.sqrt(mse[rows].mean())
            depths[b] = mae[rows].mean()
        out[name] = {"gradient_rmse": grads, "cap_depth_mae_um": depths}
    return out


def interval(values: np.ndarray) -> list[float]:
    lo, hi = np.percentile(values, [2.5, 97.5])
    return [float(lo), float(hi)]


def summarise(
    tables: Mapping[str, pd.DataFrame],
    label_draws: Mapping[str, pd.DataFrame],
    settings: CVSettings,
    seed: int,
) -> dict[str, dict]:
    """Per method: pooled figures, 95 % group-bootstrap interval, per-fold figures, label spread."""
    boot = group_bootstrap(tables, settings.bootstrap, seed)
    out = {}
    for name, table in tables.items():
        figures = pooled(table)
        per_fold = [
            {"fold": int(f), "n_test_images": int(len(part)), **pooled(part)}
            for f, part in table.groupby("fold")
        ]
        draws = label_draws.get(name)
        result = {
            **figures,
            "n_test_images": int(len(table)),
            "interval95": {m: interval(boot[name][m]) for m in METRICS},
            "folds": per_fold,
        }
        if draws is not None and len(draws):
            result["label_uncertainty"] = {
                m: {"mean": float(draws[m].mean()), "interval95": interval(draws[m].to_numpy())}
                for m in METRICS
            }
        out[name] = result
    if "lookup" in tables:
        for name in tables:
            if name == "lookup":
                continue
            out[name]["versus_lookup"] = {
                m: {
                    "difference": out[name][m] - out["lookup"][m],
                    "interval95": interval(boot[name][m] - boot["lookup"][m]),
                }
                for m in METRICS
            }
    return out


def nearest_training_distance(folds: pd.DataFrame) -> np.ndarray:
    """(N,) distance (px) from each press to the nearest press its fold's model trained on."""
    centres = folds[["center_x_px", "center_y_px"]].to_numpy(float)
    fold = folds["fold"].to_numpy()
    distance = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    distance[fold[:, None] == fold[None, :]] = np.inf
    return distance.min(axis=1)


def label_spread_from_duplicates(
    folds: pd.DataFrame, radius_drawn_px: np.ndarray, within_px: float = 3.0
) -> dict:
    """Radius disagreement of presses (nearly) at one place: an upper bound of hand-label noise.

    Two presses whose centres lie within `within_px` were very likely the same press; their drawn
    radii should agree. sigma = RMS difference / sqrt(2) (an upper bound: the depths may differ).
    """
    centres = folds[["center_x_px", "center_y_px"]].to_numpy(float)
    n = len(centres)
    diffs = [
        radius_drawn_px[i] - radius_drawn_px[j]
        for i in range(n)
        for j in range(i + 1, n)
        if math.hypot(*(centres[i] - centres[j])) <= within_px
    ]
    if not diffs:
        return {"pairs": 0, "within_px": within_px, "radius_sigma_px": None}
    rms = float(np.sqrt(np.mean(np.square(diffs))))
    return {"pairs": len(diffs), "within_px": within_px, "radius_sigma_px": rms / math.sqrt(2)}


def score_methods(
    ts: TrainingSet,
    folds: pd.DataFrame,
    predictions: Mapping[str, Mapping[int, tuple[np.ndarray, np.ndarray]]],
    settings: CVSettings,
    seed: int,
) -> tuple[dict[str, pd.DataFrame], dict[str, pd.DataFrame]]:
    """Per method, the per-image table (IMAGE_COLUMNS) and the pooled figures of each label draw.

    `predictions[method][frame]` = (gradients (H, W, 2), depth (H, W) mm) of the frame, predicted
    by the model of the fold that held it out.
    """
    nearest = nearest_training_distance(folds)
    truth = Truth.of(ts)
    tables, draws = {}, {}
    rng_draws = [
        perturbed_truth(ts, settings, np.random.default_rng([seed, 0x1AB, k]))
        for k in range(settings.label_draws)
    ]
    for method, frames in predictions.items():
        rows, per_draw = [], []
        for frame in folds["frame"]:
            grads, depth = frames[int(frame)]
            mse, mae, bias, shape = image_errors(grads, depth, ts, int(frame), truth)
            rows.append(
                {
                    "method": method,
                    "frame": int(frame),
                    "image": folds.at[frame, "image"],
                    "group": int(folds.at[frame, "group"]),
                    "fold": int(folds.at[frame, "fold"]),
                    "gradient_mse": mse,
                    "cap_depth_mae_um": mae,
                    "cap_depth_bias_um": bias,
                    "cap_shape_mae_um": shape,
                    "nearest_train_px": float(nearest[frame]),
                }
            )
        for perturbed in rng_draws:
            errs = np.array(
                [image_errors(*frames[int(f)], ts, int(f), perturbed)[:2] for f in folds["frame"]]
            )
            per_draw.append(
                {
                    "gradient_rmse": float(np.sqrt(np.nanmean(errs[:, 0]))),
                    "cap_depth_mae_um": float(np.nanmean(errs[:, 1])),
                }
            )
        tables[method] = pd.DataFrame(rows, columns=list(IMAGE_COLUMNS))
        draws[method] = pd.DataFrame(per_draw, columns=list(METRICS))
    return tables, draws


def cv_figure(
    tables: Mapping[str, pd.DataFrame], summary: Mapping, path: str | Path, title: str
) -> None:
    """Per-image errors of every method (dots) with the pooled figure and its 95 % interval (bar)."""
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, layout="constrained")
    names = list(tables)
    for ax, metric, column, label in (
        (axes[0], "gradient_rmse", "gradient_mse", "gradient RMSE"),
        (axes[1], "cap_depth_mae_um", "cap_depth_mae_um", "cap depth MAE (µm)"),
    ):
        for x, name in enumerate(names):
            values = tables[name][column].to_numpy()
            values = np.sqrt(values) if column == "gradient_mse" else values
            jitter = np.linspace(-0.15, 0.15, len(values))
            ax.scatter(x + jitter, values, s=8, alpha=0.5, color="grey")
            lo, hi = summary[name]["interval95"][metric]
            centre = summary[name][metric]
            ax.errorbar(
                x, centre, yerr=[[centre - lo], [hi - centre]], fmt="o", color="C3", capsize=4
            )
        ax.set_xticks(range(len(names)), names)
        ax.set_ylabel(label)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def train_fold_methods(
    trainset_dir: str | Path,
    folds_path: str | Path,
    fold: int,
    methods: Mapping[str, Mapping],
    seed: int,
    threads: int,
    out_dirs: Mapping[str, str | Path],
    progress: bool = True,
) -> dict[str, dict]:
    """One fold's model of every method (name -> `model:` settings) into out_dirs[name]
    (model.pt, losses.csv), each trained on the images outside the fold: one job for the fold, so
    the set, its folds and the libraries are loaded once, not once a method."""
    ts = TrainingSet.load(trainset_dir)
    subset = fold_trainset(ts, read_folds(folds_path, ts), fold, None, seed)
    out = {}
    for name, model in methods.items():
        settings = TrainSettings.of(seed=seed, torch_threads=threads, **dict(model))
        out[name] = train(subset, out_dirs[name], 80, settings, progress)
    return out


def predict_held_out(
    ts: TrainingSet, folds: pd.DataFrame, models: Sequence[str | Path], threads: int
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """frame -> (gradients, depth) from the model of the fold that held the frame out."""

    torch.set_num_threads(threads)
    out = {}
    for fold, path in enumerate(models):
        estimator = DepthEstimator.from_checkpoint(path, device="cpu")
        for frame in folds.loc[folds["fold"] == fold, "frame"]:
            image = np.asarray(ts.frames[int(frame)])
            grads = estimator.gradients(image)
            out[int(frame)] = (grads, _integrate(grads, ts.px_per_mm))
    return out


def _integrate(grads: np.ndarray, px_per_mm: float) -> np.ndarray:
    return integrate(grads[..., 0], grads[..., 1], px_per_mm=px_per_mm)


def protocol(folds: pd.DataFrame, settings: CVSettings, seed: int) -> dict:
    """How the figures were made, for ball_eval.json."""
    sizes = folds.groupby("group").size()
    return {
        "folds": settings.folds,
        "fold_sizes": folds.groupby("fold").size().astype(int).tolist(),
        "group_fraction": settings.group_fraction,
        "groups": int(len(sizes)),
        "largest_group": int(sizes.max()),
        "min_nearest_train_px": float(nearest_training_distance(folds).min()),
        "interval": f"95 % percentile bootstrap over press groups, {settings.bootstrap} resamples",
        "label_uncertainty": (
            f"{settings.label_draws} draws: contact radius +N(0, {settings.radius_sigma_px} px), "
            f"centre +N(0, {settings.centre_sigma_px} px) per axis; same predictions"
        ),
        "seed": seed,
    }


def error_sources(
    ts: TrainingSet, folds: pd.DataFrame, frames: Mapping[int, tuple[np.ndarray, np.ndarray]]
) -> dict[str, float]:
    """Where a method's cap depth error comes from: the same MAE (µm) with parts of the field swapped.

    - ``as_predicted``: the predicted gradients integrated over the whole frame (the figure);
    - ``integration_only``: the label gradients integrated (the solver and the 75-degree clamp);
    - ``inside_contact_only``: predictions inside the labelled contact, zero outside;
    - ``outside_contact_only``: labels inside the contact, predictions outside (the slopes the net
      sees on the deformed gel around the contact, which the Poisson solve accumulates);
    - ``shape_only``: the figure after removing each image's mean depth error (offset-free).
    """
    truth = Truth.of(ts)
    rows = []
    for frame in folds["frame"]:
        i = int(frame)
        grads, depth = frames[i]
        c, d = tuple(truth.center_px[i]), float(truth.depth_mm[i])
        label = sphere_gradients(
            ts.image_shape, c, ts.sphere_radius_mm, d, ts.px_per_mm, ts.max_slope_deg
        )
        contact = sphere_depth(ts.image_shape, c, ts.sphere_radius_mm, d, ts.px_per_mm) > 0
        inside = contact[..., None]
        row = {}
        for name, field in (
            ("integration_only", label),
            ("inside_contact_only", np.where(inside, grads, 0.0)),
            ("outside_contact_only", np.where(inside, label, grads)),
        ):
            z = _integrate(field.astype(np.float32), ts.px_per_mm)
            row[name] = image_errors(field, z, ts, i, truth)[1]
        _, row["as_predicted"], _, row["shape_only"] = image_errors(grads, depth, ts, i, truth)
        rows.append(row)
    table = pd.DataFrame(rows)
    return {
        k: float(table[k].mean())
        for k in (
            "as_predicted",
            "integration_only",
            "inside_contact_only",
            "outside_contact_only",
            "shape_only",
        )
    }


def label_noise_floor(ts: TrainingSet, settings: CVSettings, seed: int) -> dict[str, float]:
    """The figures a perfect predictor (the labels' own sphere) scores against the perturbed labels:
    how much of a method's error the label uncertainty alone accounts for."""
    exact = {}
    for i in range(len(ts.depth_mm)):
        c, d = tuple(ts.center_px[i]), float(ts.depth_mm[i])
        exact[i] = (
            sphere_gradients(
                ts.image_shape, c, ts.sphere_radius_mm, d, ts.px_per_mm, ts.max_slope_deg
            ),
            sphere_depth(ts.image_shape, c, ts.sphere_radius_mm, d, ts.px_per_mm),
        )
    draws = []
    for k in range(max(settings.label_draws, 1)):
        truth = perturbed_truth(ts, settings, np.random.default_rng([seed, 0x1AB, k]))
        errs = np.array([image_errors(*exact[i], ts, i, truth)[:2] for i in exact])
        draws.append((np.sqrt(np.nanmean(errs[:, 0])), np.nanmean(errs[:, 1])))
    mean = np.mean(draws, axis=0)
    return {"gradient_rmse": float(mean[0]), "cap_depth_mae_um": float(mean[1])}


def nested_choice(
    ts: TrainingSet,
    folds: pd.DataFrame,
    fold: int,
    candidates: Mapping[str, Mapping],
    inner_k: int,
    seed: int,
    threads: int,
    work_dir: str | Path,
) -> dict:
    """Pick model settings for outer `fold` by a grouped inner CV of its training images alone.

    Each candidate (name -> `model:` settings) is trained on inner_k - 1 inner folds and scored on
    the remaining one; the pooled inner figures are compared as relative scores (each figure over
    the best candidate's, summed over gradient RMSE and cap depth MAE): lowest wins.
    Returns {"chosen": name, "inner": {name: pooled figures}}.
    """
    inner = inner_folds(folds, fold, inner_k, seed)
    figures = {}
    for name, model in candidates.items():
        settings = TrainSettings.of(seed=seed, torch_threads=threads, **dict(model))
        paths = []
        for k in range(inner_k):
            out = Path(work_dir) / f"outer{fold}" / name / f"inner{k}"
            train(fold_trainset(ts, inner, k), out, 80, settings, progress=False)
            paths.append(out / "model.pt")
        frames = predict_held_out(ts, inner, paths, threads)
        truth = Truth.of(ts)
        errors = np.array(
            [image_errors(*frames[int(f)], ts, int(f), truth)[:2] for f in inner["frame"]]
        )
        figures[name] = {
            "gradient_rmse": float(np.sqrt(np.nanmean(errors[:, 0]))),
            "cap_depth_mae_um": float(np.nanmean(errors[:, 1])),
        }
    best = {m: min(f[m] for f in figures.values()) for m in METRICS}
    score = {name: sum(f[m] / best[m] for m in METRICS) for name, f in figures.items()}
    return {"chosen": min(score, key=score.get), "inner": figures}
