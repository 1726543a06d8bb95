"""The workflow's jobs of an imported scene: the models its cross-validation trains per fold, and
for the sim-to-real study (threedcal.evaluate.sim2real) which `sim_to_real` keys rerun which job,
which pretraining group a fold belongs to and which folders the scoring reads."""

from __future__ import annotations

from collections.abc import Mapping

from threedcal.errors import ConfigError
from threedcal.evaluate.sim2real_settings import (
    CONDITIONS,
    SimToRealSettings,
    chosen_folds,
    group_name,
    pretraining_groups,
)
from threedcal.profiles import load_profile
from threedcal.study.paths import CV_MODEL_DIR, SIM2REAL_FOLD_DIR, target

SIM2REAL_CONDITIONS = tuple(CONDITIONS)


# The sim_to_real keys each stage reads: a change reruns only the stages that read it.
STAGE_KEYS = {
    "simulate": ("frames", "depth_mm", "profile"),
    "pretrain": ("pretrain_epochs",),
    "train": ("finetune_epochs", "k"),
    "shipped": ("shipped_lr", "k"),
}


def train_keys(scene: Mapping, condition: str) -> dict:
    """The sim_to_real keys a `condition`'s training reads."""
    return sim2real_keys(scene, "shipped" if condition == "shipped_real" else "train")


def sim2real_keys(scene: Mapping, stage: str) -> dict:
    values = scene.get("sim_to_real") or {}
    return {key: values[key] for key in STAGE_KEYS[stage] if key in values}


def sensor_profile(scene: Mapping) -> dict:
    """The scene's sensor profile as the simulator reads it (without its machine-specific path)."""
    profile = dict(load_profile("sensor", scene["sensor"]))
    profile.pop("source", None)
    return profile


def group_of(scene: Mapping, fold: int) -> str:
    """The name of the pretraining group that holds `fold`."""
    settings = SimToRealSettings.of(**(scene.get("sim_to_real") or {}))
    for group in pretraining_groups(settings, int(scene["cv"]["folds"])):
        if fold in group:
            return group_name(group)
    raise ConfigError(f"sim_to_real.folds: fold {fold} is not evaluated")


def sim2real_inputs(name: str, scene: Mapping) -> dict[str, list[str]]:
    """The folders sim2real_eval scores: "{condition}" -> the condition's fold folders (each with
    k{k}/model.pt), "scene" -> the scene's cross-validated models (ball_eval's) of the same folds."""
    settings = SimToRealSettings.of(**(scene.get("sim_to_real") or {}))
    folds = chosen_folds(settings, int(scene["cv"]["folds"]))

    def path(pattern: str, **wildcards) -> str:
        path = target(pattern, name)
        for key, value in wildcards.items():
            path = path.replace(f"{{{key}}}", str(value))
        return path

    out = {
        condition: [path(SIM2REAL_FOLD_DIR, condition=condition, fold=f) for f in folds]
        for condition in settings.conditions
    }
    out["scene"] = [path(f"{CV_MODEL_DIR}/model.pt", method="model", fold=f) for f in folds]
    return out


def method_settings(scene: Mapping, method: str) -> dict:
    """The `model:` settings a CV method trains with: `model` = the scene's own, `lookup` = the
    baseline (the same settings, preset lookup). Item 3's variants add entries here."""
    model = dict(scene.get("model") or {})
    if method == "model":
        return model
    if method == "lookup":
        return {**model, "preset": "lookup"}
    raise ConfigError(
        f"unknown cross-validation method {method!r} (allowed: {', '.join(CV_METHODS)})"
    )


CV_METHODS = ("model", "lookup")
