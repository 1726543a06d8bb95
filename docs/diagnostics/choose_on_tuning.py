"""Train one model of a scene with changed settings and score it on the test objects' tuning
presses: how docs/explanation/labels.md chose `model.loss` and `dataset.max_depth_over_radius`.

Usage (from a study's folder, after its `dataset` and `object_presses` stages):
    python docs/diagnostics/choose_on_tuning.py SCENE P NAME [--model KEY=VALUE ...]
        [--max-depth-over-radius X] [--replicate R] [--seed-of R2]
Trains replicate R (default 0; each has its own training draw and initialisation, as in rule
`train`) into /tmp/choose_on_tuning/SCENE_NAME/P{P}/r{R}/ (reused when there), scores every press
under both protocols (what rule `objects` does) and prints tuning.csv only: settings are chosen on
the tuning presses, never on the reporting ones. Frames pressed
deeper than X times R are taken out of the built training set, as the dataset stage does.
`--seed-of R2` trains on replicate R's subset with replicate R2's seed (initialisation, patch draws
and order; folder r{R}_seed{R2}): which of the two moves a figure between replicates.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
import yaml

from threedcal.config import load_config
from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.object_scores import evaluate_objects
from threedcal.model.train import TrainSettings, train
from threedcal.scenes import stage_config


def without_deep_presses(ts: TrainingSet, ratio: float, touch_offset_mm: float) -> TrainingSet:
    """The set with presses planned deeper than ratio x R moved out of every split (a label's
    depth is the planned one plus the registered touch offset)."""
    samples = ts.samples.copy()
    planned = samples["depth_mm"].to_numpy() - touch_offset_mm
    deep = planned > ratio * ts.sphere_radius_mm + 1e-9
    samples.loc[deep, "split"] = "left_out"
    return TrainingSet(
        frames=ts.frames,
        blank=ts.blank,
        samples=samples,
        px_per_mm=ts.px_per_mm,
        sphere_radius_mm=ts.sphere_radius_mm,
        max_slope_deg=ts.max_slope_deg,
        meta=ts.meta,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("p", type=int)
    parser.add_argument("name")
    parser.add_argument("--model", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--max-depth-over-radius", type=float)
    parser.add_argument("--replicate", type=int, default=0)
    parser.add_argument("--seed-of", type=int, help="train with this replicate's seed")
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    args = parser.parse_args()
    config = load_config(args.config)
    scene = config["scenes"][args.scene]
    for item in args.model:
        key, value = item.split("=", 1)
        scene["model"][key] = yaml.safe_load(value)
    results = Path("results") / args.scene
    out = Path("/tmp/choose_on_tuning") / f"{args.scene}_{args.name}"
    seeded = "" if args.seed_of is None else f"_seed{args.seed_of}"
    run = out / f"P{args.p}" / f"r{args.replicate}{seeded}"
    model = run / "model.pt"
    if not model.is_file():
        ts = TrainingSet.load(results / "dataset/trainset")
        if args.max_depth_over_radius is not None:
            registration = json.loads((results / "dataset/registration.json").read_text())
            offset = registration["touch_offset_mm"]
            ts = without_deep_presses(ts, args.max_depth_over_radius, offset)
        train_frames = ts.indices("train", percent=args.p, replicate=args.replicate)
        print(f"training on {len(train_frames)} frames", flush=True)
        began = time.perf_counter()
        settings = TrainSettings.from_scene(
            {k: scene[k] for k in ("model", "seed", "torch_threads") if k in scene}
        )
        if args.seed_of is not None:  # train() seeds replicate r by splits.replicate_seed
            from threedcal.dataset import splits

            own = splits.replicate_seed
            splits.replicate_seed = lambda seed, _r: own(seed, args.seed_of)
        train(ts, run, args.p, settings, replicate=args.replicate, progress=False)
        print(f"trained in {time.perf_counter() - began:.0f} s", flush=True)
    objects = stage_config(scene, "objects")
    torch.set_num_threads(objects["torch_threads"])
    evaluate_objects(
        objects,
        {args.p: str(model)},
        results / "objects/pressing",
        results / "dataset/registration.json",
        run / "objects",
    )
    tuning = pd.read_csv(run / "objects/tuning.csv").query("protocol == 'printer'")
    columns = ["object", "protocol", "presses", "overall_um", "type1_um", "type2_um"]
    print(tuning[columns].round(1).to_string(index=False))
    print(f"mean Type 2 over objects: {np.mean(tuning['type2_um']):.1f} um (tuning presses)")


if __name__ == "__main__":
    main()
