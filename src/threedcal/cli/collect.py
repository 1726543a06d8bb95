"""`threedcal collect`: probe one scene of a config outside Snakemake (resumes an existing store)."""

from __future__ import annotations

import argparse

from threedcal.cli import Command, ask_on_console


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="study config (e.g. config.yaml)")
    parser.add_argument("--scene", required=True, help="scene name in the config")
    parser.add_argument(
        "--out",
        help="store path (default results/<scene>/raw.zarr): resumed with the same settings, "
        "never overwritten",
    )
    parser.add_argument(
        "--estimate",
        action="store_true",
        help="only print the plan's duration on the real printer (no capture)",
    )


def _run(args: argparse.Namespace) -> int:
    import json

    from threedcal.study.config import load_config, scene_config
    from threedcal.study.session import collect_scene, estimate_hardware_s, prepare

    config = load_config(args.config)
    scene = scene_config(config, args.scene)
    if "import" in scene:
        from threedcal.errors import ConfigError

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


COMMANDS = [
    Command(("collect",), "probe a scene's plan into its Zarr store (resumable)", _run, _configure)
]
