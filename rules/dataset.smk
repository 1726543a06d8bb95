# Stage `dataset`: registration, exact labels, splits and the model-ready set (results/{scene}/dataset/).


rule dataset_import:
    output:
        trainset=directory(TRAINSET),
        splits=SPLITS,
    log:
        "results/{scene}/logs/dataset.log",
    benchmark:
        "results/{scene}/benchmarks/dataset_import.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
    conda:
        CONDA_ENV
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "dataset"
        ),
        code=code_digest("dataset_import.py"),
    script:
        "../scripts/dataset_import.py"


rule dataset_collected:
    input:
        # names the store (a source, see rules/collect.smk) and the digest of its frame settings
        collected=COLLECT["summary"],
        truth=BENCH_TRUTH,
    output:
        trainset=directory(TRAINSET),
        splits=SPLITS,
        registration=REGISTRATION,
        figure=report(
            REGISTRATION_FIGURE,
            caption="../workflow/report/registration.rst",
            category="{scene}",
            subcategory="2 registration",
        ),
    log:
        "results/{scene}/logs/dataset.log",
    benchmark:
        "results/{scene}/benchmarks/dataset_collected.tsv"
    wildcard_constraints:
        scene=one_of(COLLECTED_SCENES),
    conda:
        CONDA_ENV
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "dataset"
        ),
        code=code_digest("dataset_collected.py"),
    script:
        "../scripts/dataset_collected.py"
