"""`threedcal config check`, `threedcal config reference` and `threedcal profiles list`."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _reference_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--write",
        metavar="PAGE",
        help="replace the generated table in PAGE (docs/reference/configuration.md)",
    )


COMMANDS = [
    Command(
        ("config", "check"),
        "validate a study config as a run would (schema, duplicate keys, plans, fault names, "
        "imported data) and list each scene's result files",
        "config:run_config_check",
        lambda p: p.add_argument("config", help="config YAML (e.g. config.yaml)"),
    ),
    Command(
        ("config", "reference"),
        "print every config key (allowed values, default, meaning) from the schema, or write "
        "it into a page",
        "builtin:run_config_reference",
        _reference_args,
    ),
    Command(
        ("profiles", "list"),
        "list the built-in sensor and printer profiles",
        "builtin:run_profiles_list",
    ),
]
