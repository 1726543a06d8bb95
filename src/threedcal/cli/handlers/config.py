"""`threedcal config check`: a study config validated as a run would, with each scene's results."""

from __future__ import annotations

import argparse

from threedcal.evaluate.objects import check_object_files
from threedcal.study.config import load_config
from threedcal.study.paths import scene_targets


def run_config_check(args: argparse.Namespace) -> int:
    config = load_config(args.config, check_files=True)
    check_object_files(config, source=args.config)
    print(f"{args.config}: valid, {len(config['scenes'])} scene(s)")
    for name, scene in config["scenes"].items():
        print(
            f"  {name}: sensor={scene['sensor']} printer={scene.get('printer')} seed={scene['seed']}"
        )
        for target in scene_targets(name, scene):
            print(f"    {target}")
    return 0
