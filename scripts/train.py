"""Rule `train`: replicate r of fraction P → model.pt, losses.csv, losses.png."""

from threedcal.logs import stage_log
from threedcal.model.contact_guard import check_calibration_presses
from threedcal.model.train import train
from threedcal.study.training import train_settings

with stage_log(snakemake.log[0]):
    settings = train_settings(snakemake.params.settings)
    train(
        snakemake.input.trainset,
        snakemake.output.model.rsplit("/", 1)[0],
        int(snakemake.wildcards.p),
        settings,
        replicate=int(snakemake.wildcards.r),
    )
    # the calibration's own presses: a model reading more than the probe can touch is named
    check_calibration_presses(
        snakemake.output.model,
        snakemake.input.trainset,
        f"scene {snakemake.wildcards.scene}, P={snakemake.wildcards.p} r{snakemake.wildcards.r}",
    )
