"""Rule `sim2real_eval`: held-out real-image errors of the sim+real, real-only (and shipped+real)
models against k (errors.csv, images.csv, error_vs_k.png)."""

from threedcal.evaluate.sim2real_scores import sim2real_eval
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    models = {
        name: list(snakemake.input[name])
        for name in snakemake.input.keys()
        if name not in ("trainset", "folds", "scene")
    }
    sim2real_eval(
        snakemake.input.trainset,
        snakemake.input.folds,
        models,
        list(snakemake.input.scene),
        snakemake.params.sim_to_real,
        snakemake.params.cv,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.errors,
        snakemake.output.figure,
        images_path=snakemake.output.images,
    )
