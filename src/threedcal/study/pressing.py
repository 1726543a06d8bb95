"""A scene's test objects parsed into what pressing and scoring them take (ObjectsSetup). Apart
from threedcal.study.scene so that the collection's code never imports the evaluation's."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict

from threedcal.errors import ConfigError
from threedcal.evaluate.press_plan import SIM_MOUNT, Mount, ObjectsSetup
from threedcal.profiles import load_profile
from threedcal.study.config import mount_problem
from threedcal.study.scene import rig_settings, scene_sensor


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
        printer=load_profile("printer", scene["printer"]) if scene.get("printer") else None,
        mount=pressing_mount(scene, source),
        seed=pressing_seed(scene),
        objects=tuple(scene.get("objects") or ()),
        pressing=scene.get("pressing") or {},
        integrators=tuple(scene.get("integrators") or ()),
        rig=rig_settings(scene),
    )
