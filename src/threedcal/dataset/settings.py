"""The dataset stage's settings, typed: what it reads of a scene once the study layer has parsed
it (threedcal.study.scene.dataset_settings). Kept light, for the config check imports it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class DatasetSettings:
    """What the dataset stage reads of a scene, as the study layer parsed it
    (threedcal.study.scene.dataset_settings)."""

    seed: int
    fractions: tuple[int, ...]  # the data fractions P trained, ascending
    replicates: int  # nested subset draws per fraction
    downscale: int
    max_slope_deg: float | None  # as configured: check_max_slope reads it
    max_depth_over_radius: float | None = None
    refine_labels: bool = False
    sensor: Mapping | None = None  # the sensor profile, seated as the scene's mount says
    probe_radius_mm: float | None = None  # a collected scene's ball
    bench_gel_mechanics: str | None = None  # a simulated bench's gel (None on a real rig)
    simulated: bool = False  # collected on the simulated bench
