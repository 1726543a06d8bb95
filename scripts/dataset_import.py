"""Rule `dataset_import`: an imported folder → splits.csv and the model-ready set."""

from threedcal.logs import stage_log
from threedcal.study.dataset_stage import import_stage

with stage_log(snakemake.log[0]):
    import_stage(
        snakemake.params.scene,
        snakemake.output.trainset,
        snakemake.output.splits,
    )
