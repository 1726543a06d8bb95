# Stage `presets`: every CPU model preset trained alike on an imported scene, depth error against
# inference time (the report's "which preset when").


rule presets:
    input:
        trainset="results/{scene}/dataset/trainset",
    output:
        csv="results/{scene}/presets.csv",
        png=report(
            "results/{scene}/presets.png",
            caption="../workflow/report/presets.rst",
            category="{scene}",
            subcategory="3 models",
        ),
    log:
        "results/{scene}/logs/presets.log",
    benchmark:
        "results/{scene}/benchmarks/presets.tsv"
    wildcard_constraints:
        scene="|".join(IMPORTED_SCENES) or "(?!)",  # "(?!)" matches nothing
    conda:
        CONDA_ENV
    threads: lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"]
    params:
        model=lambda wildcards: config["scenes"][wildcards.scene]["model"],
        seed=lambda wildcards: config["scenes"][wildcards.scene]["seed"],
        threads=lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"],
        presets=["compact", "compact_tiny", "context", "multiscale", "lookup"],
        code=code_digest("presets.py"),
    script:
        "../scripts/presets.py"
