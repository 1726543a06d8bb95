"""`threedcal reskin read`: check a ReSkin board (or the simulated one) by printing a few readings."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        required=True,
        help="serial device (/dev/ttyACM0, COM4), pyserial URL, or 'sim' (the simulated board)",
    )
    parser.add_argument("--sensor", default="reskin", help="magnetic sensor profile (name or YAML)")
    parser.add_argument("--count", type=int, default=5, help="readings to print (>= 1)")


COMMANDS = [
    Command(
        ("reskin", "read"),
        "flush, then print readings from a ReSkin board (checks port, baud rate and line format)",
        "reskin:run_reskin_read",
        _configure,
    )
]
