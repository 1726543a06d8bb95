"""Rule `sim2real_simulate`: one group of test folds' simulated ball presses at the real set's image
size, px/mm and ball radius, labelled exactly (a model-ready set), with the sensor profile's optics
fitted to the images outside those folds (`sim_to_real.profile: fitted`) or as they are (`as_is`)."""

from threedcal.evaluate.sim2real_settings import parse_group
from threedcal.evaluate.sim2real_simulate import write_simulated
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    write_simulated(
        snakemake.input.trainset,
        snakemake.params.profile,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.output[0],
        folds_path=snakemake.input.folds,
        held_out=parse_group(snakemake.wildcards.folds),
    )
