# Stage `presets`: every CPU model preset trained alike on an imported scene, depth error against
# inference time (the report's "which preset when"); the scene's own preset is its P = 80 model.


rule presets:
    input:
        unpack(presets_scene_model),
        trainset=TRAINSET,
    output:
        csv=PRESETS["csv"],
        png=report(
            PRESETS["png"],
            caption="../workflow/report/presets.rst",
            category="{scene}",
            subcategory="3 models",
        ),
    log:
        "results/{scene}/logs/presets.log",
    benchmark:
        "results/{scene}/benchmarks/presets.tsv"
    wildcard_constraints:
        scene=one_of(IMPORTED_SCENES),
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        model=lambda wildcards: config["scenes"][wildcards.scene]["model"],
        seed=scene_seed,
        threads=scene_threads,
        presets=["compact", "compact_tiny", "context", "multiscale", "lookup"],
        code=code_digest("presets.py"),
    script:
        "../scripts/presets.py"
