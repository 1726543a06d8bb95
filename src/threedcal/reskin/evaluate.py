"""ReSkin errors on held-out coordinates: localisation (x, y) error per reading and depth error.

The numbers of results/{scene}/reskin_eval.json: `median_error_mm` and `p90_error_mm` of the
Euclidean (x, y) error over every held-out reading, `depth_mae_mm` the mean absolute depth error.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from threedcal.reskin.model import predict


def localisation_errors(predicted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Summary figures of (N, 3) predictions against (N, 3) truths (x_mm, y_mm, depth_mm)."""
    predicted = np.asarray(predicted, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if len(predicted) == 0:
        raise ValueError("no held-out readings to evaluate")
    xy = np.hypot(predicted[:, 0] - truth[:, 0], predicted[:, 1] - truth[:, 1])
    depth = np.abs(predicted[:, 2] - truth[:, 2])
    return {
        "median_error_mm": float(np.median(xy)),
        "p90_error_mm": float(np.percentile(xy, 90)),
        "mean_error_mm": float(np.mean(xy)),
        "depth_mae_mm": float(np.mean(depth)),
    }


def per_point_table(predicted: np.ndarray, truth: np.ndarray, point: np.ndarray) -> pd.DataFrame:
    """Mean prediction per probe point (x, y, depth), with its (x, y) error: what the figure draws."""
    frame = pd.DataFrame(
        {
            "point": point,
            "x_mm": truth[:, 0],
            "y_mm": truth[:, 1],
            "depth_mm": truth[:, 2],
            "pred_x_mm": predicted[:, 0],
            "pred_y_mm": predicted[:, 1],
            "pred_depth_mm": predicted[:, 2],
        }
    )
    table = frame.groupby("point").mean().reset_index()
    table["error_mm"] = np.hypot(table.pred_x_mm - table.x_mm, table.pred_y_mm - table.y_mm)
    return table


def evaluate_split(
    checkpoint: Mapping[str, Any], data, test: np.ndarray
) -> tuple[dict[str, Any], pd.DataFrame]:
    """Errors of `checkpoint` on the held-out readings of `data` (a ReSkinSet), overall and per depth."""
    held = data.subset(test)
    predicted = predict(checkpoint, held.inputs)
    truth = held.targets.astype(float)
    result: dict[str, Any] = localisation_errors(predicted, truth)
    depths = np.round(truth[:, 2], 4)
    result["per_depth"] = {
        f"{d:g}": localisation_errors(predicted[depths == d], truth[depths == d])
        for d in np.unique(depths)
    }
    result["n_test_readings"] = int(len(truth))
    result["n_test_coordinates"] = int(len(np.unique(np.round(truth[:, :2], 6), axis=0)))
    train = data.subset(~test)
    result["n_train_readings"] = int(len(train.targets))
    result["n_train_coordinates"] = int(
        len(np.unique(np.round(train.targets[:, :2].astype(float), 6), axis=0))
    )
    return result, per_point_table(predicted, truth, held.point)
