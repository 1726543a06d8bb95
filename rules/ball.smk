# Stage `ball_eval`: the cross-validated real-data evaluation of imported scenes (docs/explanation/real-data.md):
# grouped folds, one model per (method, fold), then the pooled figures with intervals.


rule cv_folds:
    input:
        trainset=TRAINSET,
    output:
        CV_FOLDS,
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
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        model=f"{CV_MODEL_DIR}/model.pt",
        losses=f"{CV_MODEL_DIR}/losses.csv",
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
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        json=BALL_EVAL["json"],
        images=BALL_EVAL["images"],
        figure=report(
            BALL_EVAL["figure"],
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


# Stage `sim2real` (scenes with sim_to_real.enabled; docs/explanation/real-data.md): simulated presses of the
# scene's sensor profile -> a pretrained model -> per fold and k, fine-tuned and real-only models
# (and, with sim_to_real.shipped, the package's pretrained weights fine-tuned) -> error against k.


rule sim2real_simulate:
    input:
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        directory(SIM2REAL_SIMSET),
    log:
        "results/{scene}/logs/sim2real_simulate_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_simulate_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        fold=r"\d+",
    conda:
        CONDA_ENV
    params:
        profile=lambda wildcards: sensor_profile(config["scenes"][wildcards.scene]),
        sim_to_real=lambda wildcards: sim2real_keys(
            config["scenes"][wildcards.scene], "simulate"
        ),
        seed=scene_seed,
        code=code_digest("sim2real_simulate.py"),
    script:
        "../scripts/sim2real_simulate.py"


rule sim2real_pretrain:
    input:
        simset=SIM2REAL_SIMSET,
    output:
        model=f"{SIM2REAL_PRETRAINED_DIR}/model.pt",
        losses=f"{SIM2REAL_PRETRAINED_DIR}/losses.csv",
    log:
        "results/{scene}/logs/sim2real_pretrain_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_pretrain_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        fold=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        model=lambda wildcards: config["scenes"][wildcards.scene]["model"],
        sim_to_real=lambda wildcards: sim2real_keys(
            config["scenes"][wildcards.scene], "pretrain"
        ),
        seed=scene_seed,
        threads=scene_threads,
        code=code_digest("sim2real_pretrain.py"),
    script:
        "../scripts/sim2real_pretrain.py"


rule sim2real_train:
    input:
        unpack(sim2real_init),
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        model=f"{SIM2REAL_MODEL_DIR}/model.pt",
        losses=f"{SIM2REAL_MODEL_DIR}/losses.csv",
    log:
        "results/{scene}/logs/sim2real_{condition}_k{k}_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_{condition}_k{k}_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        condition="|".join(SIM2REAL_CONDITIONS),
        k=r"\d+|all",
        fold=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        # shipped+real trains with the shipped weights' own recipe, not the scene's model
        model=lambda wildcards: (
            {}
            if wildcards.condition == "shipped_real"
            else config["scenes"][wildcards.scene]["model"]
        ),
        sim_to_real=lambda wildcards: train_keys(
            config["scenes"][wildcards.scene], wildcards.condition
        ),
        seed=scene_seed,
        threads=scene_threads,
        code=code_digest("sim2real_train.py"),
    script:
        "../scripts/sim2real_train.py"


rule sim2real_eval:
    input:
        unpack(sim2real_models),
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        errors=SIM2REAL["errors"],
        images=SIM2REAL["images"],
        figure=report(
            SIM2REAL["figure"],
            caption="../workflow/report/sim2real.rst",
            category="{scene}",
            subcategory="3 models",
        ),
    log:
        "results/{scene}/logs/sim2real_eval.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_eval.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
    conda:
        CONDA_ENV
    params:
        sim_to_real=lambda wildcards: config["scenes"][wildcards.scene]["sim_to_real"],
        cv=lambda wildcards: config["scenes"][wildcards.scene]["cv"],
        seed=scene_seed,
        threads=scene_threads,
        code=code_digest("sim2real_eval.py"),
    script:
        "../scripts/sim2real_eval.py"
