"""The weights this package ships for `model.init: pretrained`: how they are made, found and checked.

A calibration that starts from a network already fluent in how a sensor model's images answer a
press needs far fewer presses and steps than one from random weights. The project makes such a
network itself, per built-in vision sensor: simulated presses of many units drawn from the
profile's unit-to-unit variation (threedcal.dataset.unit_presses), trained long. The weights and
their provenance — the pretraining settings, the digest of the code that made them, the units
drawn — ship inside the package (`threedcal/pretrained/{sensor}.pt` and `.json`), so nothing is
downloaded; `make pretrained` rebuilds them (the same bytes on the same host).
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


def settings_digest(pretraining: Mapping, profile: Mapping) -> str:
    """What the weights were made from: the pretraining section and the sensor profile."""
    text = canonical_json({"pretraining": dict(pretraining), "profile": dict(profile)})
    return hashlib.sha256(text.encode()).hexdigest()


def pretrain(
    sensor: str,
    pretraining: Mapping,
    out_dir: str | Path,
    code_digest: str,
    progress: bool = True,
) -> dict:
    """Simulate the units' presses, train the network on them, write model.pt and provenance.json
    into out_dir. `pretraining` is the config's validated `pretraining` section."""
    from threedcal.dataset.unit_presses import simulate_units
    from threedcal.model.train import TrainSettings, train
    from threedcal.profiles import load_profile

    profile = load_profile("sensor", sensor)
    first, count = int(pretraining["first_unit"]), int(pretraining["units"])
    units = list(range(first, first + count))
    trainset = simulate_units(
        profile,
        units,
        int(pretraining["presses_per_unit"]),
        tuple(pretraining["depth_mm"]),
        float(pretraining["probe_radius_mm"]),
        factor=int(pretraining["downscale"]),
        gel_mechanics=pretraining["gel_mechanics"],
        val_units=int(pretraining["val_units"]),
        progress=progress,
    )
    model = dict(pretraining["model"])
    if model.get("init"):
        raise ConfigError("pretraining.model.init: pretraining starts from random weights")
    settings = TrainSettings.from_scene(
        {"model": model, "seed": pretraining["seed"], "torch_threads": pretraining["torch_threads"]}
    )
    out_dir = Path(out_dir)
    checkpoint = train(trainset, out_dir, 80, settings, progress)
    # A unit's blank means nothing to another unit: a calibration brings its own. Without it
    # the shipped file is the weights and their record, a few tens of KB.
    from threedcal.model.checkpoint import save_checkpoint

    checkpoint["blank"] = None
    save_checkpoint(out_dir / "model.pt", checkpoint)
    record = {
        "sensor": sensor,
        "image_shape": list(trainset.image_shape),
        "downscale": int(pretraining["downscale"]),
        "preset": checkpoint["preset"],
        "units": [units[0], units[-1]],
        "frames": int(len(trainset.frames)),
        "settings_digest": settings_digest(pretraining, profile),
        "code_digest": code_digest,
        "pretraining": dict(pretraining),
        "training": {
            k: checkpoint["training"][k]
            for k in ("epochs", "steps", "precision", "machine", "stopped")
        },
    }
    (out_dir / "provenance.json").write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record
