# Stage `quick`: a new unit calibrated in rounds of presses (plan.pattern: quick), each round scored
# by the model before it, until the stop rule or max_presses; results/{scene}/quick/. The store
# (results/{scene}/raw.zarr) is a source as in rules/collect.smk: filled under .partial/, moved into
# place when the rule stops, never among the outputs; a rerun replays the rounds from it.


# The printer is attached to the machine that runs Snakemake: never submitted to a cluster.
localrules:
    quick,


rule quick:
    input:
        unpack(pretrained_input),
    output:
        model=QUICK["model"],
        rounds=QUICK["rounds"],
        stop=QUICK["stop"],
        work=directory(QUICK_ROUNDS),
    log:
        "results/{scene}/logs/quick.log",
    benchmark:
        "results/{scene}/benchmarks/quick.tsv"
    wildcard_constraints:
        scene=one_of(QUICK_SCENES),
    conda:
        CONDA_ENV
    threads: scene_threads
    resources:
        printer=1,
    params:
        scene=lambda wildcards: canonical_json(
            stage_config(config["scenes"][wildcards.scene], "quick")
        ),
        store=lambda wildcards: target(STORE, wildcards.scene),
        staging=lambda wildcards: target(STAGING_STORE, wildcards.scene),
        code=code_digest("quick.py"),
    script:
        "../scripts/quick.py"


# Stage `quick_arms`, for quick scenes with `quick.compare_with` (and quick.arms): the rounds' models
# (quick; stopped: where the rule stopped), the same presses trained from scratch, and the compared
# scene's P = 80 models (full), scored on that scene's validation coordinates and test-object
# presses (threedcal.study.quick_arms).
rule quick_arms:
    input:
        unpack(arms_inputs),
        rounds=QUICK["rounds"],
        stop=QUICK["stop"],
        work=QUICK_ROUNDS,
    output:
        table=QUICK_ARMS["table"],
        figure=report(
            QUICK_ARMS["figure"],
            caption="../workflow/report/quick_arms.rst",
            category="{scene}",
            subcategory="quick calibration",
        ),
        verdicts=QUICK_ARMS["verdicts"],
        scratch=directory(QUICK_SCRATCH),
    log:
        "results/{scene}/logs/quick_arms.log",
    benchmark:
        "results/{scene}/benchmarks/quick_arms.tsv"
    wildcard_constraints:
        scene=one_of(COMPARED_SCENES),
    conda:
        CONDA_ENV
    threads: scene_threads
    params:
        scene=lambda wildcards: canonical_json(
            stage_config(config["scenes"][wildcards.scene], "quick")
        ),
        full=lambda wildcards: compared_with(config["scenes"][wildcards.scene]),
        objects=lambda wildcards: stage_config(
            config["scenes"][compared_with(config["scenes"][wildcards.scene])],
            "objects",
        ),
        store=lambda wildcards: target(STORE, wildcards.scene),
        code=code_digest("quick_arms.py"),
    script:
        "../scripts/quick_arms.py"


# Target `quick_study` (`make quick-study`, config/quick_study.yaml; never part of `all`): every
# compared quick scene's stopped model against its unit's full calibration, and the claim over
# units (threedcal.study.quick_study).
rule quick_study:
    input:
        unpack(quick_study_inputs),
    output:
        table=QUICK_STUDY["table"],
        summary=QUICK_STUDY["summary"],
        figure=report(
            QUICK_STUDY["figure"],
            caption="../workflow/report/quick_study.rst",
            category="quick calibration over units",
        ),
    log:
        "results/quick_study/logs/quick_study.log",
    benchmark:
        "results/quick_study/benchmarks/quick_study.tsv"
    conda:
        CONDA_ENV
    threads: 1
    params:
        pairs=lambda wildcards: study_pairs(),
        sensors={name: config["scenes"][name]["sensor"] for name, _ in study_pairs()},
        units={
            name: (config["scenes"][name].get("bench") or {}).get("unit")
            for name, _ in study_pairs()
        },
        datasets=lambda wildcards: {
            full: stage_config(config["scenes"][full], "dataset")
            for _, full in study_pairs()
        },
        code=code_digest("quick_study.py"),
    script:
        "../scripts/quick_study.py"
