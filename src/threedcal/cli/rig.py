"""`threedcal rig`: the set-up page in the browser (threedcal.page): watch the camera, jog, find
the gel, save the mount, collect."""

from __future__ import annotations

import argparse
import sys

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


def _run(args: argparse.Namespace) -> int:
    from threedcal.errors import ConfigError
    from threedcal.page.control import RigControl
    from threedcal.page.server import check_host, is_loopback, serve

    host = check_host(args.host)
    if not 0 <= args.http_port <= 65535:
        raise ConfigError(f"--http-port {args.http_port}: a TCP port is 0-65535")
    with RigControl(args.config, args.scene) as control:

        def announce(url: str) -> None:
            print(
                f"threedcal rig: {args.scene} at {url} (Ctrl-C ends it: the probe is lifted first)"
            )
            if not is_loopback(host):
                print(
                    f"threedcal rig: listening on {host}: anyone who reaches this machine can "
                    "move the printer",
                    file=sys.stderr,
                )
            sys.stdout.flush()

        serve(control, host, args.http_port, announce)
    print("threedcal rig: stopped; the probe is lifted and the steppers released")
    return 0


COMMANDS = [
    Command(
        ("rig",),
        "the set-up page in a browser",
        _run,
        _configure,
    )
]
