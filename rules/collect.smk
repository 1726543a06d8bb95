# Stage `collect`: probe the plan on the (simulated or real) printer into results/{scene}/raw.zarr.
# The store is a source, not an output: Snakemake deletes the outputs of a job it reruns (changed
# params, --forcerun, --rerun-incomplete), so it never learns the store's name. The library fills it
# under results/{scene}/.partial/ (a killed run resumes there, with the same settings only) and moves
# it into place when complete. A rerun with a finished store writes summary.json again and leaves
# the store alone, or stops naming the settings that changed (see docs/reliability.md).
# Downstream rules read summary.json, which names the store and the digest of its frame settings.


# The printer is attached to the machine that runs Snakemake: collection is never submitted to a cluster.
localrules:
    collect,


rule collect:
    output:
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
        scene=one_of(COLLECTED_SCENES),
    conda:
        CONDA_ENV
    resources:
        printer=1,
    params:
        # Canonical JSON (sorted keys): reordering keys in the config never reruns anything.
        scene=lambda wildcards: canonical_json(
            stage_config(config["scenes"][wildcards.scene], "collect")
        ),
        store=lambda wildcards: f"results/{wildcards.scene}/raw.zarr",
        staging=lambda wildcards: f"results/{wildcards.scene}/.partial/raw.zarr",
        code=code_digest("collect.py"),
    script:
        "../scripts/collect.py"
