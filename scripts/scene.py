"""Rule `scene`: write results/{scene}/scene.json."""

from threedcal.logs import stage_log
from threedcal.study.paths import write_scene_record

with stage_log(snakemake.log[0]):
    write_scene_record(snakemake.wildcards.scene, snakemake.params.scene, snakemake.output[0])
