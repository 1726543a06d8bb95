"""`threedcal printer ports`, `threedcal printer check` and `threedcal sim soak`."""

from __future__ import annotations

import argparse
import sys

from threedcal.cli import Command


def _ports(args: argparse.Namespace) -> int:
    from threedcal.hardware.printer import list_ports

    ports = list_ports()
    if not ports:
        print("no serial ports found (is the printer plugged in and powered?)")
    for device, description, hwid in ports:
        print(f"{device}\t{description}\t{hwid}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from threedcal.hardware.printer import MarlinHost

    with MarlinHost(args.port, args.printer) as host:
        info = host.firmware_info
        print(f"port: {args.port} ({host.profile['name']}, {host.profile['baudrate']} baud)")
        print(f"firmware: {info.get('FIRMWARE_NAME', 'unknown')}")
        if "MACHINE_TYPE" in info:
            print(f"machine: {info['MACHINE_TYPE']}")
        if args.home:
            host.home()
        pos = host.position()
        print(
            f"position: X={pos.x:.3f} Y={pos.y:.3f} Z={pos.z:.3f} mm"
            + ("" if host.homed else " (not homed)")
        )
    return 0


def _soak(args: argparse.Namespace) -> int:
    from threedcal.sim.marlin import RECOVERABLE_FAULTS, parse_faults
    from threedcal.sim.soak import check_soak_arguments, soak_table, table_header

    check_soak_arguments(args.faults, args.rate, args.speedup)
    kinds = parse_faults(args.kinds) if args.kinds else RECOVERABLE_FAULTS
    results = soak_table(args.faults, args.seed, rate=args.rate, kinds=kinds, speedup=args.speedup)
    print(table_header())
    for result in results:
        print(result.row())
        if result.reordered:
            print(f"  {result.kind}: executed commands are out of order", file=sys.stderr)
    bad = [r.kind for r in results if not r.ok]
    if bad:
        print(f"FAILED: {', '.join(bad)}", file=sys.stderr)
    return 1 if bad else 0


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
    Command(("printer", "ports"), "list serial ports", _ports),
    Command(
        ("printer", "check"),
        "handshake with a Marlin printer, show firmware and position",
        _check,
        _configure_check,
    ),
    Command(
        ("sim", "soak"),
        "drive the host against the fake firmware with N faults per class; fail if a command is "
        "lost, repeated, reordered or acknowledged too early",
        _soak,
        _configure_soak,
    ),
]
