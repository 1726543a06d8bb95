"""How a scene's models improve with the training budget: replicate 0 of each P trained at several
`epochs_base` values on a finished study's trainset (docs/explanation/statistics.md, "The training budget").

    .venv/bin/python docs/diagnostics/training_budget.py WORKDIR SCENE P[,P...] EPOCHS_BASE[,...] \
        [--score] [--replicate R]

Trains replicate 0 (or R: its own subset draw and initialisation). Prints the last epoch's training loss, the validation loss the trainer logs (128 fixed patches of the
validation coordinates) and the wall time. With `--score`, also each model's mean validation MSE as
the stats stage scores it (per coordinate, every validation frame) and, per budget, the paper's
tests of every P against P = 80 % (Student's t and Mann-Whitney U, two-sided, Bonferroni x5 as in
the study's six fractions; P = 80 must be among the fractions). Its only use as a setting: P = 80 %'s
losses at 2 base epochs, far from trained, made the default `epochs_base` 4 for every P alike.
"""

import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.validation import coordinate_mse
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import TrainSettings, train


def paper_tests(mse: dict[int, np.ndarray]) -> list[str]:
    """The paper's two tests of each P against P = 80 (Bonferroni over the study's 5 comparisons)."""
    reference = mse[80]
    lines = []
    for percent in sorted(p for p in mse if p != 80):
        t = stats.ttest_ind(reference, mse[percent], equal_var=True).pvalue
        u = stats.mannwhitneyu(reference, mse[percent], alternative="two-sided").pvalue
        change = mse[percent].mean() / reference.mean() - 1
        lines.append(
            f"  P = {percent} against 80: mean MSE {change:+.1%}, adjusted p t {min(1, 5 * t):.2g}, "
            f"U {min(1, 5 * u):.2g}"
        )
    return lines


def main(
    workdir: str,
    scene: str,
    fractions: list[int],
    budgets: list[int],
    score: bool = False,
    replicate: int = 0,
) -> None:
    record = Path(workdir) / "results" / scene / "scene.json"
    config = json.loads(record.read_text())["config"]  # the scene as the study ran it
    settings = TrainSettings.from_scene(config)
    ts = TrainingSet.load(Path(workdir) / "results" / scene / "dataset" / "trainset")
    print(
        f"{'P':>3s} {'epochs_base':>11s} {'epochs':>6s} {'train':>9s} {'val':>9s} {'wall s':>7s}"
        + (f" {'val MSE':>9s}" if score else "")
    )
    for budget in budgets:
        mse = {}
        for percent in fractions:
            run = replace(settings, epochs_base=budget)
            with tempfile.TemporaryDirectory() as out:
                began = time.perf_counter()
                train(ts, out, percent, run, progress=False, replicate=replicate)
                wall = time.perf_counter() - began
                losses = pd.read_csv(Path(out) / "losses.csv")
                if score:
                    estimator = DepthEstimator.from_checkpoint(Path(out) / "model.pt", device="cpu")
                    table = coordinate_mse(estimator, ts).sort_values("point")
                    mse[percent] = table["mse"].to_numpy()
            last = losses.iloc[-1]
            print(
                f"{percent:3d} {budget:11d} {run.epochs(percent):6d} {last['train_loss']:9.5f} "
                f"{last['val_loss']:9.5f} {wall:7.1f}"
                + (f" {mse[percent].mean():9.6f}" if score else ""),
                flush=True,
            )
        if score and 80 in mse:
            print("\n".join([f"epochs_base {budget}, the paper's tests:", *paper_tests(mse)]))


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--score"]
    replicate = 0
    if "--replicate" in args:
        at = args.index("--replicate")
        replicate = int(args[at + 1])
        del args[at : at + 2]
    main(
        args[0],
        args[1],
        [int(p) for p in args[2].split(",")],
        [int(b) for b in args[3].split(",")],
        score="--score" in sys.argv[1:],
        replicate=replicate,
    )
