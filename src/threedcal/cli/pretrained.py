"""`threedcal pretrained show | install`: the weights the package ships for `model.init: pretrained`."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _configure_install(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "results", nargs="?", default="results/pretrained", help="what `make pretrained` built"
    )


COMMANDS = [
    Command(
        ("pretrained", "show"),
        "the shipped pretrained weights and their provenance",
        "builtin:run_pretrained_show",
    ),
    Command(
        ("pretrained", "install"),
        "copy rebuilt pretrained weights into the package (make pretrained does this)",
        "builtin:run_pretrained_install",
        _configure_install,
    ),
]
