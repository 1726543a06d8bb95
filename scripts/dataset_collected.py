"""Rule `dataset_collected`: registration, labels, splits and the model-ready set of a collected scene."""

from threedcal.collect.store_read import collected_store
from threedcal.dataset.build import build_collected
from threedcal.logs import stage_log
from threedcal.study.scene import dataset_settings

with stage_log(snakemake.log[0]):
    store, digest = collected_store(snakemake.input.collected)
    build_collected(
        dataset_settings(snakemake.params.scene),
        store,
        snakemake.output.trainset,
        snakemake.output.splits,
        snakemake.output.registration,
        snakemake.output.figure,
        truth_path=snakemake.input.truth,
        expect_digest=digest,
    )
