# Stage `stats`: per-coordinate validation error of every model (P, replicate) of a scene's ablation,
# the tests against P = 80 (the paper's, paired, equivalence), the learning curve over every
# fraction, the recommendation, the power of the design and the paper's Fig. 3B / 4 figures; the
# cross-scene spread figure (Fig. 4C). See docs/explanation/statistics.md.


rule stats:
    input:
        unpack(scene_models),
        unpack(collect_summary),
        losses=ablation_losses,
        trainset=TRAINSET,
        splits=SPLITS,
    output:
        validation_mse=STATS["validation_mse"],
        tests=report(
            STATS["tests"],
            caption="../workflow/report/stats_tests.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        tests_figure=report(
            STATS["tests_figure"],
            caption="../workflow/report/stats_tests_figure.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        recommendation=STATS["recommendation"],
        learning_curve=report(
            STATS["learning_curve"],
            caption="../workflow/report/stats_learning_curve.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        learning_curve_figure=report(
            STATS["learning_curve_figure"],
            caption="../workflow/report/stats_learning_curve_figure.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        power=STATS["power"],
        power_figure=report(
            STATS["power_figure"],
            caption="../workflow/report/stats_power.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        costs=STATS["costs"],
        loss_figure=report(
            STATS["loss_figure"],
            caption="../workflow/report/stats_loss.rst",
            category="{scene}",
            subcategory="3 training",
        ),
        map_figure=report(
            STATS["map_figure"],
            caption="../workflow/report/stats_map.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        kde_figure=report(
            STATS["kde_figure"],
            caption="../workflow/report/stats_kde.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        cost_figure=report(
            STATS["cost_figure"],
            caption="../workflow/report/stats_cost.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
    log:
        "results/{scene}/logs/stats.log",
    benchmark:
        "results/{scene}/benchmarks/stats.tsv"
    wildcard_constraints:
        scene=one_of(ABLATION_SCENES),
    conda:
        CONDA_ENV
    params:
        models=lambda wildcards: model_keys(config["scenes"][wildcards.scene]),
        settings=config["stats"],
        seed=scene_seed,
        code=code_digest("stats.py"),
    script:
        "../scripts/stats.py"


rule stats_overview:
    input:
        expand(STATS["validation_mse"], scene=ABLATION_SCENES),
    output:
        report(
            STATS_OVERVIEW,
            caption="../workflow/report/stats_std.rst",
            category="study",
            subcategory="ablation",
        ),
    log:
        "results/logs/stats_overview.log",
    benchmark:
        "results/benchmarks/stats_overview.tsv"
    conda:
        CONDA_ENV
    params:
        scenes=ABLATION_SCENES,
        code=code_digest("stats_overview.py"),
    script:
        "../scripts/stats_overview.py"


# The ablation read again on the same models trained on to twice the budget (ablation.convergence).
rule stats_twice:
    input:
        unpack(twice_models),
        trainset=TRAINSET,
        splits=SPLITS,
    output:
        **TWICE_STATS,
    log:
        "results/{scene}/logs/stats_twice.log",
    benchmark:
        "results/{scene}/benchmarks/stats_twice.tsv"
    wildcard_constraints:
        scene=one_of(ABLATION_SCENES),
    conda:
        CONDA_ENV
    params:
        models=lambda wildcards: model_keys(config["scenes"][wildcards.scene]),
        settings=config["stats"],
        seed=scene_seed,
        code=code_digest("stats_twice.py"),
    script:
        "../scripts/stats_twice.py"


# Every fraction's error against training time: the snapshots at the earlier cycle ends scored,
# with the validation errors at the budget and at twice it; per P, the change from one to the other.
rule convergence:
    input:
        snapshots=ablation_snapshots,
        twice_losses=lambda wildcards: twice_files(wildcards, "losses.csv"),
        budget_mse=STATS["validation_mse"],
        twice_mse=TWICE_STATS["validation_mse"],
        trainset=TRAINSET,
    output:
        convergence=CONVERGENCE["convergence"],
        curve=CONVERGENCE["curve"],
        figure=report(
            CONVERGENCE["figure"],
            caption="../workflow/report/stats_error_vs_time.rst",
            category="{scene}",
            subcategory="3 training",
        ),
    log:
        "results/{scene}/logs/convergence.log",
    benchmark:
        "results/{scene}/benchmarks/convergence.tsv"
    wildcard_constraints:
        scene=one_of(ABLATION_SCENES),
    conda:
        CONDA_ENV
    params:
        models=lambda wildcards: model_keys(config["scenes"][wildcards.scene]),
        steps=lambda wildcards: config["scenes"][wildcards.scene]["ablation"]["steps"],
        threads=lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"],
        code=code_digest("convergence.py"),
    script:
        "../scripts/convergence.py"
