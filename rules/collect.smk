# Stage `collect`: probe the plan on the (simulated or real) printer into results/{scene}/raw.zarr.
# The store is a source, not an output: Snakemake deletes the outputs of a job it reruns (changed
# params, --forcerun, --rerun-incomplete), so it never learns the store's name. The library fills it
# under results/{scene}/.partial/ (a killed run resumes there, with the same settings only) and moves
# it into place when complete. A rerun with a finished store writes summary.json again and leaves
# the store alone, or stops naming the settings that changed (see docs/explanation/reliability.md).
# Downstream rules read summary.json, which names the store and the digest of its frame settings.


# The printer is attached to the machine that runs Snakemake: collection is never submitted to a cluster.
localrules:
    collect,


rule collect:
    output:
        summary=COLLECT["summary"],
        coverage=report(
            COLLECT["coverage"],
            caption="../workflow/report/collect_coverage.rst",
            category="{scene}",
            subcategory="1 collection",
        ),
        mosaic=report(
            COLLECT["mosaic"],
            caption="../workflow/report/collect_frames.rst",
            category="{scene}",
            subcategory="1 collection",
        ),
        truth=BENCH_TRUTH,
    log:
        "results/{scene}/logs/collect.log",
    benchmark:
        "results/{scene}/benchmarks/collect.tsv"
    wildcard_constraints:
        scene=one_of(COLLECTED_SCENES),
    conda:
        CONDA_ENV
    resources:
        printer=printer_held,
    params:
        # Canonical JSON (sorted keys): reordering keys in the config never reruns anything.
        scene=lambda wildcards: canonical_json(
            stage_config(config["scenes"][wildcards.scene], "collect")
        ),
        store=lambda wildcards: target(STORE, wildcards.scene),
        staging=lambda wildcards: target(STAGING_STORE, wildcards.scene),
        code=code_digest("collect.py"),
    script:
        "../scripts/collect.py"
