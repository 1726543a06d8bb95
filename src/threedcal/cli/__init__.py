"""The `threedcal` command line.

Each module in this package contributes subcommands through a module-level ``COMMANDS`` list of
:class:`Command`; they are discovered at start-up, so adding a command never touches this file.
These modules hold only what the parser needs (each command's options and help) and stay light, so
that ``--help`` is fast. A command's work lives in a module of :mod:`threedcal.cli.handlers`,
named by the command as ``"module:function"`` and imported only when that command runs: a handler
module imports what it needs (torch, cv2, pandas) at its top, and a command never loads another's
libraries (``predict`` and ``live`` run without the workflow extra's pandas or zarr).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from threedcal import __version__
from threedcal.errors import ConfigError, ThreedcalError


@dataclass(frozen=True)
class Command:
    """One leaf of the command tree, e.g. ``path=("sim", "soak")`` for ``threedcal sim soak``."""

    path: tuple[str, ...]
    help: str
    # the function that runs it, or "module:function" in threedcal.cli.handlers, imported when it runs
    run: Callable[[argparse.Namespace], int | None] | str
    configure: Callable[[argparse.ArgumentParser], None] = field(default=lambda parser: None)


# One-line descriptions of command groups (groups without an entry get a generic one).
GROUP_HELP = {
    "config": "check study configs",
    "profiles": "built-in sensor and printer profiles",
    "printer": "talk to a Marlin 3D printer",
    "sim": "the simulated bench: fake firmware, optical simulator",
    "objects": "test objects: CAD, STL files, ground-truth depth",
    "reskin": "the ReSkin magnetic sensor: serial check",
    "pretrained": "the weights shipped for model.init: pretrained",
    "report": "pages: a finished study's results, the command-line reference",
}


def ask_on_console(message: str) -> None:
    """A real rig's `ask` (threedcal.rig) at a terminal: say what to do, wait for Enter."""
    input(f"{message}, then press Enter... ")


def refuse_file_on_path(option: str, output: Path, folder: Path) -> None:
    """Refused before anything is written: `output` goes into `folder`, whose nearest existing
    part is a file (makedirs would raise FileExistsError or NotADirectoryError half way)."""
    taken = next((p for p in [folder, *folder.parents] if p.exists()), None)
    if taken is not None and not taken.is_dir():
        raise ConfigError(f"{option} {output}: {taken} is a file, not a folder")


def refuse_existing_outputs(
    outputs: Mapping[str, Path] | Sequence[tuple[str, Path]], force: bool
) -> None:
    """Refused before anything runs: an output file (option → path, or (option, path) pairs) that
    exists already, unless `--force` (a rerun with other settings would otherwise replace a result
    without a word)."""
    if force:
        return
    for option, path in outputs.items() if isinstance(outputs, Mapping) else outputs:
        if path.is_file():
            raise ConfigError(
                f"{option} {path}: already exists; refusing to overwrite it (choose another "
                "path, or add --force to replace it)"
            )


def print_or_write_reference(
    page: str | None,
    reference: Callable[[], str],
    with_reference: Callable[[str], str],
    source: str,
) -> int:
    """`config reference` and `report cli-reference`: the generated `reference` printed, or with
    `--write PAGE` replaced in the page (`with_reference`: between its markers) from `source`."""
    if page is None:
        print(reference(), end="")
        return 0
    path = Path(page)
    path.write_text(with_reference(path.read_text()))
    print(f"{path}: reference regenerated from {source}")
    return 0


def add_force_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--force", action="store_true", help="replace existing output files")


def shown_default(action: argparse.Action) -> str | None:
    """An argument's default as `--help` and the CLI reference show it, or None where there is
    nothing to show: no default, a flag, an empty string, or help that describes it already."""
    default = action.default
    if default in (None, argparse.SUPPRESS, "") or isinstance(default, bool) or action.required:
        return None
    if action.help and "default" in action.help:
        return None
    return " ".join(map(str, default)) if isinstance(default, list | tuple) else str(default)


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, with each argument's default (where :func:`shown_default` shows one)
    after its help."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ""
        default = shown_default(action)
        if default is None or help_text == argparse.SUPPRESS:
            return help_text
        return f"{help_text} (default: {default.replace('%', '%%')})"


def discover_commands() -> list[Command]:
    commands: list[Command] = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.ispkg:  # the handlers, loaded one module at a time by `handler`
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        commands.extend(getattr(module, "COMMANDS", []))
    return commands


def handler(
    run: Callable[[argparse.Namespace], int | None] | str,
) -> Callable[[argparse.Namespace], int | None]:
    """A :class:`Command`'s `run` as a function: itself, or the one its "module:function" names
    in threedcal.cli.handlers, whose module is imported now."""
    if callable(run):
        return run
    module, _, name = run.partition(":")
    loaded = importlib.import_module(f"{__name__}.handlers.{module}")  # local: when it runs
    return getattr(loaded, name)


def build_parser(commands: Sequence[Command] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="threedcal",
        description="Calibrate vision-based tactile sensors with a 3D printer (3D Cal).",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"threedcal {__version__}")
    groups: dict[tuple[str, ...], argparse._SubParsersAction] = {}
    groups[()] = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in commands if commands is not None else discover_commands():
        for depth in range(1, len(command.path)):
            prefix = command.path[:depth]
            if prefix not in groups:
                group = groups[prefix[:-1]].add_parser(
                    prefix[-1],
                    help=GROUP_HELP.get(prefix[-1], f"{prefix[-1]} commands"),
                    formatter_class=HelpFormatter,
                )
                groups[prefix] = group.add_subparsers(
                    dest=f"command_{depth}", metavar="COMMAND", required=True
                )
        leaf = groups[command.path[:-1]].add_parser(
            command.path[-1],
            help=command.help,
            description=command.help,
            formatter_class=HelpFormatter,
        )
        command.configure(leaf)
        leaf.set_defaults(_run=command.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    run = getattr(args, "_run", None)
    if run is None:  # bare `threedcal`
        parser.print_help()
        return 0
    try:
        return int(handler(run)(args) or 0)
    except ThreedcalError as exc:
        print(f"threedcal: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a path the system refuses (a file where a folder goes, no space, ...)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"threedcal: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("threedcal: interrupted", file=sys.stderr)
        return 130
