"""Sim-to-real scoring: every condition's models on their folds' held-out real images, at the set's
own frame size, with ball_eval's figures, the group bootstrap and the error-against-k figure."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from threedcal.dataset.folds import CVSettings, read_folds
from threedcal.dataset.reframe import reframe
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
from threedcal.errors import ConfigError
from threedcal.evaluate.crossval import Truth, group_bootstrap, image_errors, interval, pooled
from threedcal.evaluate.sim2real import k_model
from threedcal.evaluate.sim2real_settings import (
    CONDITIONS,
    ERROR_COLUMNS,
    SCENE_MODEL,
    SimToRealSettings,
    chosen_folds,
)
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator
from threedcal.plotting import pyplot


def score_models(
    ts: TrainingSet,
    folds: pd.DataFrame,
    models: Mapping[tuple[str, str], Mapping[int, str | Path]],
    threads: int,
) -> pd.DataFrame:
    """Per-image errors (crossval.image_errors) of every (condition, k) model on its fold's test
    images, at the set's own frame size: columns condition, k, fold, frame, group, gradient_mse,
    cap_depth_mae_um, predicted_at (the frame the model predicted in)."""
    truth = Truth.of(ts)
    rows = []
    for (condition, k), by_fold in models.items():
        for fold, path in by_fold.items():
            only = folds[folds["fold"] == fold]
            frames, predicted_at = predict_frames(ts, only["frame"], path, threads)
            for frame in only["frame"]:
                mse, mae, _, _ = image_errors(*frames[int(frame)], ts, int(frame), truth)
                rows.append(
                    {
                        "condition": condition,
                        "k": k,
                        "fold": int(fold),
                        "frame": int(frame),
                        "group": int(folds.at[frame, "group"]),
                        "gradient_mse": mse,
                        "cap_depth_mae_um": mae,
                        "predicted_at": predicted_at,
                    }
                )
    return pd.DataFrame(rows)


def frame_size(shape: Sequence[int]) -> str:
    return f"{int(shape[0])}x{int(shape[1])} px"


def predict_frames(
    ts: TrainingSet, frames: Sequence[int], path: str | Path, threads: int
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], str]:
    """frame -> (gradients, depth) at the set's frame size, and the frame the model predicted in.

    A model trained in another frame (its checkpoint's training.reframe: shipped+real) predicts
    on the frames brought to it, and its gradients are brought back to the set's pixels before
    they are integrated (threedcal.dataset.reframe): every model is integrated and scored alike.
    """

    torch.set_num_threads(threads)
    checkpoint = read_checkpoint(path)
    recorded = (checkpoint.get("training") or {}).get("reframe")
    source, how = ts, None
    if recorded is not None:
        source, how = reframe(ts, tuple(checkpoint["image_shape"]), f"{path}")
        if [list(how.full_shape), how.factor, how.turned] != [
            list(recorded["full_shape"]),
            int(recorded["factor"]),
            bool(recorded["turned"]),
        ]:
            raise ConfigError(
                f"{path}: trained on frames brought to its size as {recorded}, this set's "
                f"come there as {how}: not the set it was trained on"
            )
    estimator = DepthEstimator(checkpoint, device="cpu")
    out = {}
    for frame in frames:
        grads = estimator.gradients(np.asarray(source.frames[int(frame)]))
        if how is not None:
            grads = how.gradients_back(grads)
        # as crossval.predict_held_out integrates the scene's models
        depth = integrate(grads[..., 0], grads[..., 1], px_per_mm=ts.px_per_mm)
        out[int(frame)] = (grads, depth)
    return out, how.describe() if how is not None else frame_size(ts.image_shape)


def summarise_k(
    images: pd.DataFrame, folds: pd.DataFrame, resamples: int, seed: int, scored_at: str = ""
) -> pd.DataFrame:
    """errors.csv: per (k, condition) the figures of each fold and pooled over the folds (fold
    'all', with a 95 % interval from the group bootstrap, the same resamples for every model),
    with the frame each condition predicted at and the one it was scored at."""
    keys = list(dict.fromkeys(zip(images["condition"], images["k"], strict=True)))
    tables = {
        key: images[(images["condition"] == key[0]) & (images["k"] == key[1])].reset_index(
            drop=True
        )
        for key in keys
    }
    boot = group_bootstrap(tables, resamples, seed)
    pool_size = {int(f): int((folds["fold"] != f).sum()) for f in folds["fold"].unique()}
    rows = []
    for key, table in tables.items():
        condition, k = key
        sizes = {"scored_at": scored_at}
        if "predicted_at" in table:
            sizes["predicted_at"] = "; ".join(dict.fromkeys(table["predicted_at"]))
        for fold, part in table.groupby("fold"):
            n_train = pool_size[int(fold)] if k == "all" else int(k)
            rows.append(
                {"k": k, "n_train": n_train, "condition": condition, "fold": str(fold)}
                | {"n_test_images": len(part)}
                | pooled(part)
                | sizes
            )
        n_train = (
            float(np.mean([pool_size[int(f)] for f in table["fold"].unique()]))
            if k == "all"
            else int(k)
        )
        row = {"k": k, "n_train": n_train, "condition": condition, "fold": "all"}
        row |= {"n_test_images": len(table)} | pooled(table) | sizes
        for metric in ("gradient_rmse", "cap_depth_mae_um"):
            row[f"{metric}_lo"], row[f"{metric}_hi"] = interval(boot[key][metric])
        rows.append(row)
    return pd.DataFrame(rows).reindex(columns=list(ERROR_COLUMNS))


def error_figure(errors: pd.DataFrame, path: str | Path, title: str) -> None:
    """Error against k (log axis; 'all' at the mean training-set size), each condition with its
    95 % intervals, and the scene's own model as a band."""
    plt = pyplot()

    pooled_rows = errors[errors["fold"] == "all"]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, layout="constrained")
    for ax, metric, label in (
        (axes[0], "gradient_rmse", "gradient RMSE"),
        (axes[1], "cap_depth_mae_um", "cap depth MAE (µm)"),
    ):
        for offset, (condition, colour) in zip(
            (0.96, 1.0, 1.04),
            [(CONDITIONS[c], f"C{i}") for i, c in enumerate(CONDITIONS)],
            strict=True,
        ):
            part = pooled_rows[pooled_rows["condition"] == condition].sort_values("n_train")
            if part.empty:
                continue
            x = part["n_train"].to_numpy(float) * offset
            y = part[metric].to_numpy(float)
            err = [y - part[f"{metric}_lo"].to_numpy(float), part[f"{metric}_hi"] - y]
            ax.errorbar(x, y, yerr=err, fmt="o-", color=colour, capsize=3, label=condition)
        scene = pooled_rows[pooled_rows["condition"] == SCENE_MODEL]
        if not scene.empty:
            row = scene.iloc[0]
            ax.axhspan(row[f"{metric}_lo"], row[f"{metric}_hi"], color="grey", alpha=0.2)
            ax.axhline(row[metric], color="grey", lw=1, label=f"{SCENE_MODEL} (all, full budget)")
        ax.set_xscale("log")
        ticks = pooled_rows[pooled_rows["condition"] != SCENE_MODEL].drop_duplicates("k")
        ax.set_xticks(
            ticks["n_train"].to_numpy(float),
            [
                f"{k}" if k != "all" else f"all\n({n:.0f})"
                for k, n in zip(ticks["k"], ticks["n_train"], strict=True)
            ],
        )
        ax.minorticks_off()
        ax.set_xlabel("real training images k")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def sim2real_eval(
    trainset_dir: str | Path,
    folds_path: str | Path,
    models: Mapping[str, Sequence[str | Path]],
    scene_models: Sequence[str | Path],
    sim_to_real: Mapping,
    cv: Mapping,
    seed: int,
    threads: int,
    errors_path: str | Path,
    figure_path: str | Path,
    images_path: str | Path | None = None,
) -> pd.DataFrame:
    """errors.csv and error_vs_k.png of the chosen folds.

    `models[condition]` lists that condition's fold folders (:func:`train_fold_ks`, k{k}/model.pt
    inside) in the order of the chosen folds; `scene_models` the scene's cross-validated models
    (ball_eval's) of the same folds.
    """
    settings = SimToRealSettings.of(**sim_to_real)
    cv_settings = CVSettings.of(**cv)
    ts = TrainingSet.load(trainset_dir)
    folds = read_folds(folds_path, ts)
    chosen = chosen_folds(settings, cv_settings.folds)
    by_model: dict[tuple[str, str], dict[int, str | Path]] = {}
    for condition in settings.conditions:
        dirs = list(models[condition])
        if len(dirs) != len(chosen):
            raise ConfigError(f"sim2real: {len(dirs)} {condition} fold folders for folds {chosen}")
        for k in settings.k:
            paths = {fold: k_model(d, k) for fold, d in zip(chosen, dirs, strict=True)}
            missing = [str(p) for p in paths.values() if not p.is_file()]
            if missing:
                raise ConfigError(f"sim2real: no {condition} model of k = {k}: {missing[0]}")
            by_model[(CONDITIONS[condition], str(k))] = paths
    if len(scene_models) != len(chosen):
        raise ConfigError(f"sim2real: {len(scene_models)} scene models for folds {chosen}")
    by_model[(SCENE_MODEL, "all")] = dict(zip(chosen, scene_models, strict=True))
    images = score_models(ts, folds, by_model, threads)
    errors = summarise_k(
        images, folds, cv_settings.bootstrap, seed, scored_at=frame_size(ts.image_shape)
    )
    Path(errors_path).parent.mkdir(parents=True, exist_ok=True)
    errors.to_csv(errors_path, index=False, float_format="%.6g")
    if images_path is not None:
        images.to_csv(images_path, index=False, float_format="%.6g")
    n_test = int(folds["fold"].isin(chosen).sum())
    error_figure(
        errors,
        figure_path,
        f"folds {', '.join(map(str, chosen))}: {n_test} held-out real images, scored at "
        f"{frame_size(ts.image_shape)}; 95 % group-bootstrap intervals",
    )
    return errors
