"""`threedcal printer ports`, `threedcal printer check` and `threedcal sim soak`."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _configure_check(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        required=True,
        help="serial device (/dev/ttyUSB0, COM3) or pyserial URL (simmarlin://x)",
    )
    parser.add_argument("--printer", default="ender3", help="printer profile name or YAML path")
    parser.add_argument(
        "--home", action="store_true", help="home all axes (G28) before reading the position"
    )


def _configure_soak(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--faults",
        type=int,
        required=True,
        help="inject at least this many faults of each class",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the faults and the moves")
    parser.add_argument(
        "--rate",
        type=float,
        default=0.2,
        help="fault probability per line, in (0, 1]",
    )
    parser.add_argument(
        "--kinds",
        default="",
        help="comma-separated fault classes (default: every recoverable class, then all mixed)",
    )
    parser.add_argument(
        "--speedup",
        type=float,
        default=1e5,
        help="simulated seconds per real second, > 0 (default 1e5; inf: no pacing)",
    )


COMMANDS = [
    Command(("printer", "ports"), "list serial ports", "printer:run_printer_ports"),
    Command(
        ("printer", "check"),
        "handshake with a Marlin printer, show firmware and position",
        "printer:run_printer_check",
        _configure_check,
    ),
    Command(
        ("sim", "soak"),
        "drive the host against the fake firmware with N faults per class; fail if a command is "
        "lost, repeated, reordered or acknowledged too early",
        "printer:run_sim_soak",
        _configure_soak,
    ),
]
