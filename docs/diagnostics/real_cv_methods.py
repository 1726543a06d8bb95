"""The methods table of docs/explanation/real-data.md: several model settings under the cross-validated protocol.

    .venv/bin/python docs/diagnostics/real_cv_methods.py data/gelsight_ball_fots [METHOD ...]

Every method is trained on the same grouped folds as `make all`'s ball_eval (seed 0, the `cv:`
defaults; with refined labels the folds follow the refined centres, as `make all` does with
`dataset.refine_labels`) and scored on every image once; the table gives gradient RMSE and cap depth MAE with 95 %
intervals (bootstrap over press groups), the paired difference to `lookup`, the label-uncertainty
spread, where the depth error comes from (threedcal.model.crossval.error_sources) and
DepthEstimator.depth ms/frame at 240 x 320 with 2 torch threads on this machine (median; the
`compact` row is the same-run reference). Writes docs/figures/real_cv_{drawn,refined}.png and
.cache/real_cv/<folder>/table.csv; the refined-label methods are also scored against the drawn labels. Fold models and predictions are cached under
.cache/real_cv/ (a rerun trains only what is missing), 1 torch thread per training as in `make all`.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from threedcal.dataset.build import build_imported
from threedcal.model import crossval
from threedcal.model import folds as cv_folds
from threedcal.model.inference import DepthEstimator
from threedcal.model.presets_study import depth_ms_per_frame
from threedcal.model.train import TrainSettings, train

# fots_ball's settings before this study (chosen on an inner split; docs/explanation/models.md, Choosing a preset).
sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
from bench_model import BALL_SETTINGS as BALL  # noqa: E402

# The multiscale budget: two large windows per image and epoch (the context branch needs room), a
# third of BALL's pixels per epoch, twice the epochs.
MULTISCALE = {
    **BALL,
    "epochs_base": 40,
    "batch_size": 8,
    "patch_px": 128,
    "contact_patches": 1,
    "background_patches": 1,
    "skirt_reach": 0.0,
}
# name -> (labels, model settings); "refined" = dataset.refine_labels (threedcal.dataset.refine).
METHODS = {
    "lookup": ("drawn", {**BALL, "preset": "lookup"}),
    "compact": ("drawn", {**BALL, "preset": "compact"}),
    "context": ("drawn", {**BALL, "preset": "context"}),
    "multiscale": ("drawn", {**MULTISCALE, "preset": "multiscale"}),
    "lookup_refined": ("refined", {**BALL, "preset": "lookup"}),
    "multiscale_refined": ("refined", {**MULTISCALE, "preset": "multiscale"}),
}
CACHE = Path(".cache/real_cv")
FIGURES = Path("docs/figures")


def held_out(ts, folds, name: str, model: dict, out: Path, only: int | None = None) -> dict:
    """frame -> (gradients, depth) of `name`'s fold models (fold `only` alone if given), trained
    where not cached."""
    frames = {}
    for fold in sorted(folds["fold"].unique()) if only is None else [only]:
        cached = out / name / f"fold{fold}" / "held_out.npz"
        if not cached.is_file():
            began = time.process_time()
            checkpoint = train(
                cv_folds.fold_trainset(ts, folds, fold),
                cached.parent,
                80,
                TrainSettings.of(**model, seed=0, torch_threads=1),
                progress=False,
            )
            cpu = time.process_time() - began
            estimator = DepthEstimator(checkpoint, device="cpu")
            test = folds.loc[folds["fold"] == fold, "frame"].to_numpy()
            grads = estimator.gradients(np.asarray(ts.frames[test]))
            depth = np.stack([crossval._integrate(g, ts.px_per_mm) for g in grads])
            np.savez(cached, frames=test, grads=grads, depth=depth, train_cpu_s=cpu)
            print(f"{name} fold {fold}: trained in {cpu:.0f} s CPU", flush=True)
        data = np.load(cached)
        for i, frame in enumerate(data["frames"]):
            frames[int(frame)] = (data["grads"][i], data["depth"][i])
    return frames


def main(folder: str, names: list[str]) -> None:
    settings = cv_folds.CVSettings()
    rows = []
    for labels in ("drawn", "refined"):
        chosen = [n for n in (names or METHODS) if METHODS[n][0] == labels]
        if chosen:
            rows += methods_table(folder, labels, chosen, settings)
    refined = [n for n in (names or METHODS) if METHODS[n][0] == "refined"]
    if refined:
        rows += against_drawn_labels(folder, refined, settings)
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(table.round(3).to_string(index=False))
    table.to_csv(CACHE / Path(folder).name / "table.csv", index=False)


def model_ready(folder: str, refined: bool):
    """The model-ready set of `folder` (labels as drawn or refined) and its grouped folds."""
    scene = {
        "import": {"format": "ball_folder", "path": folder},
        "seed": 0,
        "dataset": {"downscale": 1, "max_slope_deg": 75, "refine_labels": refined},
    }
    with tempfile.TemporaryDirectory() as tmp:
        ts = build_imported(scene, Path(tmp) / "trainset", Path(tmp) / "splits.csv")
        ts.frames = np.asarray(ts.frames)
    return ts, cv_folds.make_folds(ts, cv_folds.CVSettings(), seed=0, where=folder)


def against_drawn_labels(folder: str, names: list[str], settings) -> list[dict]:
    """The refined-label methods' held-out predictions scored against the hand-drawn labels instead
    (same predictions, same folds): how much of their lead is the truth they are scored against."""
    drawn, _ = model_ready(folder, refined=False)
    refined, folds = model_ready(folder, refined=True)
    out = CACHE / Path(folder).name
    predictions = {n: held_out(refined, folds, n, METHODS[n][1], out) for n in names}
    tables, draws = crossval.score_methods(drawn, folds, predictions, settings, seed=0)
    summary = crossval.summarise(tables, draws, settings, seed=0)
    return [figure_row(name, "scored vs drawn", summary[name]) for name in names]


def figure_row(name: str, labels: str, s: dict) -> dict:
    """The pooled figures and intervals of one method (a `summarise` entry) as a table row."""
    return {
        "method": name,
        "labels": labels,
        "gradient_rmse": s["gradient_rmse"],
        "gradient_lo": s["interval95"]["gradient_rmse"][0],
        "gradient_hi": s["interval95"]["gradient_rmse"][1],
        "depth_mae_um": s["cap_depth_mae_um"],
        "depth_lo": s["interval95"]["cap_depth_mae_um"][0],
        "depth_hi": s["interval95"]["cap_depth_mae_um"][1],
        "depth_bias_um": s["cap_depth_bias_um"],
        "shape_mae_um": s["cap_shape_mae_um"],
    }


def methods_table(folder: str, labels: str, names: list[str], settings) -> list[dict]:
    """Rows of the table for the methods trained on one kind of labels (the folds follow them)."""
    lookup = "lookup" if labels == "drawn" else "lookup_refined"
    names = [lookup, *[n for n in names if n != lookup]]
    ts, folds = model_ready(folder, refined=labels == "refined")
    out = CACHE / Path(folder).name
    predictions = {name: held_out(ts, folds, name, METHODS[name][1], out) for name in names}
    renamed = {("lookup" if n == lookup else n): p for n, p in predictions.items()}
    tables, draws = crossval.score_methods(ts, folds, renamed, settings, seed=0)
    summary = crossval.summarise(tables, draws, settings, seed=0)
    crossval.cv_figure(
        tables,
        summary,
        FIGURES / f"real_cv_{labels}.png",
        f"{Path(folder).name}, {labels} labels: {settings.folds}-fold grouped CV, "
        f"{len(folds)} images (dots: images; bars: mean, 95 % interval)",
    )
    summary = {(lookup if n == "lookup" else n): v for n, v in summary.items()}
    floor = crossval.label_noise_floor(ts, settings, seed=0)
    print(f"{labels} labels: a perfect predictor scores {floor} against the perturbed labels")
    (out / f"summary_{labels}.json").write_text(
        json.dumps(summary, indent=2, sort_keys=True) + "\n"
    )
    torch.set_num_threads(2)
    rows = []
    for name in names:
        s = summary[name]
        checkpoint = out / name / "fold0" / "model.pt"
        estimator = DepthEstimator.from_checkpoint(checkpoint, device="cpu", batch_size=1)
        cpu = [
            float(np.load(out / name / f"fold{f}" / "held_out.npz")["train_cpu_s"])
            for f in sorted(folds["fold"].unique())
        ]
        row = {
            **figure_row(name, labels, s),
            "label_mc_depth_um": s["label_uncertainty"]["cap_depth_mae_um"]["mean"],
            "ms_per_frame": depth_ms_per_frame(estimator, np.asarray(ts.frames[:4])),
            "train_cpu_s_per_fold": float(np.mean(cpu)),
        }
        if "versus_lookup" in s:
            for metric, short in (("gradient_rmse", "gradient"), ("cap_depth_mae_um", "depth")):
                row[f"{short}_vs_lookup_hi"] = s["versus_lookup"][metric]["interval95"][1]
        row.update(
            {f"src_{k}": v for k, v in crossval.error_sources(ts, folds, predictions[name]).items()}
        )
        rows.append(row)
    return rows


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
