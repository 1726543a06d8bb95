"""The `dataset_import` rule as a function: an imported scene's settings parsed, its folder read
into the model-ready set. Apart from the other stages so that its code digest covers the dataset
code alone."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.dataset.build import build_imported
from threedcal.dataset.trainset import TrainingSet
from threedcal.study.scene import dataset_settings


def import_stage(scene: Mapping, trainset_dir: str | Path, splits_path: str | Path) -> TrainingSet:
    """The `dataset_import` rule: an imported scene's folder → its model-ready set and splits."""
    source = scene["import"]
    return build_imported(
        source["format"], source["path"], dataset_settings(scene), trainset_dir, splits_path
    )
