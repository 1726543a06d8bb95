# Stage `dataset`: registration, exact labels, splits and the model-ready set (results/{scene}/dataset/).


rule dataset_import:
    output:
        trainset=directory("results/{scene}/dataset/trainset"),
        splits="results/{scene}/dataset/splits.csv",
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
        collected="results/{scene}/collect/summary.json",
        truth="results/{scene}/collect/bench_truth.json",
    output:
        trainset=directory("results/{scene}/dataset/trainset"),
        splits="results/{scene}/dataset/splits.csv",
        registration="results/{scene}/dataset/registration.json",
        figure=report(
            "results/{scene}/dataset/registration.png",
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
