# Stage `train`: one model per (scene, P) from the scene's model-ready set (imported balls: rules/ball.smk).


rule train:
    input:
        trainset="results/{scene}/dataset/trainset",
    output:
        model="results/{scene}/models/P{p}/model.pt",
        losses="results/{scene}/models/P{p}/losses.csv",
        figure="results/{scene}/models/P{p}/losses.png",
    log:
        "results/{scene}/logs/train_P{p}.log",
    benchmark:
        "results/{scene}/benchmarks/train_P{p}.tsv"
    wildcard_constraints:
        p=r"\d+",
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
