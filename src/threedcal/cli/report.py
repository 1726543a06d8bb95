"""`threedcal report results-page` and `threedcal report stage-times`: pages from a finished
study's results/ folder (threedcal.report); `threedcal report cli-reference`: the command-line
reference page (threedcal.cli.reference)."""

from __future__ import annotations

import argparse

from threedcal.cli import Command, print_or_write_reference
from threedcal.cli.reference import cli_reference, with_cli_reference


def _results_page_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "results",
        nargs="?",
        default="results",
        help="a finished study's results folder",
    )
    parser.add_argument("--out", default="docs/results.md", help="the page to write")


def _cli_reference(args: argparse.Namespace) -> int:
    return print_or_write_reference(
        args.write, cli_reference, with_cli_reference, "the command-line parser"
    )


COMMANDS = [
    Command(
        ("report", "results-page"),
        "write the results page from a finished study's results folder, each table with its "
        "protocol",
        "results_page:run_report_results_page",
        _results_page_args,
    ),
    Command(
        ("report", "stage-times"),
        "print where a study's time went: its jobs' benchmark files summed per stage",
        "stage_times:run_report_stage_times",
        lambda p: p.add_argument("results", nargs="?", default="results", help="results folder"),
    ),
    Command(
        ("report", "cli-reference"),
        "print the command-line reference (Markdown), or regenerate it in a page with --write",
        _cli_reference,
        lambda p: p.add_argument(
            "--write",
            metavar="PAGE",
            help="replace the generated reference in PAGE (docs/reference/cli.md)",
        ),
    ),
]
