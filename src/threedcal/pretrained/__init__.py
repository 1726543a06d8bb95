"""The weights this package ships for `model.init: pretrained`: where they are and what made them.

A calibration that starts from a network already fluent in how a sensor model's images answer a
press needs far fewer presses and steps than one from random weights. The project makes such a
network itself, per built-in vision sensor: simulated presses of many units drawn from the
profile's unit-to-unit variation (threedcal.dataset.unit_presses), trained long. The weights and
their provenance — the pretraining settings, the digest of the code that made them, the units
drawn — ship inside the package (`threedcal/pretrained/{sensor}.pt` and `.json`), so nothing is
downloaded; `make pretrained` rebuilds them (threedcal.model.pretrained: the same bytes on the
same host). This module only finds and checks them, so the config check needs no torch.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from importlib.resources import files
from pathlib import Path

from threedcal.errors import ConfigError
from threedcal.schema import canonical_json

SHIPPED_DIR = Path(str(files("threedcal") / "pretrained"))


def shipped_sensors(directory: Path | None = None) -> list[str]:
    return sorted(p.stem for p in (directory or SHIPPED_DIR).glob("*.pt"))


def shipped_weights(
    sensor: str | None, image_shape: tuple[int, int] | None = None, directory: Path | None = None
) -> Path:
    """The shipped weights for profile `sensor`, checked against the frames they will see."""
    directory = directory or SHIPPED_DIR
    available = shipped_sensors(directory)
    path = directory / f"{sensor}.pt"
    if not sensor or not path.is_file():
        raise ConfigError(
            f"model.init: pretrained: no pretrained weights for sensor {sensor!r} (shipped: "
            f"{', '.join(available) or 'none'}); train from scratch (init: null) or give a "
            "checkpoint's path"
        )
    record = provenance(sensor, directory)
    shape = tuple(record["image_shape"])
    if image_shape is not None and shape != tuple(image_shape):
        raise ConfigError(
            f"model.init: pretrained: the {sensor} weights were made for {shape[0]} x {shape[1]} "
            f"px frames (dataset.downscale: {record['downscale']}), this dataset's are "
            f"{image_shape[0]} x {image_shape[1]}: set the scene's dataset.downscale to "
            f"{record['downscale']}, or train from scratch (init: null)"
        )
    return path


def provenance(sensor: str, directory: Path | None = None) -> dict:
    path = (directory or SHIPPED_DIR) / f"{sensor}.json"
    if not path.is_file():
        raise ConfigError(f"{path}: the provenance of the shipped {sensor} weights is missing")
    return json.loads(path.read_text())


def pretraining_digest(pretraining: Mapping, profile: Mapping) -> str:
    """What the weights were made from: the pretraining section and the sensor profile's content.
    Not its `source` keys: where its file lies, and the citations of its constants (the same recipe
    in any clone, and after a docs page moves, has one digest)."""
    text = canonical_json({"pretraining": dict(pretraining), "profile": _without_sources(profile)})
    return hashlib.sha256(text.encode()).hexdigest()


def _without_sources(node):
    if isinstance(node, Mapping):
        return {k: _without_sources(v) for k, v in node.items() if k != "source"}
    if isinstance(node, list):
        return [_without_sources(v) for v in node]
    return node
