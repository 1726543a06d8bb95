# Stage `integration_study`: error against run time of every depth integrator on analytic scenes.


rule integration_study:
    output:
        csv="results/integration/error_vs_time.csv",
        png=report(
            "results/integration/error_vs_time.png",
            caption="../workflow/report/integration_study.rst",
            category="Depth integration",
        ),
        reading="results/integration/reading.md",
    log:
        "results/integration/logs/integration_study.log",
    benchmark:
        "results/benchmarks/integration_study.tsv"
    conda:
        CONDA_ENV
    params:
        study=config["integration_study"],
        seed=config["seed"],
        code=code_digest("integration_study.py"),
    script:
        "../scripts/integration_study.py"
