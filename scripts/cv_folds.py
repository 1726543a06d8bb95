"""Rule `cv_folds`: the grouped k-fold assignment of an imported scene's images (folds.csv)."""

from threedcal.dataset.folds import write_folds
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    write_folds(
        snakemake.input.trainset,
        snakemake.params.cv,
        snakemake.params.seed,
        snakemake.output[0],
        where=snakemake.params.where,
    )
