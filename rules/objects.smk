# Stage `objects`: test objects pressed on the simulated bench, depth predicted by the P = 80 model
# (and every other P), errors against the CAD ground truth (Table II, Figs. 3C, 5, 6). It reads
# replicate 0 of each P only (models/P{p}/r0/model.pt).


rule objects:
    input:
        unpack(first_replicate_models),
    output:
        errors="results/{scene}/objects/errors.csv",
        integrators="results/{scene}/objects/integrators.csv",
        presses="results/{scene}/objects/presses.csv",
        violins=report(
            "results/{scene}/objects/violins.png",
            caption="../workflow/report/objects_violins.rst",
            category="{scene}",
            subcategory="5 test objects",
        ),
        figures=report(
            directory("results/{scene}/objects/figures"),
            patterns=["{name}.png"],
            caption="../workflow/report/objects_figures.rst",
            category="{scene}",
            subcategory="5 test objects",
        ),
    log:
        "results/{scene}/logs/objects.log",
    wildcard_constraints:
        scene="|".join(OBJECT_SCENES) or "(?!)",  # "(?!)" matches nothing
    conda:
        CONDA_ENV
    threads: lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"]
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "objects"
        ),
        fractions=lambda wildcards: training_fractions(
            config["scenes"][wildcards.scene]
        ),
        code=source_digest("evaluate", "sim", "model", "depth"),
    script:
        "../scripts/objects.py"
