"""Rule `cv_train`: one cross-validation fold's model, trained on the other folds' images."""

from threedcal.logs import stage_log
from threedcal.model.crossval import train_fold

with stage_log(snakemake.log[0]):
    train_fold(
        snakemake.input.trainset,
        snakemake.input.folds,
        int(snakemake.wildcards.fold),
        snakemake.params.model,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.model.rsplit("/", 1)[0],
    )
