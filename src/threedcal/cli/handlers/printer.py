"""`threedcal printer ports`, `threedcal printer check` and `threedcal sim soak` (the printer host
against the fake firmware)."""

from __future__ import annotations

import argparse
import sys

from threedcal.hardware.printer import MarlinHost, list_ports
from threedcal.sim.marlin import RECOVERABLE_FAULTS, parse_faults
from threedcal.sim.soak import check_soak_arguments, soak_table, table_header


def run_printer_ports(args: argparse.Namespace) -> int:
    ports = list_ports()
    if not ports:
        print("no serial ports found (is the printer plugged in and powered?)")
    for device, description, hwid in ports:
        print(f"{device}\t{description}\t{hwid}")
    return 0


def run_printer_check(args: argparse.Namespace) -> int:
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


def run_sim_soak(args: argparse.Namespace) -> int:
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
