"""Rule `train_ablation`: every replicate of fraction P, trained together for the ablation's steps."""

from pathlib import Path

from threedcal.logs import stage_log
from threedcal.model.lockstep import Member, train_lockstep
from threedcal.model.train import TrainSettings

with stage_log(snakemake.log[0]):
    percent, ablation = int(snakemake.wildcards.p), snakemake.params.ablation
    members = [
        Member(percent, r, Path(model).parent) for r, model in enumerate(snakemake.output.models)
    ]
    train_lockstep(
        snakemake.input.trainset,
        members,
        TrainSettings.from_scene(snakemake.params.settings),
        ablation["steps"],
        twice=ablation["convergence"],
        batching=ablation["batching"],
        resume=snakemake.params.resume,
    )
