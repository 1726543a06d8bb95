# Stage `train`. A scene without an ablation trains one model (P = 80, replicate 0) under its
# stopping rule; an imported scene's is rules/ball.smk. An ablation trains each fraction P's
# replicates together in one job, every model the same steps (threedcal.model.lockstep): replicate
# r on its own nested subset with its own seed (threedcal.dataset.splits).


rule train:
    input:
        unpack(pretrained_input),
        trainset=TRAINSET,
    output:
        model=model_file("{scene}", "{p}", "{r}"),
        losses=model_file("{scene}", "{p}", "{r}", "losses.csv"),
        figure=model_file("{scene}", "{p}", "{r}", "losses.png"),
    log:
        "results/{scene}/logs/train_P{p}_r{r}.log",
    benchmark:
        "results/{scene}/benchmarks/train_P{p}_r{r}.tsv"
    wildcard_constraints:
        scene=one_of(SINGLE_MODEL_SCENES),
        p=r"\d+",
        r=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        settings=lambda wildcards: {
            key: config["scenes"][wildcards.scene][key]
            for key in ("model", "seed", "torch_threads")
        },
        code=code_digest("train.py"),
    script:
        "../scripts/train.py"


# One rule per distinct (replicates, steps, convergence) of the ablation scenes: they fix its outputs.
for _index, ((_replicates, _steps, _twice), _scenes) in enumerate(
    LOCKSTEP_GROUPS.items()
):

    rule:
        name:
            "train_ablation" if _index == 0 else f"train_ablation_{_index + 1}"
        input:
            unpack(pretrained_input),
            trainset=TRAINSET,
        output:
            **lockstep_outputs(_replicates, _steps, _twice),
        log:
            "results/{scene}/logs/train_ablation_P{p}.log",
        benchmark:
            "results/{scene}/benchmarks/train_ablation_P{p}.tsv"
        wildcard_constraints:
            scene=one_of(_scenes),
            p=r"\d+",
        conda:
            CONDA_ENV
        threads: scene_threads
        params:
            settings=lambda wildcards: {
                key: config["scenes"][wildcards.scene][key]
                for key in ("model", "seed", "torch_threads")
            },
            ablation=lambda wildcards: config["scenes"][wildcards.scene]["ablation"],
            resume=lambda wildcards: target(LOCKSTEP_RESUME, wildcards.scene).replace(
                "{p}", wildcards.p
            ),
            code=code_digest("train_ablation.py"),
        script:
            "../scripts/train_ablation.py"
