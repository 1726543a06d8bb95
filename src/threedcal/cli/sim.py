"""`threedcal sim realism`: the optical simulator's figures beside a real ball dataset's."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--real",
        required=True,
        help="real ball-image folder (e.g. data/gelsight_ball_fots)",
    )
    parser.add_argument(
        "--sensor",
        default="gelsight_mini",
        help="sensor profile whose optics are rendered, at the dataset's frame size and scale",
    )
    parser.add_argument("--seed", type=int, default=0)


def _realism(args: argparse.Namespace) -> int:
    from threedcal.sim.realism import realism_report

    text, ok = realism_report(args.real, args.sensor, seed=args.seed)
    print(text, end="")
    return 0 if ok else 1


COMMANDS = [
    Command(
        ("sim", "realism"),
        "compare simulator statistics with a real ball-image dataset (exit 1 when out of tolerance)",
        _realism,
        _configure,
    )
]
