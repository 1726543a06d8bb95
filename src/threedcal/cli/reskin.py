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


def _run(args: argparse.Namespace) -> int:
    import contextlib

    from threedcal.hardware.reskin import ReSkinReader, value_names
    from threedcal.profiles import load_profile

    if args.count < 1:
        from threedcal.errors import ConfigError

        raise ConfigError(f"--count must be a whole number >= 1, got {args.count}")
    sensor = load_profile("sensor", args.sensor)
    with contextlib.ExitStack() as stack:
        port = args.port
        if port == "sim":
            from threedcal.sim.reskin import ReSkinBench

            port = stack.enter_context(ReSkinBench(sensor, 2.0, {}, 0)).sensor_url
        reader = stack.enter_context(ReSkinReader(sensor, port))
        reader.flush()
        readings, stamps = reader.capture(args.count)
    print("t_s\t" + "\t".join(value_names(sensor)))
    for stamp, values in zip(stamps - stamps[0], readings, strict=True):
        print(f"{stamp:.3f}\t" + "\t".join(f"{v:.2f}" for v in values))
    return 0


COMMANDS = [
    Command(
        ("reskin", "read"),
        "flush, then print readings from a ReSkin board (checks port, baud rate and line format)",
        _run,
        _configure,
    )
]
