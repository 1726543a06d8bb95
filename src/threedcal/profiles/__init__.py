"""Profiles: every constant of a sensor or printer lives in a validated YAML file, never in code.

Built-in profiles sit in ``profiles/<kind>s/<name>.yaml`` inside the package; a config may also
name a YAML file by path. Each kind has a JSON schema in ``threedcal/schemas/<kind>.schema.yaml``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from importlib.resources import files
from pathlib import Path
from typing import Any

from threedcal.errors import ConfigError
from threedcal.schema import fill_defaults, load_schema, load_yaml, schema_errors

KINDS = ("sensor", "printer")
PROFILE_DIR = Path(str(files("threedcal") / "profiles"))


class ProfileNotFound(ConfigError):
    pass


def builtin_dir(kind: str) -> Path:
    if kind not in KINDS:
        raise ValueError(f"unknown profile kind {kind!r} (kinds: {', '.join(KINDS)})")
    return PROFILE_DIR / f"{kind}s"


def builtin_names(kind: str) -> list[str]:
    return sorted(p.stem for p in builtin_dir(kind).glob("*.yaml"))


def resolve_profile(kind: str, ref: str | Path) -> Path:
    """A built-in name (`digit`) or a path to a YAML file → the file's path."""
    ref = str(ref)
    if ref.endswith((".yaml", ".yml")) or "/" in ref:
        path = Path(ref)
        if not path.is_file():
            raise ProfileNotFound(f"{kind} profile file {ref!r} does not exist")
        return path
    path = builtin_dir(kind) / f"{ref}.yaml"
    if not path.is_file():
        names = ", ".join(builtin_names(kind)) or "none"
        raise ProfileNotFound(
            f"no built-in {kind} profile {ref!r} (built-in: {names}; or give a path to a YAML file)"
        )
    return path


def load_profile(
    kind: str, ref: str | Path | Mapping[str, Any], *, defaults: bool = False
) -> dict[str, Any]:
    """Load and validate a profile (built-in name, path, or an already loaded mapping).

    The result carries its `name` and `source` file; `defaults=True` also fills the schema's
    defaults (what the hardware drivers read), otherwise only the keys the file gives are present.
    """
    schema = load_schema(kind)
    if isinstance(ref, Mapping):
        data = copy.deepcopy(dict(ref))
        path = data.get("source", f"{kind} profile")
    else:
        path = resolve_profile(kind, ref)
        data = load_yaml(path)
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: a {kind} profile must be a mapping of keys to values")
    problems = schema_errors(data, schema)
    if problems:
        raise ConfigError(f"{path}: invalid {kind} profile\n  " + "\n  ".join(problems))
    if not isinstance(ref, Mapping):
        data.setdefault("name", Path(path).stem)
        data["source"] = str(path)
    if defaults:
        fill_defaults(data, schema)
    return data


def with_gel_mechanics(sensor: Mapping, mechanics: str | None) -> Mapping:
    """The sensor profile whose gel a simulation renders: `mechanics` (a scene's
    `bench.gel_mechanics`, `realism.gel_mechanics`) in place of the profile's `gel.mechanics`
    (None: the profile's own). The sensor is the same physical one either way; only the simulation
    of its gel changes."""
    if mechanics is None or sensor["gel"].get("mechanics", "geometric") == mechanics:
        return sensor
    return {**sensor, "gel": {**sensor["gel"], "mechanics": mechanics}}
