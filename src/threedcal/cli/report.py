"""`threedcal report results-page` and `threedcal report stage-times`: pages from a finished
study's results/ folder (threedcal.report)."""

from __future__ import annotations

import argparse
from pathlib import Path

from threedcal.cli import Command


def _results_page(args: argparse.Namespace) -> int:
    from threedcal.report.results_page import write_results_page

    out = Path(args.out)
    write_results_page(args.results, out)
    print(f"{out}: written from {args.results}")
    return 0


def _results_page_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "results",
        nargs="?",
        default="results",
        help="a finished study's results folder (default: results)",
    )
    parser.add_argument(
        "--out", default="docs/results.md", help="the page to write (default: docs/results.md)"
    )


def _stage_times(args: argparse.Namespace) -> int:
    from threedcal.report.stage_times import stage_time_lines, stage_times

    print("\n".join(stage_time_lines(stage_times(args.results))))
    return 0


COMMANDS = [
    Command(
        ("report", "results-page"),
        "write the results page (docs/results.md) from a finished study's results folder: "
        "every table with its protocol and whether the simulator made its frames",
        _results_page,
        _results_page_args,
    ),
    Command(
        ("report", "stage-times"),
        "print where a study's time went: its jobs' benchmark files summed per stage",
        _stage_times,
        lambda p: p.add_argument(
            "results", nargs="?", default="results", help="results folder (default: results)"
        ),
    ),
]
