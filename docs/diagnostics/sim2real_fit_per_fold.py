"""Sim-to-real with the simulator's optics fitted, per fold, to the k real images that fine-tune:
is a fit on the k labelled images alone enough (the stage fits on all of a fold's training images)?

Usage (from the repository, after Snakemake made the scene's dataset, cv/folds.csv and the
sim2real models of these folds at this k: `snakemake
results/fots_ball/sim2real/{sim_real,real_only}/k8/fold{0,1,2}/model.pt`):
    python docs/diagnostics/sim2real_fit_per_fold.py [--scene fots_ball] [--k 8] [--folds 0 1 2]

Per fold: the k training images the sim2real stage fine-tunes on (the same seeded draw) and the
set's blank fit the sensor profile's optics, as the stage fits them to all of the fold's training
images (sim2real.fitted_to_frames; no test image and no label of a test image is seen), the scene's `sim_to_real.frames` presses are rendered with the
fitted profile, the preset is pretrained on them and fine-tuned on the same k images with the
stage's budget. All three conditions (the stage's sim+real, the k-image fit, real-only) are
then scored on the fold's held-out images with the stage's scoring and group bootstrap, and printed
as one table. Work lands in /tmp/sim2real_fit_per_fold/ (reused when there).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pandas as pd
import torch

from threedcal.config import load_config
from threedcal.dataset.trainset import TrainingSet
from threedcal.model.folds import read_folds, training_images
from threedcal.model.sim2real import (
    SimToRealSettings,
    fitted_to_frames,
    pretrain,
    score_models,
    sensor_profile,
    simulate_trainset,
    summarise_k,
    train_k,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fots_ball")
    parser.add_argument("--k", type=int, default=8)
    parser.add_argument("--folds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    parser.add_argument("--work", type=Path, default=Path("/tmp/sim2real_fit_per_fold"))
    args = parser.parse_args()
    config = load_config(args.config)
    scene = config["scenes"][args.scene]
    seed, threads = int(scene["seed"]), int(scene["torch_threads"])
    torch.set_num_threads(threads)
    root = Path("results") / args.scene
    ts = TrainingSet.load(root / "dataset/trainset")
    folds = read_folds(root / "cv/folds.csv", ts)
    settings = SimToRealSettings.from_scene(scene)
    models: dict[tuple[str, str], dict[int, Path]] = {}
    k = str(args.k)
    for fold in args.folds:
        work = args.work / args.scene / f"fold{fold}"
        fine_tuned = work / "fine_tuned/model.pt"
        if not fine_tuned.exists():
            frames = training_images(folds, fold, args.k, seed)
            images = [str(folds.at[int(f), "image"]) for f in frames]
            began = time.process_time()
            fit = fitted_to_frames(sensor_profile(scene), ts, frames, str(root))
            fitted_s = time.process_time() - began
            work.mkdir(parents=True, exist_ok=True)
            fit.write_profile(work / "profile.yaml")
            simset = simulate_trainset(ts, fit.profile, settings, seed)
            simset.save(work / "simset")
            pretrain(
                work / "simset",
                scene["model"],
                scene["sim_to_real"],
                seed,
                threads,
                work / "pretrained",
            )
            train_k(
                root / "dataset/trainset",
                root / "cv/folds.csv",
                fold,
                args.k,
                "sim_real",
                scene["model"],
                scene["sim_to_real"],
                seed,
                threads,
                work / "fine_tuned",
                pretrained=work / "pretrained/model.pt",
            )
            (work / "fit.json").write_text(
                json.dumps(
                    {
                        "images": images,
                        "fit_cpu_s": round(fitted_s, 1),
                        "contact_rms_dn": fit.contact_rms_dn,
                        "field_rms_dn": fit.field_rms_dn,
                    }
                )
            )
        print(f"fold {fold}: {(work / 'fit.json').read_text()}")
        models.setdefault(("sim+real, profile fitted to the k images", k), {})[fold] = fine_tuned
        for condition, name in (
            ("sim_real", "sim+real, the stage's profile"),
            ("real_only", "real-only"),
        ):
            path = root / f"sim2real/{condition}/k{k}/fold{fold}/model.pt"
            models.setdefault((name, k), {})[fold] = path
    images = score_models(ts, folds, models, threads)
    table = summarise_k(images, folds, int(scene["cv"]["bootstrap"]), seed)
    pd.set_option("display.width", 200)
    print(table[table["fold"] == "all"].to_string(index=False, float_format="%.3f"))
    print(table[table["fold"] != "all"].to_string(index=False, float_format="%.3f"))


if __name__ == "__main__":
    main()
