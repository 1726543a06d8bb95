"""How a scene's models improve with the training budget: replicate 0 of each P trained at several
`epochs_base` values on a finished study's trainset (docs/statistics.md, "The training budget").

    .venv/bin/python docs/diagnostics/training_budget.py WORKDIR SCENE P[,P...] EPOCHS_BASE[,...]

Prints the last epoch's training loss, the validation loss the trainer logs (128 fixed patches of the
validation coordinates) and the wall time. A diagnostic: the stats stage scores every validation
frame in full. Its only use as a setting: P = 80 %'s losses at 2 base epochs, far from trained,
made the default `epochs_base` 4 for every P alike.
"""

import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.model.train import TrainSettings, train


def main(workdir: str, scene: str, fractions: list[int], budgets: list[int]) -> None:
    record = Path(workdir) / "results" / scene / "scene.json"
    config = json.loads(record.read_text())["config"]  # the scene as the study ran it
    settings = TrainSettings.from_scene(config)
    ts = TrainingSet.load(Path(workdir) / "results" / scene / "dataset" / "trainset")
    print(f"{'P':>3s} {'epochs_base':>11s} {'epochs':>6s} {'train':>9s} {'val':>9s} {'wall s':>7s}")
    for percent in fractions:
        for budget in budgets:
            run = replace(settings, epochs_base=budget)
            with tempfile.TemporaryDirectory() as out:
                began = time.perf_counter()
                train(ts, out, percent, run, progress=False)
                wall = time.perf_counter() - began
                losses = pd.read_csv(Path(out) / "losses.csv")
            last = losses.iloc[-1]
            print(
                f"{percent:3d} {budget:11d} {run.epochs(percent):6d} {last['train_loss']:9.5f} "
                f"{last['val_loss']:9.5f} {wall:7.1f}"
            )


if __name__ == "__main__":
    main(
        sys.argv[1],
        sys.argv[2],
        [int(p) for p in sys.argv[3].split(",")],
        [int(b) for b in sys.argv[4].split(",")],
    )
