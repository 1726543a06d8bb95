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
        help="sensor profile rendered at the dataset's frame size and scale",
    )
    parser.add_argument(
        "--gel-mechanics",
        choices=["geometric", "elastic"],
        help="overrides the profile's gel.mechanics",
    )
    parser.add_argument("--seed", type=int, default=0, help="the renderer's seed")
    parser.add_argument(
        "--split-seed",
        type=int,
        default=0,
        help="seed of the split into fitting and compared halves",
    )
    parser.add_argument(
        "--in-sample",
        action="store_true",
        help="compare the unfitted profile with every image (no split)",
    )
    parser.add_argument(
        "--write-fitted",
        metavar="PATH",
        help="also write the fitted profile as YAML (not with --in-sample)",
    )


COMMANDS = [
    Command(
        ("sim", "realism"),
        "fit the optics on half of a real ball-image dataset, compare on the other half (exit 1 when out of tolerance)",
        "sim:run_sim_realism",
        _configure,
    )
]
