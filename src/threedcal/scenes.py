"""What each scene asks of the workflow: its result files, derived from its config alone.

`rule all` requests exactly these, so a scene builds only what it needs (an imported scene has no
collection, a scene without an ablation trains one model, ...). Each stage adds its targets here.
"""

from __future__ import annotations

import json
import platform
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from threedcal.config import (
    FULL_TRAINING_P,
    convergence_fractions,
    is_imported,
    model_keys,
    realism_sets,
    training_fractions,
)
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile

RESULTS = "results"
# The study-wide integrator comparison (rules/integration_study.smk), built when the config enables it.
INTEGRATION_STUDY_TARGETS = [
    f"{RESULTS}/integration/error_vs_time.csv",
    f"{RESULTS}/integration/error_vs_time.png",
    f"{RESULTS}/integration/reading.md",
]
# Per-scene outputs of the stats stage (rules/stats.smk), for scenes with an ablation.
STATS_FILES = (
    "validation_mse.csv",
    "tests.csv",
    "tests.png",
    "recommendation.txt",
    "power.csv",
    "power.png",
    "error_vs_cost.csv",
    "loss_curves.png",
    "mse_map.png",
    "mse_kde.png",
    "error_vs_cost.png",
)
# Outputs of the convergence check (rules/stats.smk, ablation.convergence).
CONVERGENCE_FILES = ("convergence.csv", "error_vs_time.csv", "error_vs_time.png")
# Outputs of the objects stage (rules/objects.smk): the presses, then their scores.
OBJECT_FILES = (
    "pressing/frames.npz",
    "pressing/plan.csv",
    "pressing/truth.json",
    "pressing/summary.json",
    "errors.csv",
    "tuning.csv",
    "presses.csv",
    "integrators.csv",
    "violins.png",
    "figures",
)
# Versions recorded with every scene: the packages whose behaviour changes numbers.
RECORDED_PACKAGES = (
    "threedcal",
    "numpy",
    "scipy",
    "torch",
    "opencv-contrib-python-headless",
    "xarray",
    "zarr",
    "snakemake",
)


# The scene keys each stage reads: its `params` carry exactly these, so a change reruns only the
# stages that read the changed key (a new model preset never recollects).
STAGE_KEYS = {
    "collect": ("sensor", "printer", "port", "camera", "reader", "probe", "plan", "bench", "seed"),
    "dataset": ("sensor", "probe", "import", "dataset", "ablation", "seed"),
    "object_presses": (
        "sensor",
        "printer",
        "port",
        "camera",
        "probe",
        "bench",
        "objects",
        "pressing",
        "seed",
    ),
    "objects": ("sensor", "port", "objects", "pressing", "integrators", "seed", "torch_threads"),
}


def stage_config(scene: Mapping, stage: str) -> dict:
    """The part of a scene's config that `stage` reads."""
    return {key: scene[key] for key in STAGE_KEYS[stage] if key in scene}


# Per-scene outputs of the ReSkin stage (rules/reskin.smk), for magnetic-sensor scenes.
RESKIN_FILES = (
    "reskin/model.pt",
    "reskin/losses.csv",
    "reskin/splits.csv",
    "reskin_eval.json",
    "reskin_eval.png",
)
# The store (raw.zarr) is not among them: it is a source the collect stage keeps beside its outputs,
# never a product Snakemake may delete (rules/collect.smk).
COLLECT_FILES = ("collect/summary.json", "collect/coverage.png", "collect/frames.png")


# Per-scene outputs of the sim-to-real stage (rules/ball.smk, threedcal.model.sim2real).
SIM2REAL_FILES = ("sim2real/errors.csv", "sim2real/images.csv", "sim2real/error_vs_k.png")


def has_sim2real(scene: Mapping) -> bool:
    """Imported scenes with `sim_to_real.enabled`: pretrain on simulated presses, fine-tune on real."""
    return is_imported(scene) and bool((scene.get("sim_to_real") or {}).get("enabled"))


def is_magnetic_scene(scene: Mapping) -> bool:
    """A scene whose sensor profile is `type: magnetic` (ReSkin): readings, not images."""
    return load_profile("sensor", scene["sensor"]).get("type") == "magnetic"


def reskin_scenes(config: Mapping) -> list[str]:
    return [name for name, scene in config["scenes"].items() if is_magnetic_scene(scene)]


def scene_targets(name: str, scene: Mapping) -> list[str]:
    root = f"{RESULTS}/{name}"
    targets = [f"{root}/scene.json"]
    if is_magnetic_scene(scene):  # collection, then the MLP; no images, so no registration or depth
        return targets + [f"{root}/{leaf}" for leaf in COLLECT_FILES + RESKIN_FILES]
    if is_imported(scene):
        targets += [f"{root}/dataset/splits.csv"]
    else:
        targets += [f"{root}/{leaf}" for leaf in COLLECT_FILES]
        targets += [f"{root}/dataset/registration.json", f"{root}/dataset/splits.csv"]
    targets += model_targets(name, scene)
    if is_vision(scene):
        targets += [f"{root}/models/inference.json"]
    if is_imported(scene):
        targets += [f"{root}/ball_eval.json", f"{root}/presets.csv", f"{root}/presets.png"]
        targets += [f"{root}/cv/images.csv", f"{root}/cv/errors.png"]
    if has_sim2real(scene):
        targets += [f"{root}/{leaf}" for leaf in SIM2REAL_FILES]
    if has_objects(scene):
        targets += [f"{root}/objects/{leaf}" for leaf in OBJECT_FILES]
    if has_ablation(scene):
        targets += [f"{root}/stats/{name}" for name in STATS_FILES]
    if convergence_fractions(scene):
        targets += [f"{root}/stats/{name}" for name in CONVERGENCE_FILES]
    return targets


def is_vision(scene: Mapping) -> bool:
    return load_profile("sensor", scene["sensor"]).get("type") == "vision"


def has_objects(scene: Mapping) -> bool:
    """Scenes whose test objects the printer presses: on the simulated bench, or on a real rig
    (the user mounts each object when asked)."""
    return bool(scene.get("objects")) and not is_imported(scene)


def has_ablation(scene: Mapping) -> bool:
    """Scenes whose statistics compare several training fractions against P = 80."""
    fractions = training_fractions(scene)
    return len(fractions) > 1 and FULL_TRAINING_P in fractions


def ablation_scenes(config: Mapping) -> list[str]:
    return [name for name, scene in config["scenes"].items() if has_ablation(scene)]


def model_file(name: str, percent: int, replicate: int = 0, leaf: str = "model.pt") -> str:
    """results/{scene}/models/P{p}/r{r}/{leaf}: where replicate r of fraction P is trained."""
    return f"{RESULTS}/{name}/models/P{percent}/r{replicate}/{leaf}"


def full_model_file(name: str, scene: Mapping) -> str:
    """Replicate 0 of the largest fraction: the model inference_speed reads."""
    return model_file(name, max(training_fractions(scene)), 0)


def model_targets(name: str, scene: Mapping) -> list[str]:
    """One training job per (P, replicate): model.pt and losses.csv (+ losses.png) under models/P{p}/r{r}/."""
    return [
        model_file(name, p, r, leaf)
        for p, r in model_keys(scene)
        for leaf in ("model.pt", "losses.csv")
    ]


def study_targets(config: Mapping) -> list[str]:
    """Every file `rule all` asks for: each scene's targets, then the study-wide ones."""
    targets: list[str] = []
    for name, scene in config["scenes"].items():
        targets += scene_targets(name, scene)
    if config.get("integration_study", {}).get("enabled"):
        targets += INTEGRATION_STUDY_TARGETS
    if ablation_scenes(config):
        targets += [f"{RESULTS}/stats/mse_std_vs_p.png"]
    if config.get("realism"):
        targets += [f"{RESULTS}/realism/table.txt"]
    targets += [f"{RESULTS}/environment.json", f"{RESULTS}/summary.md"]
    return targets


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in RECORDED_PACKAGES:
        try:
            versions[package] = version(package)
        except PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def scene_record(name: str, scene: Mapping) -> dict[str, Any]:
    """The resolved scene: its config, the full profiles it names, and the software it ran with."""
    profiles = {
        kind: load_profile(kind, scene[kind])
        for kind in ("sensor", "printer")
        if scene.get(kind) is not None
    }
    for profile in profiles.values():
        profile.pop("source", None)  # a machine-specific path; the content is what matters
    return {
        "scene": name,
        "config": dict(scene),
        "profiles": profiles,
        "software": package_versions(),
    }


def write_scene_record(name: str, scene: Mapping, path: str | Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(scene_record(name, scene), indent=2, sort_keys=True) + "\n")


def realism_files(config: Mapping[str, Any]) -> list[str]:
    """Every file of the realism stage's real folders (its inputs)."""
    sets = realism_sets(config)
    for real, *_ in sets:
        if not Path(real).is_dir():
            raise ConfigError(f"realism: real folder {real} is not a folder (realism.real / also)")
    return [str(p) for real, *_ in sets for p in sorted(Path(real).iterdir()) if p.is_file()]
