"""Held-out evaluation of imported ball scenes: gradient RMSE and cap depth MAE inside eval_mask.

Both figures are computed per held-out image over the pixels whose label is trusted (eval_mask: a
shrunk contact circle) and averaged over images, so each image weighs the same. Depth is integrated
from the full predicted gradient field and compared with the exact sphere cap (µm).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from threedcal.dataset.labels import sphere_depth
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
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
        )
        depth_ae.append(float(np.mean(np.abs(depth[mask] - truth[mask]))))
    return {
        "gradient_rmse": float(np.sqrt(np.mean(grad_se))) if grad_se else float("nan"),
        "cap_depth_mae_um": 1000.0 * float(np.mean(depth_ae)) if depth_ae else float("nan"),
        "n_test_images": len(indices),
    }


def ball_eval(
    model_path: str | Path, trainset_dir: str | Path, out_path: str | Path, seed: int = 0
) -> dict:
    """ball_eval.json: the trained model and the lookup baseline (fitted on the same training images)."""
    from threedcal.model.train import TrainSettings, train

    ts = TrainingSet.load(trainset_dir)
    test = ts.indices("val")
    estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
    result = {"preset": estimator.preset, **evaluate(estimator, ts, test)}
    percent = int(estimator_percent(model_path))
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        lookup = train(
            ts, tmp, percent, TrainSettings.of(preset="lookup", seed=seed), progress=False
        )
    result["lookup"] = evaluate(DepthEstimator(lookup, device="cpu"), ts, test)
    result["P"] = percent
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    Path(out_path).write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    return result


def estimator_percent(model_path: str | Path) -> int:
    from threedcal.model.checkpoint import read_checkpoint

    return int(read_checkpoint(model_path).get("training", {}).get("percent", 80))
