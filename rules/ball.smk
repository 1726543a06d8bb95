# Stage `ball_eval`: the cross-validated real-data evaluation of imported scenes (docs/explanation/real-data.md):
# grouped folds, one job per fold training its model of every method, then the pooled figures with intervals.


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
        models=expand(f"{CV_MODEL_DIR}/model.pt", method=CV_METHODS, allow_missing=True),
        losses=expand(
            f"{CV_MODEL_DIR}/losses.csv", method=CV_METHODS, allow_missing=True
        ),
    log:
        "results/{scene}/logs/cv_train_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/cv_train_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        fold=r"\d+",
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        # every method of the fold in one job, in the order of `models`
        methods=lambda wildcards: {
            method: method_settings(config["scenes"][wildcards.scene], method)
            for method in CV_METHODS
        },
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
# scene's sensor profile -> a pretrained model per group of test folds -> per condition and fold, one job
# training every k: fine-tuned and real-only models (and, with sim_to_real.shipped, the package's
# pretrained weights fine-tuned) -> error against k.


rule sim2real_simulate:
    input:
        trainset=TRAINSET,
        folds=CV_FOLDS,
    output:
        directory(SIM2REAL_SIMSET),
    log:
        "results/{scene}/logs/sim2real_simulate_folds{folds}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_simulate_folds{folds}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        folds=r"\d+(-\d+)*",
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
        "results/{scene}/logs/sim2real_pretrain_folds{folds}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_pretrain_folds{folds}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        folds=r"\d+(-\d+)*",
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
        directory(SIM2REAL_FOLD_DIR),
    log:
        "results/{scene}/logs/sim2real_{condition}_fold{fold}.log",
    benchmark:
        "results/{scene}/benchmarks/sim2real_{condition}_fold{fold}.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
        condition="|".join(SIM2REAL_CONDITIONS),
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
