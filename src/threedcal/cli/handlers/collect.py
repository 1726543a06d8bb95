"""`threedcal collect`: probe one scene of a config outside Snakemake (resumes an existing store)."""

from __future__ import annotations

import argparse
import json

from threedcal.cli import ask_on_console
from threedcal.errors import ConfigError
from threedcal.study.config import load_config, scene_config
from threedcal.study.session import collect_scene, estimate_hardware_s, prepare


def run_collect(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    scene = scene_config(config, args.scene)
    if "import" in scene:
        raise ConfigError(f"scene {args.scene!r} imports its data: there is nothing to collect")
    if args.estimate:
        prepared = prepare(scene, source=f"scenes.{args.scene}")
        seconds = estimate_hardware_s(
            prepared.sensor, prepared.printer, prepared.plan, progress=True
        )
        print(
            f"{len(prepared.plan)} points, {int(prepared.plan.frames.sum())} frames: "
            f"estimated_hardware_s={seconds:.0f} ({seconds / 3600:.2f} h)"
        )
        return 0
    out = args.out or f"results/{args.scene}/raw.zarr"
    summary = collect_scene(args.scene, scene, out, ask=ask_on_console)
    print(json.dumps(summary, indent=2))
    return 0
