# Helpers shared by the rules.


def code_digest(script):
    """Digest of a script and every library module it runs: a rerun reason when it changes.
    Each step passes its own script (tests/test_provenance.py checks that they agree).
    """
    return script_digest(Path(workflow.basedir) / "scripts" / script)


def one_of(scenes):
    """A wildcard constraint matching exactly these scene names ("(?!)": none, when empty)."""
    return "|".join(map(re.escape, scenes)) or "(?!)"


def scene_seed(wildcards):
    return config["scenes"][wildcards.scene]["seed"]


def printer_held(wildcards):
    """1 for a job that drives a scene's real printer (`resources: printer`, one at a time), 0 on
    the simulated bench: every simulated scene has its own printer and camera."""
    return int(config["scenes"][wildcards.scene].get("port", "sim") != "sim")


def scene_threads(wildcards):
    """The scene's torch threads: the job's `threads` and what its script sets torch to."""
    return config["scenes"][wildcards.scene]["torch_threads"]


def collect_summary(wildcards):
    """{"summary": results/{scene}/collect/summary.json} for a collected scene, {} for an imported one."""
    if wildcards.scene in COLLECTED_SCENES:
        return {"summary": target(COLLECT["summary"], wildcards.scene)}
    return {}


def scene_models(wildcards):
    """{"P5_r0": "results/{scene}/models/P5/r0/model.pt", ...}: every model of a scene, by fraction and replicate."""
    scene = config["scenes"][wildcards.scene]
    return {
        f"P{p}_r{r}": model_file(wildcards.scene, p, r) for p, r in model_keys(scene)
    }


def twice_files(wildcards, leaf):
    """Every model's file `leaf` at twice the budget (twice/), by fraction and replicate."""
    scene = config["scenes"][wildcards.scene]
    return [
        model_file(wildcards.scene, p, r, f"{TWICE_DIR}/{leaf}")
        for p, r in model_keys(scene)
    ]


def twice_models(wildcards):
    """{"P5_r0": ".../models/P5/r0/twice/model.pt", ...}: the ablation at twice the budget."""
    keys = model_keys(config["scenes"][wildcards.scene])
    return {
        f"P{p}_r{r}": path
        for (p, r), path in zip(keys, twice_files(wildcards, "model.pt"))
    }


def lockstep_outputs(replicates: int, steps: int, twice: bool) -> dict[str, list[str]]:
    """The files one lockstep job writes for fraction {p} of scene {scene}: per replicate its
    model, loss log and figure, its snapshots at the earlier cycle ends, and with `twice` its
    model and loss log at twice the budget (threedcal.model.lockstep)."""

    def each(leaf: str) -> list[str]:
        return [model_file("{scene}", "{p}", r, leaf) for r in range(replicates)]

    ends = cycle_ends(steps, twice)
    outputs = {
        "models": each("model.pt"),
        "losses": each("losses.csv"),
        "figures": each("losses.png"),
        "snapshots": [
            path
            for end in ends
            if end < steps
            for path in each(f"{SNAPSHOT_DIR}/{snapshot_name(end)}")
        ],
    }
    if twice:
        outputs["twice"] = each(f"{TWICE_DIR}/model.pt")
        outputs["twice_losses"] = each(f"{TWICE_DIR}/losses.csv")
    return outputs


def ablation_snapshots(wildcards):
    """Every model's snapshots at the cycle ends before the budget."""
    scene = config["scenes"][wildcards.scene]
    steps = scene["ablation"]["steps"]
    return [
        model_file(wildcards.scene, p, r, f"{SNAPSHOT_DIR}/{snapshot_name(end)}")
        for p, r in model_keys(scene)
        for end in cycle_ends(steps)
        if end < steps
    ]


def ablation_losses(wildcards):
    scene = config["scenes"][wildcards.scene]
    return [
        model_file(wildcards.scene, p, r, "losses.csv") for p, r in model_keys(scene)
    ]


def cv_models(wildcards):
    """{"model": [fold0 ... foldK-1 model.pt], "lookup": [...]}: every fold model ball_eval scores."""
    folds = config["scenes"][wildcards.scene]["cv"]["folds"]
    return {
        method: [
            target(f"{CV_MODEL_DIR}/model.pt", wildcards.scene)
            .replace("{method}", method)
            .replace("{fold}", str(fold))
            for fold in range(folds)
        ]
        for method in CV_METHODS
    }


def sim2real_init(wildcards):
    """{"pretrained": the sim-pretrained model of the fold's group} for sim+real, {"shipped": the
    package's weights for the sensor} for shipped+real (found by the training itself; an input so
    that rebuilt weights retrain), {} for real-only."""
    if wildcards.condition == "sim_real":
        scene = config["scenes"][wildcards.scene]
        return {
            "pretrained": target(
                f"{SIM2REAL_PRETRAINED_DIR}/model.pt", wildcards.scene
            ).replace("{folds}", group_of(scene, int(wildcards.fold)))
        }
    if wildcards.condition == "shipped_real":
        from threedcal.pretrained import shipped_weights
        from threedcal.profiles import load_profile

        # by the profile's name, as the config check and the training find them
        sensor = load_profile("sensor", config["scenes"][wildcards.scene]["sensor"])[
            "name"
        ]
        return {"shipped": str(shipped_weights(sensor))}
    return {}


def sim2real_models(wildcards):
    """{"sim_real": [fold folders ...], ..., "scene": [cv/model fold models]}: what sim2real_eval scores."""
    return sim2real_inputs(wildcards.scene, config["scenes"][wildcards.scene])


def presets_scene_model(wildcards):
    """{"scene_model": models/P80/r0/model.pt} where the scene trains it: the presets stage's row
    of the scene's own preset, not trained twice; {} otherwise."""
    if (FULL_TRAINING_P, 0) not in model_keys(config["scenes"][wildcards.scene]):
        return {}
    return {"scene_model": model_file(wildcards.scene, FULL_TRAINING_P, 0)}


def pretrained_input(wildcards):
    """The shipped weights a scene's training starts from (model.init: pretrained): rebuilt
    weights retrain the scene's models."""
    scene = config["scenes"][wildcards.scene]
    if (scene.get("model") or {}).get("init") != "pretrained":
        return {}
    from threedcal.pretrained import shipped_weights
    from threedcal.profiles import load_profile

    sensor = load_profile("sensor", scene["sensor"])["name"]
    return {"pretrained": str(shipped_weights(sensor))}  # a clear error when missing


def study_pairs():
    """(quick scene, full scene) of every compared quick scene: the units of `quick_study`."""
    return [
        (name, compared_with(config["scenes"][name]))
        for name in QUICK_SCENES
        if compared_with(config["scenes"][name])
    ]


def quick_study_inputs(wildcards):
    """Each unit's stopped quick model and stop.json, and its full calibration's P = 80 models,
    validation set, splits and (on the bench) hidden truth and store (relabelled through it).
    """
    inputs = {}
    for quick, full in study_pairs():
        inputs[f"{quick}_model"] = target(QUICK["model"], quick)
        inputs[f"{quick}_stop"] = target(QUICK["stop"], quick)
        inputs[f"{full}_models"] = [
            model_file(full, p, r)
            for p, r in model_keys(config["scenes"][full])
            if p == FULL_TRAINING_P
        ]
        inputs[f"{full}_trainset"] = target(TRAINSET, full)
        inputs[f"{full}_splits"] = target(SPLITS, full)
        if config["scenes"][full].get("port") == "sim":
            inputs[f"{full}_truth"] = target(BENCH_TRUTH, full)
            inputs[f"{full}_collected"] = target(
                COLLECT["summary"], full
            )  # names its store
    return inputs


def arms_inputs(wildcards):
    """The compared scene's files: its P = 80 models, validation set, registration, object presses."""
    full = compared_with(config["scenes"][wildcards.scene])
    return {
        "full": [
            model_file(full, p, r)
            for p, r in model_keys(config["scenes"][full])
            if p == FULL_TRAINING_P
        ],
        "trainset": target(TRAINSET, full),
        "splits": target(SPLITS, full),
        "summary": target(COLLECT["summary"], full),
        "registration": target(REGISTRATION, full),
        **{f"pressing_{k}": target(v, full) for k, v in PRESSING.items()},
    }
