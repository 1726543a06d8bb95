"""Rule `cv_train`: one cross-validation fold's model of every method, trained on the other folds'
images."""

from pathlib import Path

from threedcal.evaluate.crossval import train_fold_methods
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    methods = snakemake.params.methods  # in the order of the models' outputs
    train_fold_methods(
        snakemake.input.trainset,
        snakemake.input.folds,
        int(snakemake.wildcards.fold),
        methods,
        snakemake.params.seed,
        snakemake.params.threads,
        {m: Path(p).parent for m, p in zip(methods, snakemake.output.models, strict=True)},
    )
