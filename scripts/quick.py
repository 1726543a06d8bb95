"""Rule `quick`: collect a unit round by round until the stop rule; model.pt, rounds.csv, stop.json."""

import json

import torch

from threedcal.cli import ask_on_console
from threedcal.logs import stage_log
from threedcal.study.quick_loop import quick_stage

scene = json.loads(snakemake.params.scene)
with stage_log(snakemake.log[0]):
    # every round's scoring and training at the config's threads: a replay then decides alike
    torch.set_num_threads(scene["torch_threads"])
    quick_stage(
        snakemake.wildcards.scene,
        scene,
        store=snakemake.params.store,
        staging=snakemake.params.staging,
        model=snakemake.output.model,
        rounds=snakemake.output.rounds,
        stop=snakemake.output.stop,
        work=snakemake.output.work,
        ask=ask_on_console,  # a real rig asks for the probe to be attached
    )
