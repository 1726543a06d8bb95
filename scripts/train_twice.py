"""Rule `train_twice`: replicate 0 of fraction P trained with twice its stopping rule's budget."""

from threedcal.logs import stage_log
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.train import TrainSettings, train

with stage_log(snakemake.log[0]):
    study = read_checkpoint(snakemake.input.study)["training"]
    train(
        snakemake.input.trainset,
        snakemake.output.model.rsplit("/", 1)[0],
        int(snakemake.wildcards.p),
        TrainSettings.from_scene(snakemake.params.settings),
        budget_scale=2.0,
        min_steps=2 * int(study.get("steps", 0)),
        snapshot_every=1,
    )
