"""Rule `quick`: collect a unit round by round until the stop rule; model.pt, rounds.csv, stop.json."""

import json

from threedcal.cli import ask_on_console
from threedcal.logs import stage_log
from threedcal.quick.loop import quick_stage

with stage_log(snakemake.log[0]):
    quick_stage(
        snakemake.wildcards.scene,
        json.loads(snakemake.params.scene),
        store=snakemake.params.store,
        staging=snakemake.params.staging,
        model=snakemake.output.model,
        rounds=snakemake.output.rounds,
        stop=snakemake.output.stop,
        work=snakemake.output.work,
        ask=ask_on_console,  # a real rig asks for the probe to be attached
    )
