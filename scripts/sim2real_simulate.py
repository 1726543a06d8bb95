"""Rule `sim2real_simulate`: simulated ball presses of the scene's sensor profile at the real set's
image size, px/mm and ball radius, labelled exactly (a model-ready set)."""

from threedcal.logs import stage_log
from threedcal.model.sim2real import write_simulated

with stage_log(snakemake.log[0]):
    write_simulated(
        snakemake.input.trainset,
        snakemake.params.profile,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.output[0],
    )
