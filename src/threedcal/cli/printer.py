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
    from threedcal.sim.soak import run_soak

    result = run_soak(args.faults, args.seed, rate=args.rate, speedup=args.speedup)
    print(", ".join(f"{k}={v}" for k, v in result.fault_counts.items()), file=sys.stderr)
    if result.reordered:
        print("executed commands are out of order", file=sys.stderr)
    print(result.line())
    return 0 if result.ok else 1


def _configure_check(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        required=True,
        help="serial device (/dev/ttyUSB0, COM3) or pyserial URL (simmarlin://x)",
    )
    parser.add_argument(
        "--printer", default="ender3", help="printer profile name or YAML path (default: ender3)"
    )
    parser.add_argument(
        "--home", action="store_true", help="home all axes (G28) before reading the position"
    )


def _configure_soak(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--faults", type=int, required=True, help="inject at least this many faults"
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the faults and the moves (default 0)"
    )
    parser.add_argument(
        "--rate", type=float, default=0.2, help="fault probability per line (default 0.2)"
    )
    parser.add_argument(
        "--speedup",
        type=float,
        default=1e5,
        help="simulated seconds per real second (default 1e5; inf: no pacing)",
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
        "drive the host against the fake firmware with N injected faults; fail if a command is lost, repeated or reordered",
        _soak,
        _configure_soak,
    ),
]
