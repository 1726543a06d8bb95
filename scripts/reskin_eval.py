"""Rule `reskin_eval`: localisation and depth errors on the held-out coordinates → json + figure."""

from threedcal.collect.store_read import collected_store
from threedcal.logs import stage_log
from threedcal.profiles import load_profile
from threedcal.study.reskin_stages import reskin_eval_stage

with stage_log(snakemake.log[0]):
    reskin_eval_stage(
        collected_store(snakemake.input.collected)[0],
        snakemake.input.model,
        snakemake.input.splits,
        load_profile("sensor", snakemake.params.sensor),
        out_json=snakemake.output.metrics,
        out_figure=snakemake.output.figure,
        title=f"{snakemake.wildcards.scene}: ReSkin contact localisation on held-out coordinates",
    )
