"""Rule `train_ablation`: every replicate of fraction P, trained together for the ablation's steps."""

from pathlib import Path

from threedcal.dataset.trainset import TrainingSet
from threedcal.logs import stage_log
from threedcal.model.contact_guard import check_calibration_presses
from threedcal.model.lockstep import Member, train_lockstep
from threedcal.study.training import train_settings

with stage_log(snakemake.log[0]):
    percent, ablation = int(snakemake.wildcards.p), snakemake.params.ablation
    members = [
        Member(percent, r, Path(model).parent) for r, model in enumerate(snakemake.output.models)
    ]
    train_lockstep(
        snakemake.input.trainset,
        members,
        train_settings(snakemake.params.settings),
        ablation["steps"],
        twice=ablation["convergence"],
        batching=ablation["batching"],
        resume=snakemake.params.resume,
    )
    # the calibration's own presses: a model reading more than the probe can touch is named
    trainset = TrainingSet.load(snakemake.input.trainset)
    for r, model in enumerate(snakemake.output.models):
        check_calibration_presses(
            model, trainset, f"scene {snakemake.wildcards.scene}, P={percent} r{r}"
        )
