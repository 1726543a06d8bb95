"""Where the sensor sits on this printer: the rig's mount, kept with the scene, not the sensor.

A sensor profile's `mount` is where the authors' printed base puts the sensor on an Ender 3. A
user's base, bed or printer puts it elsewhere; that is a fact of the rig, so a scene may give its
own `mount` (inline, or the path of a YAML file that `threedcal rig` writes), and every key it
leaves out falls back to the profile's. The profile, and so the name the shipped weights are found
by (threedcal.pretrained), stays the same.
"""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from threedcal.errors import ConfigError
from threedcal.schema import load_schema, load_yaml, schema_errors

MOUNT_KEYS = ("x_offset_mm", "y_offset_mm", "z_touch_mm", "z_clearance_mm")


@dataclass(frozen=True)
class SensorMount:
    """The printer position of the probe area's origin (x, y), the Z at which the ball first
    touches the gel's apex, and how far above that the probe lifts between points (mm)."""

    x_offset_mm: float
    y_offset_mm: float
    z_touch_mm: float
    z_clearance_mm: float

    @classmethod
    def of(cls, values: Mapping[str, Any]) -> SensorMount:
        return cls(*(float(values[k]) for k in MOUNT_KEYS))

    def as_dict(self) -> dict[str, float]:
        return {f.name: round(float(getattr(self, f.name)), 4) for f in fields(self)}

    def centre_mm(self, sensor: Mapping) -> tuple[float, float]:
        """The printer X, Y of the probe area's centre, which the camera images at its centre."""
        width, height = sensor["probing"]["plan_area_mm"]
        return self.x_offset_mm + width / 2, self.y_offset_mm + height / 2


def _mount_schema() -> dict:
    schema = load_schema()
    return {**schema["$defs"]["mount"], "$defs": schema["$defs"]}


def read_mount_file(path: str | Path, key: str = "mount") -> dict[str, float]:
    """A mount file's values (any of MOUNT_KEYS), checked; `key` names the config key that gave
    the path."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f"{key}: {path} does not exist: save the mount from `threedcal rig` there, or give "
            f"the values ({', '.join(MOUNT_KEYS)}) in the scene itself"
        )
    values = load_yaml(path)
    problems = schema_errors(values, _mount_schema())
    if problems:
        raise ConfigError(f"{key}: {path} is not a valid mount\n  " + "\n  ".join(problems))
    return {k: float(v) for k, v in values.items()}


def with_mount(sensor: Mapping, values: Mapping[str, float]) -> dict:
    """The sensor profile with `values` in place of its mount's keys (the rest are the profile's)."""
    return {**sensor, "mount": {**sensor["mount"], **values}}


def mount_yaml(mount: SensorMount, about: str) -> str:
    """A mount file's text: one comment line saying what measured it, then the four values."""
    lines = [f"# {about}"] + [f"{k}: {v}" for k, v in mount.as_dict().items()]
    return "\n".join(lines) + "\n"


def write_mount_file(
    path: str | Path, mount: SensorMount, about: str, replace: bool = False
) -> Path | None:
    """Write `mount` to `path`. A file there is never overwritten silently: without `replace` it
    is refused, with it the old file is kept beside (returned; None when there was none)."""
    path = Path(path)
    kept = None
    if path.exists():
        if not replace:
            raise ConfigError(
                f"{path} exists already; refusing to overwrite it (confirm the replacement: the "
                "old file is then kept beside it)"
            )
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        kept = path.with_name(f"{path.name}.{stamp}.bak")
        n = 1
        while kept.exists():
            n += 1
            kept = path.with_name(f"{path.name}.{stamp}-{n}.bak")
        path.replace(kept)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = mount_yaml(mount, about)
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(text)
    temporary.replace(path)
    return kept
