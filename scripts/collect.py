"""Rule `collect`: probe one scene into its store (a source beside the outputs); summary and figures."""

import json

from threedcal.cli import ask_on_console
from threedcal.logs import stage_log
from threedcal.study.session import collect_stage

with stage_log(snakemake.log[0]):
    collect_stage(
        snakemake.wildcards.scene,
        json.loads(snakemake.params.scene),
        store=snakemake.params.store,
        staging=snakemake.params.staging,
        summary=snakemake.output.summary,
        coverage=snakemake.output.coverage,
        mosaic=snakemake.output.mosaic,
        truth=snakemake.output.truth,
        ask=ask_on_console,  # a real rig asks for the probe to be attached
    )
