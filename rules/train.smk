# Stage `train`: one model per (scene, P) from the scene's model-ready set; ball_eval for imported balls.


rule train:
    input:
        trainset="results/{scene}/dataset/trainset",
    output:
        model="results/{scene}/models/P{p}/model.pt",
        losses="results/{scene}/models/P{p}/losses.csv",
        figure="results/{scene}/models/P{p}/losses.png",
    log:
        "results/{scene}/logs/train_P{p}.log",
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


rule ball_eval:
    input:
        model=lambda wildcards: (
            f"results/{wildcards.scene}/models/P{max(training_fractions(config['scenes'][wildcards.scene]))}/model.pt"
        ),
        trainset="results/{scene}/dataset/trainset",
    output:
        "results/{scene}/ball_eval.json",
    log:
        "results/{scene}/logs/ball_eval.log",
    wildcard_constraints:
        scene="|".join(IMPORTED_SCENES) or "(?!)",
    conda:
        CONDA_ENV
    params:
        seed=lambda wildcards: config["scenes"][wildcards.scene]["seed"],
        code=code_digest("ball_eval.py"),
    script:
        "../scripts/ball_eval.py"
