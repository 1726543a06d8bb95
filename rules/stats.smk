# Stage `stats`: per-coordinate validation error of every model (P, replicate) of a scene's ablation,
# the tests against P = 80 (the paper's, paired, equivalence), the recommendation, the power of the
# design and the paper's Fig. 3B / 4 figures; the cross-scene spread figure (Fig. 4C). See
# docs/statistics.md.


rule stats:
    input:
        unpack(scene_models),
        unpack(collect_summary),
        losses=ablation_losses,
        trainset="results/{scene}/dataset/trainset",
        splits="results/{scene}/dataset/splits.csv",
    output:
        validation_mse="results/{scene}/stats/validation_mse.csv",
        tests=report(
            "results/{scene}/stats/tests.csv",
            caption="../workflow/report/stats_tests.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        tests_figure=report(
            "results/{scene}/stats/tests.png",
            caption="../workflow/report/stats_tests_figure.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        recommendation="results/{scene}/stats/recommendation.txt",
        power="results/{scene}/stats/power.csv",
        power_figure=report(
            "results/{scene}/stats/power.png",
            caption="../workflow/report/stats_power.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        costs="results/{scene}/stats/error_vs_cost.csv",
        loss_figure=report(
            "results/{scene}/stats/loss_curves.png",
            caption="../workflow/report/stats_loss.rst",
            category="{scene}",
            subcategory="3 training",
        ),
        map_figure=report(
            "results/{scene}/stats/mse_map.png",
            caption="../workflow/report/stats_map.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        kde_figure=report(
            "results/{scene}/stats/mse_kde.png",
            caption="../workflow/report/stats_kde.rst",
            category="{scene}",
            subcategory="4 ablation",
        ),
        cost_figure=report(
            "results/{scene}/stats/error_vs_cost.png",
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
        expand("results/{scene}/stats/validation_mse.csv", scene=ABLATION_SCENES),
    output:
        report(
            "results/stats/mse_std_vs_p.png",
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


rule convergence:
    input:
        study=lambda wildcards: [
            f"results/{wildcards.scene}/models/P{p}/r0/model.pt"
            for p in convergence_fractions(config["scenes"][wildcards.scene])
        ],
        study_losses=lambda wildcards: [
            f"results/{wildcards.scene}/models/P{p}/r0/losses.csv"
            for p in convergence_fractions(config["scenes"][wildcards.scene])
        ],
        twice=lambda wildcards: [
            f"results/{wildcards.scene}/convergence/P{p}/snapshots"
            for p in convergence_fractions(config["scenes"][wildcards.scene])
        ],
        twice_losses=lambda wildcards: [
            f"results/{wildcards.scene}/convergence/P{p}/losses.csv"
            for p in convergence_fractions(config["scenes"][wildcards.scene])
        ],
        trainset="results/{scene}/dataset/trainset",
    output:
        convergence="results/{scene}/stats/convergence.csv",
        curve="results/{scene}/stats/error_vs_time.csv",
        figure=report(
            "results/{scene}/stats/error_vs_time.png",
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
        fractions=lambda wildcards: convergence_fractions(
            config["scenes"][wildcards.scene]
        ),
        threads=lambda wildcards: config["scenes"][wildcards.scene]["torch_threads"],
        code=code_digest("convergence.py"),
    script:
        "../scripts/convergence.py"
