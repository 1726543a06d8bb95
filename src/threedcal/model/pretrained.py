"""How the shipped pretrained weights are made: simulated presses of many units, trained long.

The files, and how a training finds them, are threedcal.pretrained's.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from threedcal.dataset.unit_presses import simulate_units
from threedcal.errors import ConfigError
from threedcal.model.checkpoint import save_checkpoint
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings
from threedcal.pretrained import pretraining_digest
from threedcal.profiles import load_profile


def pretrain_shipped_weights(
    sensor: str,
    pretraining: Mapping,
    out_dir: str | Path,
    code_digest: str,
    progress: bool = True,
) -> dict:
    """Simulate the units' presses, train the network on them, write model.pt and provenance.json
    into out_dir. `pretraining` is the config's validated `pretraining` section."""
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
    settings = TrainSettings.of(
        seed=pretraining["seed"], torch_threads=pretraining["torch_threads"], **model
    )
    out_dir = Path(out_dir)
    checkpoint = train(trainset, out_dir, 80, settings, progress)
    # A unit's blank means nothing to another unit: a calibration brings its own. Without it
    # the shipped file is the weights and their record, a few tens of KB.

    checkpoint["blank"] = None
    save_checkpoint(out_dir / "model.pt", checkpoint)
    record = {
        "sensor": sensor,
        "image_shape": list(trainset.image_shape),
        "downscale": int(pretraining["downscale"]),
        "preset": checkpoint["preset"],
        "units": [units[0], units[-1]],
        "frames": int(len(trainset.frames)),
        "settings_digest": pretraining_digest(pretraining, profile),
        "code_digest": code_digest,
        "pretraining": dict(pretraining),
        "training": {
            k: checkpoint["training"][k]
            for k in ("epochs", "steps", "precision", "machine", "stopped")
        },
    }
    (out_dir / "provenance.json").write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record
