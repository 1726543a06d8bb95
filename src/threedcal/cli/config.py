"""`threedcal config check`, `threedcal config reference` and `threedcal profiles list`."""

from __future__ import annotations

import argparse

from threedcal.cli import Command


def _check(args: argparse.Namespace) -> int:
    from threedcal.evaluate.objects import check_object_files
    from threedcal.study.config import load_config
    from threedcal.study.paths import scene_targets

    config = load_config(args.config, check_files=True)
    check_object_files(config, source=args.config)
    print(f"{args.config}: valid, {len(config['scenes'])} scene(s)")
    for name, scene in config["scenes"].items():
        print(
            f"  {name}: sensor={scene['sensor']} printer={scene.get('printer')} seed={scene['seed']}"
        )
        for target in scene_targets(name, scene):
            print(f"    {target}")
    return 0


def _list_profiles(args: argparse.Namespace) -> int:
    from threedcal.profiles import KINDS, builtin_names, load_profile

    for kind in KINDS:
        print(f"{kind}s:")
        for name in builtin_names(kind):
            profile = load_profile(kind, name)
            print(f"  {name:16s} {profile.get('description', '')}")
    return 0


def _reference(args: argparse.Namespace) -> int:
    from pathlib import Path

    from threedcal.schema import reference_table, with_reference

    if args.write is None:
        print(reference_table(), end="")
        return 0
    page = Path(args.write)
    page.write_text(with_reference(page.read_text()))
    print(f"{page}: reference regenerated from the config schema")
    return 0


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
        _check,
        lambda p: p.add_argument("config", help="config YAML (e.g. config.yaml)"),
    ),
    Command(
        ("config", "reference"),
        "print every config key (allowed values, default, meaning) from the schema, or write "
        "it into a page",
        _reference,
        _reference_args,
    ),
    Command(("profiles", "list"), "list the built-in sensor and printer profiles", _list_profiles),
]
