# Stage `train`: one model per (scene, P, replicate) from the scene's model-ready set (imported balls:
# rules/ball.smk). Replicate r trains on its own nested subset with its own seed (threedcal.dataset.splits).


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


# The convergence check (ablation.convergence): replicate 0 of P = 80 and of the smallest P trained
# again with twice the stopping rule's budget, a snapshot of the best weights at every check.
rule train_twice:
    input:
        unpack(pretrained_input),
        trainset=TRAINSET,
        study=model_file("{scene}", "{p}", 0),
    output:
        model=f"{CONVERGENCE_RUN}/model.pt",
        losses=f"{CONVERGENCE_RUN}/losses.csv",
        figure=f"{CONVERGENCE_RUN}/losses.png",
        snapshots=directory(f"{CONVERGENCE_RUN}/snapshots"),
    log:
        "results/{scene}/logs/train_twice_P{p}.log",
    benchmark:
        "results/{scene}/benchmarks/train_twice_P{p}.tsv"
    wildcard_constraints:
        p=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        settings=lambda wildcards: {
            key: config["scenes"][wildcards.scene][key]
            for key in ("model", "seed", "torch_threads")
        },
        code=code_digest("train_twice.py"),
    script:
        "../scripts/train_twice.py"
