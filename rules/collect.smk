# Stage `collect`: probe the plan on the (simulated or real) printer into results/{scene}/raw.zarr.
# The store is filled under results/{scene}/.partial/ (not a declared output, so a failed job never
# deletes captured frames) and moved into place when complete; rerunning resumes. The finished
# store is protected: Snakemake refuses to overwrite it.


# The printer is attached to the machine that runs Snakemake: collection is never submitted to a cluster.
localrules:
    collect,


rule collect:
    output:
        store=protected(directory("results/{scene}/raw.zarr")),
        summary="results/{scene}/collect/summary.json",
        coverage=report(
            "results/{scene}/collect/coverage.png",
            caption="../workflow/report/collect_coverage.rst",
            category="{scene}",
            subcategory="1 collection",
        ),
        mosaic=report(
            "results/{scene}/collect/frames.png",
            caption="../workflow/report/collect_frames.rst",
            category="{scene}",
            subcategory="1 collection",
        ),
        truth="results/{scene}/collect/bench_truth.json",
    log:
        "results/{scene}/logs/collect.log",
    benchmark:
        "results/{scene}/benchmarks/collect.tsv"
    wildcard_constraints:
        scene="|".join(COLLECTED_SCENES) or "(?!)",  # "(?!)" matches nothing
    conda:
        CONDA_ENV
    resources:
        printer=1,
    params:
        scene=lambda wildcards: stage_config(
            config["scenes"][wildcards.scene], "collect"
        ),
        staging=lambda wildcards: f"results/{wildcards.scene}/.partial/raw.zarr",
        code=source_digest("collect", "sim", "hardware"),
    script:
        "../scripts/collect.py"
