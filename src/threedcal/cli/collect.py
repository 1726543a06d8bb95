"""`threedcal collect`: probe one scene of a config outside Snakemake (resumes an existing store)."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


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


COMMANDS = [
    Command(
        ("collect",),
        "probe a scene's plan into its Zarr store (resumable)",
        "collect:run_collect",
        _configure,
    )
]
