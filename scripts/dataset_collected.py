"""Rule `dataset_collected`: registration, labels, splits and the model-ready set of a collected scene."""

from threedcal.dataset.build import build_collected
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    build_collected(
        snakemake.params.scene,
        snakemake.input.store,
        snakemake.output.trainset,
        snakemake.output.splits,
        snakemake.output.registration,
        snakemake.output.figure,
        truth_path=snakemake.input.truth,
    )
