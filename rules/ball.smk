# Stage `ball_eval`: the cross-validated real-data evaluation of imported scenes (docs/real_data.md):
# grouped folds, one model per (method, fold), then the pooled figures with intervals.


rule cv_folds:
    input:
        trainset="results/{scene}/dataset/trainset",
    output:
        "results/{scene}/cv/folds.csv",
    log:
        "results/{scene}/logs/cv_folds.log",
    benchmark:
        "results/{scene}/benchmarks/cv_folds.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
    conda:
        CONDA_ENV
    params:
        cv=lambda wildcards: config["scenes"][wildcards.scene]["cv"],
        seed=scene_seed,
        where=lambda wildcards: config["scenes"][wildcards.scene]["import"]["path"],
        code=code_digest("cv_folds.py"),
    script:
        "../scripts/cv_folds.py"


rule cv_train:
    input:
        trainset="results/{scene}/dataset/trainset",
        folds="results/{scene}/cv/folds.csv",
    output:
        model="results/{scene}/cv/{method}/fold{fold}/model.pt",
        losses="results/{scene}/cv/{method}/fold{fold}/losses.csv",
    log:
        "results/{scene}/logs/cv_{method}_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/cv_{method}_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        method="|".join(CV_METHODS),
        fold=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        model=lambda wildcards: method_settings(
            config["scenes"][wildcards.scene], wildcards.method
        ),
        seed=scene_seed,
        threads=scene_threads,
        code=code_digest("cv_train.py"),
    script:
        "../scripts/cv_train.py"


rule ball_eval:
    input:
        unpack(cv_models),
        trainset="results/{scene}/dataset/trainset",
        folds="results/{scene}/cv/folds.csv",
    output:
        json="results/{scene}/ball_eval.json",
        images="results/{scene}/cv/images.csv",
        figure=report(
            "results/{scene}/cv/errors.png",
            caption="../workflow/report/ball_eval.rst",
            category="{scene}",
            subcategory="3 models",
        ),
    log:
        "results/{scene}/logs/ball_eval.log",
    benchmark:
        "results/{scene}/benchmarks/ball_eval.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
    conda:
        CONDA_ENV
    params:
        cv=lambda wildcards: config["scenes"][wildcards.scene]["cv"],
        seed=scene_seed,
        threads=scene_threads,
        preset=lambda wildcards: config["scenes"][wildcards.scene]["model"]["preset"],
        code=code_digest("ball_eval.py"),
    script:
        "../scripts/ball_eval.py"
