"""Rule `quick_arms`: the quick rounds, the same presses from scratch and the full calibration,
scored on the compared scene's validation coordinates and object presses."""

import json
from pathlib import Path

import torch

from threedcal.logs import stage_log
from threedcal.study.quick_arms import arms_stage

with stage_log(snakemake.log[0]):
    scene = json.loads(snakemake.params.scene)
    torch.set_num_threads(scene["torch_threads"])
    arms_stage(
        snakemake.wildcards.scene,
        scene,
        store=snakemake.params.store,
        rounds=snakemake.input.rounds,
        rounds_dir=snakemake.input.work,
        full_name=snakemake.params.full,
        full_models=list(snakemake.input.full),
        trainset=snakemake.input.trainset,
        splits=snakemake.input.splits,
        collect_summary=snakemake.input.summary,
        objects_scene=snakemake.params.objects,
        pressing_dir=Path(snakemake.input.pressing_frames).parent,
        registration=snakemake.input.registration,
        out=dict(snakemake.output.items()),
    )
