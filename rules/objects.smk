# Stage `objects`, in two rules. `object_presses`: the printer presses each test object (mounted on
# the head in place of the ball) at planned poses, a tuning and a reporting session, one frame per
# press (the simulated bench renders each press once). `objects`: every model predicts depth on
# those frames, scored under the `printer` protocol (ground truth where the registration and the
# commanded Z put the object) and the paper's (`paper`: aligned and depth-fitted), Table II,
# Figs. 3C, 5, 6. A new model reruns only the scoring. With ablation replicates, `objects` scores
# every replicate of each P (models/P{p}/r{r}/model.pt) and reports the mean over presses and
# replicates; the figures show replicate 0.


# The presses drive the printer, attached to the machine that runs Snakemake: never submitted to a cluster.
localrules:
    object_presses,


rule object_presses:
    input:
        registration=REGISTRATION,
    output:
        frames=PRESSING["frames"],
        plan=PRESSING["plan"],
        truth=PRESSING["truth"],
        summary=PRESSING["summary"],
    log:
        "results/{scene}/logs/object_presses.log",
    benchmark:
        "results/{scene}/benchmarks/object_presses.tsv"
    wildcard_constraints:
        scene=one_of(OBJECT_SCENES),
    conda:
        CONDA_ENV
    resources:
        printer=printer_held,
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "object_presses"
        ),
        code=code_digest("object_presses.py"),
    script:
        "../scripts/object_presses.py"


rule objects:
    input:
        unpack(scene_models),
        registration=REGISTRATION,
        frames=PRESSING["frames"],
        plan=PRESSING["plan"],
        truth=PRESSING["truth"],
    output:
        errors=OBJECTS["errors"],
        tuning=OBJECTS["tuning"],
        integrators=OBJECTS["integrators"],
        presses=OBJECTS["presses"],
        violins=report(
            OBJECTS["violins"],
            caption="../workflow/report/objects_violins.rst",
            category="{scene}",
            subcategory="5 test objects",
        ),
        figures=report(
            directory(OBJECTS["figures"]),
            patterns=["{name}.png"],
            caption="../workflow/report/objects_figures.rst",
            category="{scene}",
            subcategory="5 test objects",
        ),
    log:
        "results/{scene}/logs/objects.log",
    benchmark:
        "results/{scene}/benchmarks/objects.tsv"
    wildcard_constraints:
        scene=one_of(OBJECT_SCENES),
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "objects"
        ),
        models=lambda wildcards: model_keys(config["scenes"][wildcards.scene]),
        code=code_digest("objects.py"),
    script:
        "../scripts/objects.py"
