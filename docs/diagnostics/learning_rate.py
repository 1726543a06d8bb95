"""Mean validation MSE of a scene's models at several learning rates and seeds, on a study folder
that is *not* the reported one (docs/explanation/models.md, "The learning rate, chosen on an independent
collection").

    .venv/bin/python docs/diagnostics/learning_rate.py WORKDIR SCENE P[,P...] LR[,LR...] SEED[,SEED...] \
        [KEY=VALUE ...]

WORKDIR is a study run with another config seed, e.g. `snakemake ... --config seed=7 --until
dataset_collected` in a clone: its own collection, presses and noise, never scored by the default
study. Each (lr, seed, P) trains replicate 0's subset of that collection with the scene's settings
in WORKDIR/config.yaml, `lr` replaced and the given scene seed (initialisation, patch draws and
order), any KEY=VALUE replacing that `model:` key too (e.g. batch_size=16), and prints the last epoch's training loss and the mean validation MSE per
coordinate as the stats stage scores it.
"""

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd
import yaml

from threedcal.config import load_config
from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.validation import coordinate_mse
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import TrainSettings, train


def main(
    workdir: str,
    scene: str,
    fractions: list[int],
    rates: list[float],
    seeds: list[int],
    changes: dict | None = None,
):
    config = load_config(Path(workdir) / "config.yaml")["scenes"][scene]
    model = {**config["model"], **(changes or {})}
    settings = TrainSettings.from_scene(
        {"model": model, "seed": 0, "torch_threads": config["torch_threads"]}
    )
    ts = TrainingSet.load(Path(workdir) / "results" / scene / "dataset" / "trainset")
    print(f"{'lr':>8s} {'seed':>4s} {'P':>3s} {'train':>9s} {'val MSE':>9s} {'wall s':>7s}")
    for rate in rates:
        for seed in seeds:
            for percent in fractions:
                run = replace(settings, lr=rate, seed=seed)
                with tempfile.TemporaryDirectory() as out:
                    began = time.perf_counter()
                    train(ts, out, percent, run, progress=False, replicate=0)
                    wall = time.perf_counter() - began
                    last = pd.read_csv(Path(out) / "losses.csv").iloc[-1]
                    estimator = DepthEstimator.from_checkpoint(Path(out) / "model.pt", device="cpu")
                    mse = coordinate_mse(estimator, ts)["mse"].mean()
                print(
                    f"{rate:8.1e} {seed:4d} {percent:3d} {last['train_loss']:9.5f} {mse:9.5f} "
                    f"{wall:7.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    workdir, scene, fractions, rates, seeds = sys.argv[1:6]
    main(
        workdir,
        scene,
        [int(p) for p in fractions.split(",")],
        [float(r) for r in rates.split(",")],
        [int(s) for s in seeds.split(",")],
        {k: yaml.safe_load(v) for k, v in (a.split("=", 1) for a in sys.argv[6:])},
    )
