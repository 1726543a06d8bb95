"""What ships inside the package: `threedcal profiles list`, `threedcal config reference` (the
config schema) and `threedcal pretrained show | install` (the pretrained weights). These need
PyYAML and jsonschema only, not the study's pandas (`config check` is in handlers.config)."""

from __future__ import annotations

import argparse
import filecmp
import shutil
from pathlib import Path

import threedcal.pretrained as pretrained
from threedcal.cli import print_or_write_reference
from threedcal.errors import ConfigError
from threedcal.pretrained import provenance, shipped_sensors
from threedcal.profiles import KINDS, builtin_names, load_profile
from threedcal.schema import reference_table, with_reference


def run_profiles_list(args: argparse.Namespace) -> int:
    for kind in KINDS:
        print(f"{kind}s:")
        for name in builtin_names(kind):
            profile = load_profile(kind, name)
            print(f"  {name:16s} {profile.get('description', '')}")
    return 0


def run_config_reference(args: argparse.Namespace) -> int:
    return print_or_write_reference(
        args.write, reference_table, with_reference, "the config schema"
    )


def run_pretrained_show(args: argparse.Namespace) -> int:
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


def run_pretrained_install(args: argparse.Namespace) -> int:
    """Copy results/pretrained/{sensor}/ into the package, saying which files changed."""
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
