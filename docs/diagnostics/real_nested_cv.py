"""Nested cross-validation of the multiscale training budget (docs/explanation/real-data.md, "Choosing settings").

    .venv/bin/python docs/diagnostics/real_nested_cv.py data/gelsight_ball_fots [drawn|refined]

The budget of `multiscale` (window size 96 or 128 px) was first compared on two outer folds; this
redoes the choice honestly: for every outer fold, each candidate is scored by a grouped 2-fold CV of
that fold's training images only (threedcal.model.crossval.nested_choice), the winner is retrained
on all of them and scored on the outer fold. The pooled figure is what the whole procedure —
choice included — achieves on unseen images. Outer predictions of a candidate are shared with
real_cv_methods.py's cache when that holds them.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from threedcal.dataset.build import build_imported
from threedcal.model import crossval
from threedcal.model import folds as cv_folds

sys.path.insert(0, str(Path(__file__).parent))
from real_cv_methods import CACHE, MULTISCALE, held_out  # noqa: E402

CANDIDATES = {
    "multiscale": {**MULTISCALE, "preset": "multiscale"},
    "multiscale_96": {
        **MULTISCALE,
        "preset": "multiscale",
        "patch_px": 96,
        "contact_patches": 2,
        "background_patches": 1,
    },
}
INNER_FOLDS = 2


def main(folder: str, labels: str = "drawn") -> None:
    settings = cv_folds.CVSettings()
    scene = {
        "import": {"format": "ball_folder", "path": folder},
        "seed": 0,
        "dataset": {"downscale": 1, "max_slope_deg": 75, "refine_labels": labels == "refined"},
    }
    with tempfile.TemporaryDirectory() as tmp:
        ts = build_imported(scene, Path(tmp) / "trainset", Path(tmp) / "splits.csv")
        ts.frames = np.asarray(ts.frames)
    folds = cv_folds.make_folds(ts, settings, seed=0, where=folder)
    out = CACHE / Path(folder).name
    suffix = "" if labels == "drawn" else "_refined"
    chosen, frames = {}, {}
    for fold in sorted(folds["fold"].unique()):
        record = out / f"nested{suffix}" / f"outer{fold}.json"
        if not record.is_file():
            choice = crossval.nested_choice(
                ts, folds, int(fold), CANDIDATES, INNER_FOLDS, 0, 1, out / f"nested{suffix}"
            )
            record.write_text(json.dumps(choice, indent=2, sort_keys=True) + "\n")
        choice = json.loads(record.read_text())
        chosen[int(fold)] = choice["chosen"]
        print(f"outer fold {fold}: inner figures {choice['inner']} -> {choice['chosen']}")
        name = choice["chosen"] + suffix
        predictions = held_out(ts, folds, name, CANDIDATES[choice["chosen"]], out, only=int(fold))
        frames.update(predictions)
    tables, draws = crossval.score_methods(ts, folds, {"nested": frames}, settings, seed=0)
    summary = crossval.summarise(tables, draws, settings, seed=0)["nested"]
    print(
        f"nested CV ({labels} labels): gradient RMSE {summary['gradient_rmse']:.3f} "
        f"{summary['interval95']['gradient_rmse']}, cap depth MAE {summary['cap_depth_mae_um']:.0f} µm "
        f"{summary['interval95']['cap_depth_mae_um']}; chosen per fold {chosen}"
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
