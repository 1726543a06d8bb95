"""Rule `reskin_train`: split a ReSkin store by coordinate and train the MLP → model.pt, losses, splits."""

from threedcal.collect.store_read import collected_store
from threedcal.logs import stage_log
from threedcal.study.reskin_stages import reskin_train_stage

with stage_log(snakemake.log[0]):
    reskin_train_stage(
        collected_store(snakemake.input.collected)[0],
        snakemake.params.settings,
        seed=snakemake.params.seed,
        torch_threads=snakemake.params.torch_threads,
        model_path=snakemake.output.model,
        losses_path=snakemake.output.losses,
        splits_path=snakemake.output.splits,
    )
