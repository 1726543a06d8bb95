# Stage `reskin`: magnetic-sensor scenes. The readings in results/{scene}/raw.zarr (named by
# collect/summary.json: the store is a source, see rules/collect.smk) train a small MLP
# (contact x, y and depth), scored on held-out probe coordinates: results/{scene}/reskin_eval.json.


rule reskin_train:
    input:
        collected=COLLECT["summary"],
    output:
        model=RESKIN_MODEL["model"],
        losses=RESKIN_MODEL["losses"],
        splits=RESKIN_MODEL["splits"],
    log:
        "results/{scene}/logs/reskin_train.log",
    benchmark:
        "results/{scene}/benchmarks/reskin_train.tsv"
    wildcard_constraints:
        scene=one_of(RESKIN_SCENES),
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        settings=lambda wildcards: config["scenes"][wildcards.scene]["reskin"],
        seed=scene_seed,
        torch_threads=scene_threads,
        code=code_digest("reskin_train.py"),
    script:
        "../scripts/reskin_train.py"


rule reskin_eval:
    input:
        collected=COLLECT["summary"],
        model=RESKIN_MODEL["model"],
        splits=RESKIN_MODEL["splits"],
    output:
        metrics=RESKIN_EVAL["metrics"],
        figure=report(
            RESKIN_EVAL["figure"],
            caption="../workflow/report/reskin_eval.rst",
            category="{scene}",
            subcategory="3 ReSkin",
        ),
    log:
        "results/{scene}/logs/reskin_eval.log",
    benchmark:
        "results/{scene}/benchmarks/reskin_eval.tsv"
    wildcard_constraints:
        scene=one_of(RESKIN_SCENES),
    conda:
        CONDA_ENV
    params:
        sensor=lambda wildcards: config["scenes"][wildcards.scene]["sensor"],
        code=code_digest("reskin_eval.py"),
    script:
        "../scripts/reskin_eval.py"
