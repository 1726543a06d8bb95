"""Rule `sim2real_pretrain`: the scene's model preset trained on the simulated presses."""

from threedcal.logs import stage_log
from threedcal.model.sim2real import pretrain

with stage_log(snakemake.log[0]):
    pretrain(
        snakemake.input.simset,
        snakemake.params.model,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.model.rsplit("/", 1)[0],
    )
