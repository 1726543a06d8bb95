"""Rule `presets`: depth error against inference time of every CPU preset on an imported scene."""

from threedcal.logs import stage_log
from threedcal.study.presets_stage import presets_stage

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
