# Stage `integration_study`: error against run time of every depth integrator on analytic scenes.


rule integration_study:
    output:
        csv=INTEGRATION_STUDY["csv"],
        png=report(
            INTEGRATION_STUDY["png"],
            caption="../workflow/report/integration_study.rst",
            category="Depth integration",
        ),
        reading=INTEGRATION_STUDY["reading"],
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
