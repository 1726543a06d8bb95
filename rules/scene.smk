# Stage `scene`: the resolved scene (config, full profiles, software versions) every later stage reads.


rule scene:
    output:
        SCENE_JSON,
    log:
        "results/{scene}/logs/scene.log",
    benchmark:
        "results/{scene}/benchmarks/scene.tsv"
    conda:
        CONDA_ENV
    params:
        scene=lambda wildcards: config["scenes"][wildcards.scene],
        code=code_digest("scene.py"),
    script:
        "../scripts/scene.py"
