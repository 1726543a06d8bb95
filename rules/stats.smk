# Stage `stats`: per-coordinate validation error of every model of a scene's ablation, the tests
# against P = 80 and the paper's Fig. 3B / 4 figures; the cross-scene spread figure (Fig. 4C).


rule stats:
    input:
        unpack(scene_models),
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
        recommendation="results/{scene}/stats/recommendation.txt",
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
        scene="|".join(ABLATION_SCENES) or "(?!)",  # "(?!)" matches nothing
    conda:
        CONDA_ENV
    params:
        fractions=lambda wildcards: training_fractions(
            config["scenes"][wildcards.scene]
        ),
        summary=lambda wildcards: (
            f"results/{wildcards.scene}/collect/summary.json"
            if wildcards.scene in COLLECTED_SCENES
            else None
        ),
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
