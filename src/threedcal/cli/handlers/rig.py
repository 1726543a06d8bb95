"""`threedcal rig`: the set-up page in the browser (threedcal.page)."""

from __future__ import annotations

import argparse
import sys

from threedcal.errors import ConfigError
from threedcal.page.control import RigControl
from threedcal.page.server import check_host, is_loopback, serve


def run_rig(args: argparse.Namespace) -> int:
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
