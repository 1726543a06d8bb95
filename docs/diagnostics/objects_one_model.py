"""Score one trained model on a scene's test-object presses under both protocols, before the other
fractions of the ablation have trained: what rule `objects` does, restricted to the models given.

Usage (from the study's folder, after its `object_presses` and `dataset` stages and the model ran):
    python docs/diagnostics/objects_one_model.py SCENE P [REPLICATE] [--out DIR]
Writes errors.csv, tuning.csv, presses.csv, integrators.csv and figures into DIR (default
/tmp/objects_one_model/SCENE) and prints errors.csv. Reads config.yaml of the current folder.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from threedcal.config import load_config
from threedcal.evaluate.object_scores import evaluate_objects
from threedcal.scenes import stage_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("p", type=int)
    parser.add_argument("replicate", type=int, nargs="?", default=0)
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    config = load_config(args.config)
    scene = stage_config(config["scenes"][args.scene], "objects")
    torch.set_num_threads(scene["torch_threads"])
    results = Path("results") / args.scene
    out = args.out or Path("/tmp/objects_one_model") / args.scene
    out.mkdir(parents=True, exist_ok=True)
    model = results / f"models/P{args.p}/r{args.replicate}/model.pt"
    evaluate_objects(
        scene,
        {args.p: str(model)},
        results / "objects/pressing",
        results / "dataset/registration.json",
        out,
    )
    print((out / "errors.csv").read_text())


if __name__ == "__main__":
    main()
