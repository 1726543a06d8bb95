# Stage `train`: one model per (scene, P, replicate) from the scene's model-ready set; ball_eval for
# imported balls. Replicate r trains on its own nested subset with its own seed (threedcal.dataset.splits).


rule train:
    input:
        trainset="results/{scene}/dataset/trainset",
    output:
        model="results/{scene}/models/P{p}/r{r}/model.pt",
        losses="results/{scene}/models/P{p}/r{r}/losses.csv",
        figure="results/{scene}/models/P{p}/r{r}/losses.png",
    log:
        "results/{scene}/logs/train_P{p}_r{r}.log",
    benchmark:
        "results/{scene}/benchmarks/train_P{p}_r{r}.tsv"
    wildcard_constraints:
        p=r"\d+",
        r=r"\d+",
    conda:
        CONDA_ENV
    threads: lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"]
    params:
        settings=lambda wildcards: {
            key: config["scenes"][wildcards.scene][key]
            for key in ("model", "seed", "torch_threads")
        },
        code=code_digest("train.py"),
    script:
        "../scripts/train.py"


rule ball_eval:
    input:
        model=lambda wildcards: full_model_file(
            wildcards.scene, config["scenes"][wildcards.scene]
        ),
        trainset="results/{scene}/dataset/trainset",
    output:
        "results/{scene}/ball_eval.json",
    log:
        "results/{scene}/logs/ball_eval.log",
    benchmark:
        "results/{scene}/benchmarks/ball_eval.tsv"
    wildcard_constraints:
        scene="|".join(IMPORTED_SCENES) or "(?!)",
    conda:
        CONDA_ENV
    params:
        seed=lambda wildcards: config["scenes"][wildcards.scene]["seed"],
        code=code_digest("ball_eval.py"),
    script:
        "../scripts/ball_eval.py"
