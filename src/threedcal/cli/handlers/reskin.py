"""`threedcal reskin read`: check a ReSkin board (or the simulated one) by printing a few readings."""

from __future__ import annotations

import argparse
import contextlib

from threedcal.errors import ConfigError
from threedcal.hardware.reskin import ReSkinReader, value_names
from threedcal.profiles import load_profile
from threedcal.sim.reskin import ReSkinBench


def run_reskin_read(args: argparse.Namespace) -> int:
    if args.count < 1:
        raise ConfigError(f"--count must be a whole number >= 1, got {args.count}")
    sensor = load_profile("sensor", args.sensor)
    with contextlib.ExitStack() as stack:
        port = args.port
        if port == "sim":
            port = stack.enter_context(ReSkinBench(sensor, 2.0, {}, 0)).sensor_url
        reader = stack.enter_context(ReSkinReader(sensor, port))
        reader.flush()
        readings, stamps = reader.capture(args.count)
    print("t_s\t" + "\t".join(value_names(sensor)))
    for stamp, values in zip(stamps - stamps[0], readings, strict=True):
        print(f"{stamp:.3f}\t" + "\t".join(f"{v:.2f}" for v in values))
    return 0
