"""`threedcal sim realism`: the optical simulator's figures beside a real ball dataset's."""

from __future__ import annotations

import argparse
from pathlib import Path

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


def _realism(args: argparse.Namespace) -> int:
    from threedcal.errors import ConfigError
    from threedcal.realism.folder import realism_report

    if args.in_sample and args.write_fitted:
        raise ConfigError("--write-fitted needs the fit: leave out --in-sample")
    if args.write_fitted:  # checked before the fit: it takes minutes, then writes
        fitted = Path(args.write_fitted)
        if fitted.exists():
            raise ConfigError(
                f"--write-fitted {fitted}: already exists; refusing to overwrite it (a profile "
                "you may have tuned): choose another path or move it away"
            )
        if not fitted.parent.is_dir():
            raise ConfigError(f"--write-fitted {fitted}: folder {fitted.parent} does not exist")
    text, ok = realism_report(
        args.real,
        args.sensor,
        seed=args.seed,
        split_seed=args.split_seed,
        fit=not args.in_sample,
        fitted_out=args.write_fitted,
        gel_mechanics=args.gel_mechanics,
    )
    print(text, end="")
    return 0 if ok else 1


COMMANDS = [
    Command(
        ("sim", "realism"),
        "fit the optics on half of a real ball-image dataset, compare on the other half (exit 1 when out of tolerance)",
        _realism,
        _configure,
    )
]
