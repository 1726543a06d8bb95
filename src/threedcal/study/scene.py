"""A scene's settings parsed into the typed values the domain packages take: the one place that
reads a scene's sections for them (its test objects: study.pressing), so no domain function reads
a config mapping by key."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.dataset.settings import DatasetSettings
from threedcal.mount import read_mount_file, with_mount
from threedcal.profiles import load_profile
from threedcal.rig import RigSettings
from threedcal.study.fractions import ablation_replicates, training_fractions


def dataset_settings(scene: Mapping) -> DatasetSettings:
    """The dataset stage's settings: an imported scene's (its sensor profile when it names one) or
    a collected scene's (its sensor seated by its mount, its ball, and the bench it ran on)."""
    dataset = scene["dataset"]
    imported = "import" in scene
    if imported:
        sensor = load_profile("sensor", scene["sensor"]) if scene.get("sensor") else None
    else:
        sensor = scene_sensor(scene)
    return DatasetSettings(
        seed=scene["seed"],
        fractions=tuple(training_fractions(scene)),
        replicates=ablation_replicates(scene),
        downscale=int(dataset["downscale"]),
        max_slope_deg=dataset["max_slope_deg"],
        max_depth_over_radius=dataset.get("max_depth_over_radius"),
        refine_labels=bool(dataset.get("refine_labels")),
        sensor=sensor,
        probe_radius_mm=None if imported else float(scene["probe"]["radius_mm"]),
        bench_gel_mechanics=(scene.get("bench") or {}).get("gel_mechanics"),
        simulated=scene.get("port") == "sim",
    )


def rig_settings(scene: Mapping) -> RigSettings:
    """The rig a collected scene runs on: the simulated bench (`port: sim`) or its printer, camera
    and ReSkin board."""
    return RigSettings(
        sensor_ref=scene["sensor"],
        probe_radius_mm=(scene.get("probe") or {}).get("radius_mm"),
        seed=scene.get("seed"),
        bench=scene.get("bench") or {},
        port=scene.get("port", "sim"),
        camera=scene.get("camera", "sim"),
        reader=scene.get("reader", "sim"),
    )


def scene_mount_values(
    scene: Mapping, source: str | None = "scene", missing_ok: bool = False
) -> dict[str, float]:
    """The keys the scene's `mount` gives (its file's, where it names one); {} without one, or
    with `missing_ok` when its file is not there yet (the set-up page writes it).
    `source`: how errors name the scene (None: the key alone)."""
    given = scene.get("mount")
    if given is None:
        return {}
    if isinstance(given, str):
        if missing_ok and not Path(given).exists():
            return {}
        return read_mount_file(given, f"{source}.mount" if source else "mount")
    return {k: float(v) for k, v in given.items()}


def scene_sensor(scene: Mapping, source: str | None = "scene", missing_ok: bool = False) -> dict:
    """The scene's sensor profile, seated as the scene's `mount` says (see scene_mount_values)."""
    sensor = load_profile("sensor", scene["sensor"])
    return with_mount(sensor, scene_mount_values(scene, source, missing_ok))
