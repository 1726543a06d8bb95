"""`threedcal objects export`: the test objects as STL files to 3D-print, with depth previews."""

from __future__ import annotations

import argparse

from threedcal.cli import Command, add_force_option


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", required=True, help="folder for <object>.stl and <object>_depth.png"
    )
    parser.add_argument(
        "--objects",
        nargs="+",
        metavar="OBJECT",
        help="built-in names (hemispheres, pill, pawn; default: all three) or STL paths",
    )
    parser.add_argument("--sensor", default="digit", help="sensor profile for the preview grid")
    parser.add_argument("--px-per-mm", type=float, help="override the sensor's px/mm")
    parser.add_argument("--indentation-mm", type=float, default=1.0, help="preview depth (mm)")
    add_force_option(parser)


COMMANDS = [
    Command(
        ("objects", "export"),
        "write the test objects as STL files (press frame: contact side toward -z) with depth previews",
        "objects:run_objects_export",
        _configure,
    )
]
