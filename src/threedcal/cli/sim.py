"""`threedcal sim realism`: the optical simulator's figures beside a real ball dataset's."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--real",
        required=True,
        help="real ball-image folder (e.g. ../shared/data/gelsight_ball_fots)",
    )
    parser.add_argument(
        "--sensor",
        default="gelsight_mini",
        help="sensor profile whose optics are rendered, at the dataset's frame size and scale",
    )
    parser.add_argument("--seed", type=int, default=0)


def _realism(args: argparse.Namespace) -> int:
    from threedcal.profiles import load_profile
    from threedcal.sim.realism import compare, format_table, load_ball_dataset

    data = load_ball_dataset(args.real)
    profile = load_profile("sensor", args.sensor)
    rows = compare(data, profile, seed=args.seed)
    print(
        f"realism: {profile['name']} optics at {data.width_px}x{data.height_px}, "
        f"{data.px_per_mm} px/mm, ball {data.ball_radius_mm} mm, {len(data.labels)} images of {data.root}"
    )
    print(format_table(rows))
    bad = [r["figure"] for r in rows if not r["ok"]]
    if bad:
        print(f"realism: FAIL, out of the real range by more than the tolerance: {', '.join(bad)}")
        return 1
    print("realism: ok, every simulated figure within the real range and tolerance")
    return 0


COMMANDS = [
    Command(
        ("sim", "realism"),
        "compare simulator statistics with a real ball-image dataset (exit 1 when out of tolerance)",
        _realism,
        _configure,
    )
]
