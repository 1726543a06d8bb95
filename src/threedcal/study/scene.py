"""A scene's settings parsed into the typed values the domain packages take: the one place that
reads a scene's sections for them, so no domain function reads a config mapping by key."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict

from threedcal.dataset.settings import DatasetSettings
from threedcal.errors import ConfigError
from threedcal.evaluate.press_plan import SIM_MOUNT, Mount, ObjectsSetup
from threedcal.mount import scene_sensor
from threedcal.object_refs import mount_problem
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


def pressing_mount(scene: Mapping, source: str = "scene") -> Mount:
    """`pressing.mount`; on the simulated bench it defaults to `SIM_MOUNT`, a real rig must say."""
    problem = mount_problem(scene)
    if problem:
        raise ConfigError(f"{source}.{problem}")
    mount = scene.get("pressing", {}).get("mount") or SIM_MOUNT
    return Mount(**{k: float(mount.get(k, 0.0)) for k in asdict(Mount())})


def pressing_seed(scene: Mapping) -> int:
    """`pressing.seed`, else the scene's: either way drawn through the pressing streams only."""
    return int(scene.get("pressing", {}).get("seed", scene["seed"]))


def objects_setup(scene: Mapping, source: str = "scene") -> ObjectsSetup:
    """The test objects' settings: what is pressed, by which rig, scored with which integrators
    (`source`: the scene's key in error messages)."""
    return ObjectsSetup(
        sensor=scene_sensor(scene, source),
        printer=load_profile("printer", scene["printer"]),
        mount=pressing_mount(scene, source),
        seed=pressing_seed(scene),
        objects=tuple(scene.get("objects") or ()),
        pressing=scene.get("pressing") or {},
        integrators=tuple(scene.get("integrators") or ()),
        rig=rig_settings(scene),
    )
