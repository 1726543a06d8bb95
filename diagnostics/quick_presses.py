"""What the quick calibration's few presses cost, apart from its registration.

A finished `make quick-study` compares each unit's quick model with its full calibration, and the
two differ in two ways: the quick run has 40 presses where the full one has hundreds, and it
registered its camera from those 40 presses where the full one used a lattice of its own. This
takes the second difference away. Per unit, as many presses as the quick run had are drawn at
random from the full calibration's own training presses (its registration, its labels), and
trained as the quick loop trains them (rounds of `plan.round_presses`, each fine-tuned for
`quick.steps` from the last round's weights, round 1 from the shipped weights), then scored with
the full calibration's P = 80 models on its validation presses, as units.csv scores them. The
change over units is the presses' share; units.csv's is the presses' and the registration's.

    .venv/bin/python -m diagnostics.quick_presses [--results DIR] [--units digit_u11 ...] [--seed N]
        [--steps N]

About 4 minutes a unit on one core (four fine-tunings and the scoring); `--smoke`: one simulated
unit's 12 presses, tiny trainings.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from scipy import stats

from threedcal.dataset.trainset import TrainingSet
from threedcal.dataset.unit_presses import simulate_units
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings
from threedcal.profiles import load_profile
from threedcal.study.config import compared_with, load_config, scene_config
from threedcal.study.quick_arms import ArmModel, validation_scores
from threedcal.study.quick_loop import round_train_settings

LEVEL = 0.95


def drawn_presses(full: TrainingSet, count: int, seed: int) -> TrainingSet:
    """`count` of the full set's training presses drawn at random, each with its frame, all
    training (no subset split), in the order the rounds add them."""
    train_rows = np.flatnonzero(full.split == "train")
    if count > len(train_rows):
        raise ValueError(f"{count} presses asked, the full set trains on {len(train_rows)}")
    rows = np.random.default_rng(seed).choice(train_rows, count, replace=False)
    samples = full.samples.iloc[rows].reset_index(drop=True)
    samples = samples[[c for c in samples.columns if not c.startswith("min_p_r")]]
    samples = samples.assign(frame=np.arange(count), split="train", min_p=1)
    frames = np.asarray(full.frames)[rows]
    return TrainingSet(
        frames,
        full.blank,
        samples,
        full.px_per_mm,
        full.sphere_radius_mm,
        full.max_slope_deg,
        full.meta,
    )


def first(trainset: TrainingSet, count: int) -> TrainingSet:
    """The set's first `count` presses (one round's data so far)."""
    samples = trainset.samples.iloc[:count]
    return replace(trainset, frames=trainset.frames[:count], samples=samples)


def presses_change(
    validation: TrainingSet,
    splits: pd.DataFrame,
    full_models: list[str],
    presses: int,
    per_round: int,
    settings,
    seed: int,
    work: Path,
) -> dict:
    """`presses` drawn from `validation`'s training presses, fine-tuned in rounds of `per_round`
    as the quick loop does (`settings`: threedcal.study.quick_loop.round_train_settings), and
    its mean validation MSE against the full models'."""
    drawn = drawn_presses(validation, presses, seed)
    model = None
    for count in range(per_round, presses + 1, per_round):
        out = work / f"round_{count}"
        if model is not None:
            settings = replace(settings, init=str(model))
        train(first(drawn, count), out, 80, settings, progress=False)
        model = out / "model.pt"
    models = [
        ArmModel("full", None, 0, math.nan, 0, tuple(map(str, full_models))),
        ArmModel("drawn", 1, presses, math.nan, 0, (str(model),)),
    ]
    scores = validation_scores(models, validation, splits)
    drawn_mse = float(scores[scores["arm"] == "drawn"]["mse"].mean())
    full_mse = float(scores[scores["arm"] == "full"]["mse"].mean())
    return {
        "presses": presses,
        "drawn_mse": drawn_mse,
        "full_mse": full_mse,
        "change": drawn_mse / full_mse - 1,
    }


def unit_change(results: Path, scene: dict, quick: str, full: str, seed: int, work: Path) -> dict:
    """One unit of a finished quick study: as many presses as its quick run had."""
    stop = json.loads((results / quick / "quick" / "stop.json").read_text())
    full_models = sorted(glob.glob(str(results / full / "models" / "P80" / "r*" / "model.pt")))
    row = presses_change(
        TrainingSet.load(results / full / "dataset" / "trainset"),
        pd.read_csv(results / full / "dataset" / "splits.csv"),
        full_models,
        int(stop["presses"]),
        int(stop["round_presses"]),
        round_train_settings(scene),
        seed,
        work / quick,
    )
    return {"unit": full, **row}


def smoke_unit() -> tuple[TrainingSet, pd.DataFrame, TrainSettings]:
    """The smoke modes' stand-in for a finished calibration (this one's and registration_cost's):
    one simulated unit's 12 presses labelled exactly, half validating; their splits table; training
    settings of a few steps."""
    presses = simulate_units(
        load_profile("sensor", "digit_fots"),
        [7100],
        12,
        (0.9, 1.1),
        2.0,
        factor=2,
        val_units=0,
        progress=False,
    )
    split = np.where(np.arange(12) % 2 == 0, "train", "val")
    samples = presses.samples.drop(columns="unit").assign(
        split=split, min_p=np.where(split == "train", 80, 0)
    )
    unit = TrainingSet(
        presses.frames,
        presses.unit_blanks[0],
        samples,
        presses.px_per_mm,
        presses.sphere_radius_mm,
        presses.max_slope_deg,
        presses.meta,
    )
    splits = samples[["point"]].assign(
        x_mm=samples["center_x_px"] / presses.px_per_mm,
        y_mm=samples["center_y_px"] / presses.px_per_mm,
    )
    fixed = {"rule": "doubling", "holdout": 0.0, "first_cycle": 4, "min_gain": 0.0, "max_steps": 4}
    settings = TrainSettings.of(
        preset="context_half",
        init="pretrained",
        batch_size=2,
        stopping=fixed,
        seed=0,
        torch_threads=1,
    )
    return unit, splits, settings


def smoke(work: Path) -> dict:
    """The whole path on one simulated unit's 12 presses (6 validate), tiny trainings."""
    validation, splits, settings = smoke_unit()
    train(validation, work / "full", 80, settings, progress=False)
    row = presses_change(
        validation, splits, [str(work / "full" / "model.pt")], 4, 2, settings, 0, work
    )
    return {"unit": "smoke", **row}


def over_units(changes: list[float]) -> tuple[float, float, float]:
    """The mean change and its Student's t interval over units (as quick_study's claim)."""
    values = np.asarray(changes, float)
    mean = float(values.mean())
    if len(values) < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + LEVEL / 2, len(values) - 1) * stats.sem(values))
    return mean, mean - half, mean + half


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", default="results", type=Path)
    parser.add_argument("--config", default="config/quick_study.yaml")
    parser.add_argument("--units", nargs="*", help="full scenes (default: every compared one)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--steps", type=int, help="fine-tuning steps a round (default: quick.steps)"
    )
    parser.add_argument("--smoke", action="store_true", help="one simulated unit, tiny trainings")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.smoke:
        with tempfile.TemporaryDirectory() as work:
            row = smoke(Path(work))
        print(json.dumps(row))
        return row
    config = load_config(args.config)
    pairs = [
        (name, compared_with(scene))
        for name, scene in config["scenes"].items()
        if compared_with(scene) and (not args.units or compared_with(scene) in args.units)
    ]
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for quick, full in pairs:
            scene = scene_config(config, quick)
            if args.steps:  # what more (or fewer) steps a round would buy
                scene = {**scene, "quick": {**(scene.get("quick") or {}), "steps": args.steps}}
            row = unit_change(args.results, scene, quick, full, args.seed, Path(work))
            row["sensor"] = config["scenes"][full]["sensor"]
            rows.append(row)
            print(json.dumps(row), flush=True)
    table = pd.DataFrame(rows)
    groups = {str(s): part for s, part in table.groupby("sensor", sort=False)}
    groups["all"] = table
    for name, part in groups.items():
        mean, low, high = over_units(part["change"].tolist())
        print(
            f"{name}: {int(part['presses'].max())} presses drawn from the full calibration, "
            f"against its P = 80 models over {len(part)} units: {mean:+.1%} "
            f"({LEVEL:.0%} interval {low:+.1%} to {high:+.1%})"
        )
    return {"units": rows}


if __name__ == "__main__":
    main()
