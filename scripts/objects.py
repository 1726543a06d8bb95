"""Rule `objects`: every model's depth of the pressed test objects (every P, every replicate),
scored under both protocols."""

from pathlib import Path

import torch

from threedcal.evaluate.object_scores import evaluate_objects
from threedcal.logs import stage_log
from threedcal.study.pressing import objects_setup

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.scene["torch_threads"])
    models = {}  # P -> its replicates' checkpoints, in replicate order
    for p, r in sorted(snakemake.params.models):
        models.setdefault(p, []).append(snakemake.input[f"P{p}_r{r}"])
    evaluate_objects(
        objects_setup(snakemake.params.scene),
        models,
        Path(snakemake.input.frames).parent,
        snakemake.input.registration,
        Path(snakemake.output.errors).parent,
    )
