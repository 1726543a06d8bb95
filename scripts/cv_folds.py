"""Rule `cv_folds`: the grouped k-fold assignment of an imported scene's images (folds.csv)."""

from threedcal.logs import stage_log
from threedcal.model.folds import write_folds

with stage_log(snakemake.log[0]):
    write_folds(
        snakemake.input.trainset,
        snakemake.params.cv,
        snakemake.params.seed,
        snakemake.output[0],
        where=snakemake.params.where,
    )
