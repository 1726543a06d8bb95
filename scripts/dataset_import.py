"""Rule `dataset_import`: an imported folder → splits.csv and the model-ready set."""

from threedcal.dataset.build import build_imported
from threedcal.logs import stage_log
from threedcal.study.scene import dataset_settings

with stage_log(snakemake.log[0]):
    build_imported(
        snakemake.params.scene["import"]["format"],
        snakemake.params.scene["import"]["path"],
        dataset_settings(snakemake.params.scene),
        snakemake.output.trainset,
        snakemake.output.splits,
    )
