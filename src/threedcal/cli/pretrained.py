"""`threedcal pretrained show | install`: the weights the package ships for `model.init: pretrained`."""

from __future__ import annotations

import argparse
import filecmp
import shutil
from pathlib import Path

from threedcal.cli import Command


def _show(args: argparse.Namespace) -> int:
    import threedcal.pretrained as pretrained
    from threedcal.pretrained import provenance, shipped_sensors

    SHIPPED_DIR = pretrained.SHIPPED_DIR
    sensors = shipped_sensors()
    if not sensors:
        print(f"no pretrained weights in {SHIPPED_DIR} (make pretrained builds them)")
        return 0
    for sensor in sensors:
        record = provenance(sensor)
        size_kb = (SHIPPED_DIR / f"{sensor}.pt").stat().st_size / 1024
        training = record["training"]
        print(
            f"{sensor}: {record['preset']}, {record['image_shape'][0]} x {record['image_shape'][1]} "
            f"px (dataset.downscale: {record['downscale']}), {size_kb:.0f} KB; units "
            f"{record['units'][0]}-{record['units'][1]}, {record['frames']} presses, "
            f"{training['steps']} steps in {training['precision']} on {training['machine']['cpu_capability']}"
        )
        print(f"  settings {record['settings_digest'][:12]}, code {record['code_digest'][:12]}")
    return 0


def _install(args: argparse.Namespace) -> int:
    """Copy results/pretrained/{sensor}/ into the package, saying which files changed."""
    import threedcal.pretrained as pretrained
    from threedcal.errors import ConfigError

    SHIPPED_DIR = pretrained.SHIPPED_DIR
    built = Path(args.results)
    sensors = sorted(p.parent.name for p in built.glob("*/model.pt"))
    if not sensors:
        raise ConfigError(f"{built}: no */model.pt to install (run `make pretrained` first)")
    SHIPPED_DIR.mkdir(parents=True, exist_ok=True)
    for sensor in sensors:
        for source, name in (("model.pt", f"{sensor}.pt"), ("provenance.json", f"{sensor}.json")):
            origin, target = built / sensor / source, SHIPPED_DIR / name
            if not origin.is_file():
                raise ConfigError(f"{origin}: missing; rebuild with `make pretrained`")
            same = target.is_file() and filecmp.cmp(origin, target, shallow=False)
            if not same:
                shutil.copyfile(origin, target)
            print(f"{target}: {'unchanged (the same bytes)' if same else 'installed'}")
    return 0


def _configure_install(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "results", nargs="?", default="results/pretrained", help="what `make pretrained` built"
    )


COMMANDS = [
    Command(("pretrained", "show"), "the shipped pretrained weights and their provenance", _show),
    Command(
        ("pretrained", "install"),
        "copy rebuilt pretrained weights into the package (make pretrained does this)",
        _install,
        _configure_install,
    ),
]
