"""`threedcal rig`: the set-up page in the browser (threedcal.page): watch the camera, jog, find
the gel, save the mount, collect."""

from __future__ import annotations

import argparse

from threedcal.cli import Command

DEFAULT_HTTP_PORT = 8765


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="study config")
    parser.add_argument("--scene", required=True, help="scene name in the config")
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on",
    )
    parser.add_argument(
        "--http-port",
        type=int,
        default=DEFAULT_HTTP_PORT,
        help="TCP port (0: any free)",
    )


COMMANDS = [
    Command(
        ("rig",),
        "the set-up page in a browser",
        "rig:run_rig",
        _configure,
    )
]
