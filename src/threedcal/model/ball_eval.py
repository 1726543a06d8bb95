"""Held-out evaluation of imported ball scenes: gradient RMSE and cap depth MAE inside eval_mask.

Both figures are computed per held-out image over the pixels whose label is trusted (eval_mask: a
shrunk contact circle) and averaged over images, so each image weighs the same. Depth is integrated
from the full predicted gradient field and compared with the exact sphere cap (µm). `ball_eval`
pools them over the grouped cross-validation folds (threedcal.model.crossval).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.labels import sphere_depth
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
from threedcal.errors import ConfigError
from threedcal.model import crossval
from threedcal.model import folds as cv_folds
from threedcal.model.inference import DepthEstimator


def evaluate(estimator: DepthEstimator, ts: TrainingSet, indices: np.ndarray) -> dict:
    grad_se, depth_ae = [], []
    for i in indices:
        frame = np.asarray(ts.frames[i])
        grads = estimator.gradients(frame)
        mask = ts.eval_mask(int(i))
        label = ts.labels(int(i)).transpose(1, 2, 0)
        grad_se.append(float(np.mean((grads[mask] - label[mask]) ** 2)))
        depth = integrate(grads[..., 0], grads[..., 1], px_per_mm=ts.px_per_mm)
        truth = sphere_depth(
            ts.image_shape,
            tuple(ts.center_px[i]),
            ts.sphere_radius_mm,
            float(ts.depth_mm[i]),
            ts.px_per_mm,
            dome=ts.dome_at(int(i)),
        )
        depth_ae.append(float(np.mean(np.abs(depth[mask] - truth[mask]))))
    return {
        "gradient_rmse": float(np.sqrt(np.mean(grad_se))) if grad_se else float("nan"),
        "cap_depth_mae_um": 1000.0 * float(np.mean(depth_ae)) if depth_ae else float("nan"),
        "n_test_images": len(indices),
    }


def ball_eval(
    trainset_dir: str | Path,
    folds_path: str | Path,
    models: Mapping[str, Sequence[str | Path]],
    cv: Mapping,
    seed: int,
    threads: int,
    json_path: str | Path,
    images_path: str | Path,
    figure_path: str | Path,
    preset: str | None = None,
) -> dict:
    """ball_eval.json: cross-validated figures of the scene's model (top level) and of `lookup`.

    `models[method]` lists the fold models in fold order. The top level keeps the keys of the
    single-split evaluation (gradient_rmse, cap_depth_mae_um, n_test_images, lookup) and adds the
    interval, the per-fold figures, the label-uncertainty spread and the protocol
    (threedcal.model.crossval).
    """
    settings = cv_folds.CVSettings.of(**cv)
    ts = TrainingSet.load(trainset_dir)
    folds = cv_folds.read_folds(folds_path, ts)
    for method, paths in models.items():
        if len(paths) != settings.folds:
            raise ConfigError(
                f"ball_eval: {len(paths)} {method} fold models for {settings.folds} folds"
            )
    predictions = {
        method: crossval.predict_held_out(ts, folds, paths, threads)
        for method, paths in models.items()
    }
    tables, draws = crossval.score_methods(ts, folds, predictions, settings, seed)
    summary = crossval.summarise(tables, draws, settings, seed)
    main = next(m for m in models if m != "lookup")
    result = {
        "preset": preset,
        **summary[main],
        "lookup": summary.get("lookup"),
        "protocol": crossval.protocol(folds, settings, seed),
        "label_spread_from_duplicates": crossval.label_spread_from_duplicates(
            folds, cv_folds.contact_radius_px(ts)
        ),
        "label_noise_floor": crossval.label_noise_floor(ts, settings, seed),
        "error_sources": {
            method: crossval.error_sources(ts, folds, frames)
            for method, frames in predictions.items()
        },
    }
    Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    Path(json_path).write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    pd.concat(tables.values()).to_csv(images_path, index=False, float_format="%.6g")
    crossval.cv_figure(
        tables,
        summary,
        figure_path,
        f"{settings.folds}-fold grouped cross-validation, {len(folds)} real images",
    )
    return result
