# threedcal study workflow: `snakemake --cores 2 all` builds every scene's results (see README.md).
import re
from pathlib import Path

from snakemake.utils import min_version, validate

from threedcal.study.fractions import FULL_TRAINING_P, convergence_fractions, model_keys
from threedcal.evaluate.objects import check_object_files
from threedcal.model.stopping import SNAPSHOT_DIR, TWICE_DIR, cycle_ends, snapshot_name
from threedcal.provenance import script_digest
from threedcal.schema import canonical_json, load_yaml
from threedcal.study.config import compared_with, is_imported, validate_config
from threedcal.study.imported_jobs import (
    CV_METHODS,
    SIM2REAL_CONDITIONS,
    group_of,
    method_settings,
    sensor_profile,
    sim2real_inputs,
    sim2real_keys,
    train_keys,
)
from threedcal.study.paths import (
    BALL_EVAL,
    BENCH_TRUTH,
    COLLECT,
    CONVERGENCE,
    CV_FOLDS,
    CV_MODEL_DIR,
    ENVIRONMENT,
    INFERENCE_SPEED,
    INTEGRATION_STUDY,
    LOCKSTEP_RESUME,
    OBJECTS,
    PRESETS,
    PRESSING,
    PRETRAINED_DIR,
    QUICK,
    QUICK_ARMS,
    QUICK_ROUNDS,
    QUICK_SCRATCH,
    QUICK_STUDY,
    REAL_CHECK,
    REALISM_TABLE,
    REALISM_HALO,
    REGISTRATION,
    REGISTRATION_FIGURE,
    RESKIN_EVAL,
    RESKIN_MODEL,
    SCENE_JSON,
    SIM2REAL,
    SIM2REAL_FOLD_DIR,
    SIM2REAL_PRETRAINED_DIR,
    SIM2REAL_SIMSET,
    SPLITS,
    STAGING_STORE,
    STATS,
    STATS_OVERVIEW,
    STORE,
    SUMMARY,
    TRAINSET,
    TWICE_STATS,
    ablation_scenes,
    arms_scenes,
    full_model_file,
    has_objects,
    lockstep_groups,
    model_file,
    quick_scenes,
    real_check_files,
    realism_files,
    realism_sets,
    reskin_scenes,
    stage_config,
    study_targets,
    target,
)

min_version("9.0")


# config.yaml is the default study; `--configfile other.yaml` replaces it (never merges scenes into it).
if not workflow.overwrite_configfiles:

    configfile: "config.yaml"


# Snakemake's YAML loader keeps the last of two equal keys (two scenes of one name) silently; ours
# refuses them, naming the line.
for _config_file in workflow.configfiles:
    load_yaml(_config_file)

# Our validation first (messages name the key and the allowed values), then Snakemake's own.
CONFIG_SOURCE = ", ".join(map(str, workflow.overwrite_configfiles)) or "config.yaml"
config.update(validate_config(config, source=CONFIG_SOURCE))
# What each test-object STL holds, read before anything is collected.
check_object_files(config, source=CONFIG_SOURCE)
validate(config, "workflow/schemas/config.schema.yaml")

# One printer: jobs that drive a real one hold `resources: printer=1` (printer_held), so two never run at
# once, with or without a profile; simulated scenes hold none. `--resources printer=N` still decides.
if "printer" not in workflow.global_resources:
    workflow.global_resources["printer"] = 1

SCENES = list(config["scenes"])
IMPORTED_SCENES = [
    name for name, scene in config["scenes"].items() if is_imported(scene)
]
QUICK_SCENES = quick_scenes(config)
# quick scenes scored arm by arm against a full calibration of their unit (quick.compare_with)
COMPARED_SCENES = arms_scenes(config)
# scenes the collect stage probes (a quick scene collects in its own stage, round by round)
COLLECTED_SCENES = [
    name for name in SCENES if name not in IMPORTED_SCENES and name not in QUICK_SCENES
]
ABLATION_SCENES = ablation_scenes(config)
# an ablation's models train a fraction at a time (rule train_ablation); every other scene's one
# model in rule train
LOCKSTEP_GROUPS = lockstep_groups(config)
SINGLE_MODEL_SCENES = [name for name in SCENES if name not in ABLATION_SCENES]
OBJECT_SCENES = [name for name in SCENES if has_objects(config["scenes"][name])]
RESKIN_SCENES = reskin_scenes(config)
# One software environment for every rule (used with `--sdm conda`; the local .venv otherwise).
CONDA_ENV = str(Path(workflow.basedir) / "workflow/envs/threedcal.yaml")


wildcard_constraints:
    scene="|".join(map(re.escape, SCENES)),


include: "rules/common.smk"
include: "rules/scene.smk"
include: "rules/collect.smk"
include: "rules/dataset.smk"
include: "rules/integration_study.smk"
include: "rules/train.smk"
include: "rules/ball.smk"
include: "rules/stats.smk"
include: "rules/objects.smk"
include: "rules/presets.smk"
include: "rules/report.smk"
include: "rules/reskin.smk"
include: "rules/pretrained.smk"
include: "rules/quick.smk"


rule all:
    default_target: True
    input:
        study_targets(config),
