# Study-wide outputs: run environment, inference speed per scene, simulator realism, the summary page.


rule environment:
    output:
        report(
            ENVIRONMENT,
            caption="../workflow/report/environment.rst",
            category="study",
            subcategory="run environment",
        ),
    log:
        "results/logs/environment.log",
    benchmark:
        "results/benchmarks/environment.tsv"
    conda:
        CONDA_ENV
    params:
        config=lambda wildcards: {
            k: config[k] for k in ("seed", "torch_threads", "scenes")
        },
        code=code_digest("environment.py"),
    script:
        "../scripts/environment.py"


rule inference_speed:
    input:
        model=lambda wildcards: full_model_file(
            wildcards.scene, config["scenes"][wildcards.scene]
        ),
        trainset=TRAINSET,
    output:
        INFERENCE_SPEED,
    log:
        "results/{scene}/logs/inference_speed.log",
    benchmark:
        "results/{scene}/benchmarks/inference_speed.tsv"
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        threads=scene_threads,
        code=code_digest("inference_speed.py"),
    script:
        "../scripts/inference_speed.py"


rule realism:
    input:
        realism_files(config),
    output:
        table=report(
            REALISM_TABLE,
            caption="../workflow/report/realism.rst",
            category="study",
            subcategory="simulator realism",
        ),
        halo_csv=REALISM_HALO["csv"],
        halo_png=report(
            REALISM_HALO["png"],
            caption="../workflow/report/realism_halo.rst",
            category="study",
            subcategory="simulator realism",
        ),
    log:
        "results/logs/realism.log",
    benchmark:
        "results/benchmarks/realism.tsv"
    conda:
        CONDA_ENV
    params:
        sets=realism_sets(config),
        split_seed=config.get("realism", {}).get("split_seed", 0),
        seed=config["seed"],
        code=code_digest("realism.py"),
    script:
        "../scripts/realism.py"


rule summary:
    input:
        [t for t in study_targets(config) if t != SUMMARY],
    output:
        report(
            SUMMARY,
            caption="../workflow/report/summary.rst",
            category="study",
            subcategory="summary",
        ),
    log:
        "results/logs/summary.log",
    benchmark:
        "results/benchmarks/summary.tsv"
    conda:
        CONDA_ENV
    params:
        config=lambda wildcards: {k: config[k] for k in ("scenes",)},
        code=code_digest("summary.py"),
    script:
        "../scripts/summary.py"


rule real_check:
    input:
        real_check_files(config),
    output:
        table=report(
            REAL_CHECK["table"],
            caption="../workflow/report/real_check.rst",
            category="study",
            subcategory="shipped weights on real frames",
        ),
        frames=REAL_CHECK["frames"],
    log:
        "results/logs/real_check.log",
    benchmark:
        "results/benchmarks/real_check.tsv"
    conda:
        CONDA_ENV
    threads: config["torch_threads"]
    params:
        settings=config.get("real_check", {}),
        seed=config["seed"],
        code=code_digest("real_check.py"),
    script:
        "../scripts/real_check.py"
