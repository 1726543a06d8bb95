"""The methods table of the real-data explanation: several model settings under the
cross-validated protocol, on a ball folder (data/gelsight_ball_fots).

    .venv/bin/python -m diagnostics.real_cv_methods [METHOD ...] [--folder data/gelsight_ball_fots]

Every method is trained on the same grouped folds as `make all`'s ball_eval (seed 0, the `cv:`
defaults; with refined labels the folds follow the refined centres, as `make all` does with
`dataset.refine_labels`) and scored on every image once; the table gives gradient RMSE and cap
depth MAE with 95 % intervals (bootstrap over press groups), the paired difference to `lookup`,
the label-uncertainty spread, where the depth error comes from
(threedcal.evaluate.crossval.error_sources) and DepthEstimator.depth ms/frame with 2 torch threads on
this machine (median). Writes real_cv_{drawn,refined}.png into `--out` and CACHE/<folder>/table.csv;
the refined-label methods are also scored against the drawn labels. Fold models and predictions
are cached under `--cache` (default .cache/real_cv; a rerun trains only what is missing), 1 torch
thread per training as in `make all`. Hours on 2 cores for every method; `--smoke`: `lookup` alone
unless methods are named, 2 folds, few bootstrap draws, images pooled 4 x 4, a tiny budget: seconds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from threedcal.dataset import folds as cv_folds
from threedcal.depth import integrate
from threedcal.evaluate import crossval
from threedcal.evaluate.presets_study import PATCH_BALL_SETTINGS, depth_ms_per_frame
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import TrainSettings, train
from threedcal.study.dataset_stage import import_stage

# fots_ball's settings before this study (the models explanation, Choosing a preset).
BALL = PATCH_BALL_SETTINGS
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
FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"
DATA = Path(__file__).resolve().parents[1] / "data" / "gelsight_ball_fots"
# --smoke: two folds, few draws, and a budget of seconds for the trained presets
SMOKE_CV = {"folds": 2, "bootstrap": 100, "label_draws": 2}
SMOKE_DOWNSCALE = 4  # images pooled 4 x 4
SMOKE_MODEL = {"epochs_base": 1, "batch_size": 4, "contact_patches": 2, "background_patches": 2}


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
            depth = np.stack(
                [integrate(g[..., 0], g[..., 1], px_per_mm=ts.px_per_mm) for g in grads]
            )
            np.savez(cached, frames=test, grads=grads, depth=depth, train_cpu_s=cpu)
            print(f"{name} fold {fold}: trained in {cpu:.0f} s CPU", flush=True)
        data = np.load(cached)
        for i, frame in enumerate(data["frames"]):
            frames[int(frame)] = (data["grads"][i], data["depth"][i])
    return frames


def main(argv: list[str] | None = None) -> pd.DataFrame:
    """Train, score and tabulate the methods named (every one when none): the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DATA, help="a ball folder (%(default)s)")
    parser.add_argument("methods", nargs="*", metavar="METHOD", help=", ".join(METHODS))
    parser.add_argument("--out", type=Path, help="folder for the figures (docs/figures)")
    parser.add_argument("--cache", type=Path, help=f"fold models and predictions ({CACHE})")
    parser.add_argument("--smoke", action="store_true", help="lookup, 2 folds, a tiny budget")
    args = parser.parse_args(argv)
    scratch = Path(tempfile.mkdtemp(prefix="real_cv_smoke-")) if args.smoke else None
    out = args.out or (scratch if args.smoke else FIGURES)  # a smoke run never overwrites the docs'
    cache = args.cache or (scratch / "cache" if args.smoke else CACHE)
    unknown = sorted(set(args.methods) - set(METHODS))
    if unknown:
        parser.error(f"unknown methods {unknown}; known: {', '.join(METHODS)}")
    names = args.methods or (["lookup"] if args.smoke else list(METHODS))
    settings = cv_folds.CVSettings.of(**(SMOKE_CV if args.smoke else {}))
    methods = {
        name: (labels, {**model, **(SMOKE_MODEL if args.smoke else {})})
        for name, (labels, model) in METHODS.items()
    }
    downscale = SMOKE_DOWNSCALE if args.smoke else 1
    run = Run(str(args.folder), methods, settings, cache / args.folder.name, out, downscale)
    rows = []
    for labels in ("drawn", "refined"):
        chosen = [n for n in names if methods[n][0] == labels]
        if chosen:
            rows += run.methods_table(labels, chosen)
    refined = [n for n in names if methods[n][0] == "refined"]
    if refined:
        rows += run.against_drawn_labels(refined)
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(table.round(3).to_string(index=False))
    table.to_csv(run.cache / "table.csv", index=False)
    return table


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


class Run:
    """One table: the folder, the methods' settings, the CV settings, where models and figures go."""

    def __init__(
        self, folder: str, methods: dict, settings, cache: Path, figures: Path, downscale: int = 1
    ):
        self.folder, self.methods, self.settings = folder, methods, settings
        self.downscale = downscale
        self.cache, self.figures = cache, figures
        self.cache.mkdir(parents=True, exist_ok=True)
        self.figures.mkdir(parents=True, exist_ok=True)

    def model_ready(self, refined: bool):
        """The model-ready set of the folder (labels as drawn or refined) and its grouped folds."""
        scene = {
            "import": {"format": "ball_folder", "path": self.folder},
            "seed": 0,
            "dataset": {"downscale": self.downscale, "max_slope_deg": 75, "refine_labels": refined},
        }
        with tempfile.TemporaryDirectory() as tmp:
            ts = import_stage(
                scene,
                Path(tmp) / "trainset",
                Path(tmp) / "splits.csv",
            )
            ts.frames = np.asarray(ts.frames)
        return ts, cv_folds.make_folds(ts, self.settings, seed=0, where=self.folder)

    def predictions(self, ts, folds, names: list[str]) -> dict:
        return {n: held_out(ts, folds, n, self.methods[n][1], self.cache) for n in names}

    def against_drawn_labels(self, names: list[str]) -> list[dict]:
        """The refined-label methods' held-out predictions scored against the hand-drawn labels
        instead (same predictions, same folds): how much of their lead is the truth they are
        scored against."""
        drawn, _ = self.model_ready(refined=False)
        refined, folds = self.model_ready(refined=True)
        predictions = self.predictions(refined, folds, names)
        tables, draws = crossval.score_methods(drawn, folds, predictions, self.settings, seed=0)
        summary = crossval.summarise(tables, draws, self.settings, seed=0)
        return [figure_row(name, "scored vs drawn", summary[name]) for name in names]

    def methods_table(self, labels: str, names: list[str]) -> list[dict]:
        """Rows of the table for the methods trained on one kind of labels (the folds follow
        them); draws real_cv_{labels}.png."""
        settings, out = self.settings, self.cache
        lookup = "lookup" if labels == "drawn" else "lookup_refined"
        names = [lookup, *[n for n in names if n != lookup]]
        ts, folds = self.model_ready(refined=labels == "refined")
        predictions = self.predictions(ts, folds, names)
        renamed = {("lookup" if n == lookup else n): p for n, p in predictions.items()}
        tables, draws = crossval.score_methods(ts, folds, renamed, settings, seed=0)
        summary = crossval.summarise(tables, draws, settings, seed=0)
        figure = self.figures / f"real_cv_{labels}.png"
        crossval.cv_figure(
            tables,
            summary,
            figure,
            f"{Path(self.folder).name}, {labels} labels: {settings.folds}-fold grouped CV, "
            f"{len(folds)} images (dots: images; bars: mean, 95 % interval)",
        )
        print(f"wrote {figure}")
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
            sources = crossval.error_sources(ts, folds, predictions[name])
            row.update({f"src_{k}": v for k, v in sources.items()})
            rows.append(row)
        return rows


if __name__ == "__main__":
    main()
