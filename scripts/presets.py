"""Rule `presets`: depth error against inference time of every CPU preset on an imported scene."""

from threedcal.evaluate.presets_study import presets_stage
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    presets_stage(
        snakemake.input.trainset,
        snakemake.params.model,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.params.presets,
        snakemake.output.csv,
        snakemake.output.png,
        scene_model=snakemake.input.get("scene_model"),
    )
