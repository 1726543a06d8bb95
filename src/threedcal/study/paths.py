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

from threedcal.errors import ConfigError
from threedcal.pretrained import SHIPPED_DIR
from threedcal.profiles import load_profile
from threedcal.study.config import has_arms, is_imported, is_quick, real_check_sets, realism_sets
from threedcal.study.fractions import (
    FULL_TRAINING_P,
    convergence_fractions,
    model_keys,
    normalise_ablation,
    training_fractions,
)
from threedcal.study.scene import scene_mount_values

RESULTS = "results"
# Every file the workflow writes that something else names (a rule's input, a scene's targets), as
# the rules' pattern: `{scene}` is their wildcard, and `target` fills in a scene's name. The rules
# name their outputs and inputs from here; logs and benchmarks, which nothing reads, stay in them.
SCENE = f"{RESULTS}/{{scene}}"


def _files(folder: str, **leaves: str) -> dict[str, str]:
    """{name: folder/leaf}: a stage's files by the names its rule gives them."""
    return {name: f"{folder}/{leaf}" for name, leaf in leaves.items()}


SCENE_JSON = f"{SCENE}/scene.json"
# The collect stage (rules/collect.smk). The store (raw.zarr) is not among its outputs: it is a
# source the stage keeps beside them, never a product Snakemake may delete.
COLLECT = _files(
    f"{SCENE}/collect",
    summary="summary.json",
    coverage="coverage.png",
    mosaic="frames.png",
)
BENCH_TRUTH = f"{SCENE}/collect/bench_truth.json"
STORE = f"{SCENE}/raw.zarr"
STAGING_STORE = f"{SCENE}/.partial/raw.zarr"
# The dataset stage (rules/dataset.smk).
TRAINSET = f"{SCENE}/dataset/trainset"
SPLITS = f"{SCENE}/dataset/splits.csv"
REGISTRATION = f"{SCENE}/dataset/registration.json"
REGISTRATION_FIGURE = f"{SCENE}/dataset/registration.png"
# One model per (P, replicate) (rules/train.smk), and the speed of the largest P's model. An
# ablation trains a fraction's replicates in one job (threedcal.model.lockstep), which keeps its
# state in LOCKSTEP_RESUME until it ends.
MODEL_DIR = f"{SCENE}/models/P{{p}}/r{{r}}"
LOCKSTEP_RESUME = f"{SCENE}/models/P{{p}}/resume.pt"
INFERENCE_SPEED = f"{SCENE}/models/inference.json"
# The weights shipped for `model.init: pretrained`, one network per sensor (rules/pretrained.smk).
PRETRAINED_DIR = f"{RESULTS}/pretrained/{{sensor}}"
# The quick calibration (rules/quick.smk), for scenes whose plan is `pattern: quick`: rounds of
# presses until the stop rule; its store is STORE, a source like the collect stage's.
QUICK = _files(f"{SCENE}/quick", model="model.pt", rounds="rounds.csv", stop="stop.json")
QUICK_ROUNDS = f"{SCENE}/quick/rounds"
# The three arms of a quick scene with `quick.compare_with` (rules/quick.smk, quick_arms): its rounds,
# the same presses trained from scratch (one model a round under scratch/), its full calibration.
QUICK_ARMS = _files(f"{SCENE}/quick", table="arms.csv", figure="arms.png", verdicts="arms.json")
QUICK_SCRATCH = f"{SCENE}/quick/scratch"
# The quick calibration over units (rules/quick.smk, quick_study; `make quick-study`): every compared
# quick scene's stopped model against its full calibration, and the claim over units.
QUICK_STUDY = _files(
    f"{RESULTS}/quick_study", table="units.csv", summary="summary.json", figure="units.png"
)
# The stats stage (rules/stats.smk), for scenes with an ablation.
STATS = _files(
    f"{SCENE}/stats",
    validation_mse="validation_mse.csv",
    tests="tests.csv",
    tests_figure="tests.png",
    recommendation="recommendation.txt",
    learning_curve="learning_curve.csv",
    learning_curve_figure="learning_curve.png",
    power="power.csv",
    power_figure="power.png",
    costs="error_vs_cost.csv",
    loss_figure="loss_curves.png",
    map_figure="mse_map.png",
    kde_figure="mse_kde.png",
    cost_figure="error_vs_cost.png",
)
# The ablation read again on the models trained on to twice the budget (ablation.convergence), and
# every fraction's error against training time (rules/stats.smk).
TWICE_STATS = _files(
    f"{SCENE}/stats/twice",
    validation_mse="validation_mse.csv",
    tests="tests.csv",
    recommendation="recommendation.txt",
    learning_curve="learning_curve.csv",
    learning_curve_figure="learning_curve.png",
)
CONVERGENCE = _files(
    f"{SCENE}/stats",
    convergence="convergence.csv",
    curve="error_vs_time.csv",
    figure="error_vs_time.png",
)
# The objects stage (rules/objects.smk): the presses, then their scores.
PRESSING = _files(
    f"{SCENE}/objects/pressing",
    frames="frames.npz",
    plan="plan.csv",
    truth="truth.json",
    summary="summary.json",
)
OBJECTS = _files(
    f"{SCENE}/objects",
    errors="errors.csv",
    tuning="tuning.csv",
    presses="presses.csv",
    integrators="integrators.csv",
    violins="violins.png",
    figures="figures",
)
# The ReSkin stage (rules/reskin.smk), for magnetic-sensor scenes.
RESKIN_MODEL = _files(
    f"{SCENE}/reskin",
    model="model.pt",
    losses="losses.csv",
    splits="splits.csv",
)
RESKIN_EVAL = {"metrics": f"{SCENE}/reskin_eval.json", "figure": f"{SCENE}/reskin_eval.png"}
# Imported scenes (rules/ball.smk, rules/presets.smk): the cross-validated evaluation, the presets
# and the sim-to-real stage (threedcal.evaluate.sim2real).
CV_FOLDS = f"{SCENE}/cv/folds.csv"
CV_MODEL_DIR = f"{SCENE}/cv/{{method}}/fold{{fold}}"
# One simulated set and pretraining per group of test folds (`{folds}`: 0-1-2), one folder of
# models (k{k}/model.pt) per condition and fold.
SIM2REAL_PRETRAINING = f"{SCENE}/sim2real/pretraining/folds{{folds}}"
SIM2REAL_SIMSET = f"{SIM2REAL_PRETRAINING}/simset"
SIM2REAL_PRETRAINED_DIR = f"{SIM2REAL_PRETRAINING}/pretrained"
SIM2REAL_FOLD_DIR = f"{SCENE}/sim2real/{{condition}}/fold{{fold}}"
BALL_EVAL = {
    "json": f"{SCENE}/ball_eval.json",
    "images": f"{SCENE}/cv/images.csv",
    "figure": f"{SCENE}/cv/errors.png",
}
PRESETS = {"csv": f"{SCENE}/presets.csv", "png": f"{SCENE}/presets.png"}
SIM2REAL = _files(
    f"{SCENE}/sim2real",
    errors="errors.csv",
    images="images.csv",
    figure="error_vs_k.png",
)
# Study-wide: the integrator comparison (rules/integration_study.smk, when the config enables it),
# the cross-scene spread, the realism table, the run environment and the summary page.
INTEGRATION_STUDY = _files(
    f"{RESULTS}/integration",
    csv="error_vs_time.csv",
    png="error_vs_time.png",
    reading="reading.md",
)
INTEGRATION_STUDY_TARGETS = list(INTEGRATION_STUDY.values())
STATS_OVERVIEW = f"{RESULTS}/stats/mse_std_vs_p.png"
REALISM_TABLE = f"{RESULTS}/realism/table.txt"
REAL_CHECK = _files(f"{RESULTS}/real_check", table="table.csv", frames="frames.csv")
REALISM_HALO = _files(f"{RESULTS}/realism", csv="halo_2d.csv", png="halo_2d.png")
ENVIRONMENT = f"{RESULTS}/environment.json"
SUMMARY = f"{RESULTS}/summary.md"


def target(pattern: str, name: str) -> str:
    """A pattern of the list above with the scene's name filled in (other wildcards kept)."""
    return pattern.replace("{scene}", name)


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
    "collect": (
        "sensor",
        "printer",
        "port",
        "camera",
        "reader",
        "mount",
        "probe",
        "plan",
        "bench",
        "seed",
    ),
    "dataset": ("sensor", "mount", "probe", "import", "dataset", "ablation", "seed"),
    "object_presses": (
        "sensor",
        "printer",
        "port",
        "camera",
        "mount",
        "probe",
        "bench",
        "objects",
        "pressing",
        "seed",
    ),
    "objects": (
        "sensor",
        "mount",
        "port",
        "objects",
        "pressing",
        "integrators",
        "seed",
        "torch_threads",
    ),
    "quick": (
        "sensor",
        "printer",
        "port",
        "camera",
        "mount",
        "probe",
        "plan",
        "bench",
        "seed",
        "dataset",
        "model",
        "quick",
        "torch_threads",
    ),
}


def stage_config(scene: Mapping, stage: str) -> dict:
    """The part of a scene's config that `stage` reads. Of `ablation`, the subsets' fractions and
    replicates alone: the training budget is not the dataset's. A `mount` file is read into its
    values: a changed file is a changed config (the stage reruns, and reads what its params say)."""
    part = {key: scene[key] for key in STAGE_KEYS[stage] if key in scene}
    if "ablation" in part:
        ablation = normalise_ablation(part["ablation"])
        part["ablation"] = {key: ablation[key] for key in ("fractions", "replicates")}
    if isinstance(part.get("mount"), str):
        part["mount"] = scene_mount_values(scene)
    return part


def has_sim2real(scene: Mapping) -> bool:
    """Imported scenes with `sim_to_real.enabled`: pretrain on simulated presses, fine-tune on real."""
    return is_imported(scene) and bool((scene.get("sim_to_real") or {}).get("enabled"))


def is_magnetic_scene(scene: Mapping) -> bool:
    """A scene whose sensor profile is `type: magnetic` (ReSkin): readings, not images."""
    return load_profile("sensor", scene["sensor"]).get("type") == "magnetic"


def reskin_scenes(config: Mapping) -> list[str]:
    return [name for name, scene in config["scenes"].items() if is_magnetic_scene(scene)]


def scene_targets(name: str, scene: Mapping) -> list[str]:
    def of(*patterns) -> list[str]:
        return [target(pattern, name) for pattern in patterns]

    targets = of(SCENE_JSON)
    if is_quick(scene):  # one model, round by round; no dataset, ablation or objects stage
        targets += of(*QUICK.values())
        if has_arms(scene):
            targets += of(*QUICK_ARMS.values(), QUICK_SCRATCH)
        return targets
    if is_magnetic_scene(scene):  # collection, then the MLP; no images, so no registration or depth
        return targets + of(*COLLECT.values(), *RESKIN_MODEL.values(), *RESKIN_EVAL.values())
    if is_imported(scene):
        targets += of(SPLITS)
    else:
        targets += of(*COLLECT.values(), REGISTRATION, SPLITS)
    targets += model_targets(name, scene)
    if is_vision(scene):
        targets += of(INFERENCE_SPEED)
    if is_imported(scene):
        targets += of(
            BALL_EVAL["json"], *PRESETS.values(), BALL_EVAL["images"], BALL_EVAL["figure"]
        )
    if has_sim2real(scene):
        targets += of(*SIM2REAL.values())
    if has_objects(scene):
        targets += of(*PRESSING.values(), *OBJECTS.values())
    if has_ablation(scene):
        targets += of(*STATS.values())
    if convergence_fractions(scene):
        targets += of(*TWICE_STATS.values(), *CONVERGENCE.values())
    return targets


def quick_scenes(config: Mapping) -> list[str]:
    return [name for name, scene in config["scenes"].items() if is_quick(scene)]


def arms_scenes(config: Mapping) -> list[str]:
    """The compared quick scenes scored arm by arm (quick_arms)."""
    return [name for name in quick_scenes(config) if has_arms(config["scenes"][name])]


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


def lockstep_groups(config: Mapping) -> dict[tuple[int, int, bool], list[str]]:
    """Ablation scenes by (replicates, steps, convergence): one lockstep training rule each, whose
    outputs (every replicate's model, snapshots and twice-the-budget model) these fix."""
    groups: dict[tuple[int, int, bool], list[str]] = {}
    for name in ablation_scenes(config):
        ablation = normalise_ablation(config["scenes"][name].get("ablation"))
        key = (
            ablation["replicates"],
            ablation["steps"],
            bool(convergence_fractions(config["scenes"][name])),
        )
        groups.setdefault(key, []).append(name)
    return groups


def model_file(name: str, percent, replicate=0, leaf: str = "model.pt") -> str:
    """results/{scene}/models/P{p}/r{r}/{leaf}: where replicate r of fraction P is trained (the
    rule's own pattern with the wildcards for arguments)."""
    return f"{target(MODEL_DIR, name)}/{leaf}".replace("{p}", str(percent)).replace(
        "{r}", str(replicate)
    )


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
        targets += [STATS_OVERVIEW]
    if config.get("realism"):
        targets += [REALISM_TABLE, *REALISM_HALO.values()]
    if config.get("real_check"):
        targets += list(REAL_CHECK.values())
    targets += [ENVIRONMENT, SUMMARY]
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


def real_check_files(config: Mapping[str, Any]) -> list[str]:
    """The real_check stage's inputs: every file of its folders and the shipped weights it reads."""
    sets = real_check_sets(config)
    files = [str(p) for s in sets for p in sorted(Path(s["real"]).iterdir()) if p.is_file()]
    sensors = sorted({s["sensor"] for s in sets})
    return files + [str(SHIPPED_DIR / f"{s}.{ext}") for s in sensors for ext in ("pt", "json")]


def realism_files(config: Mapping[str, Any]) -> list[str]:
    """Every file of the realism stage's real folders (its inputs)."""
    sets = realism_sets(config)
    for real, *_ in sets:
        if not Path(real).is_dir():
            raise ConfigError(f"realism: real folder {real} is not a folder (realism.real / also)")
    return [str(p) for real, *_ in sets for p in sorted(Path(real).iterdir()) if p.is_file()]
