"""A scene's training settings: its `model:` section with its seed and threads, typed. Apart from
threedcal.study.scene so that the collection's code never imports the model's."""

from __future__ import annotations

from collections.abc import Mapping

from threedcal.model.train_settings import TrainSettings


def train_settings(scene: Mapping) -> TrainSettings:
    """The scene's `model:` section with its seed and threads (the ablation's, the quick loop's)."""
    return TrainSettings.of(
        seed=scene.get("seed"), torch_threads=scene.get("torch_threads"), **scene.get("model", {})
    )
