"""Rule `sim2real_pretrain`: the scene's model preset trained on the simulated presses."""

from threedcal.evaluate.sim2real import pretrain
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    pretrain(
        snakemake.input.simset,
        snakemake.params.model,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.model.rsplit("/", 1)[0],
    )
