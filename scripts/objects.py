"""Rule `objects`: every model's depth of the pressed test objects, scored under both protocols."""

from pathlib import Path

import torch

from threedcal.evaluate.pressing import evaluate_objects
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.scene["torch_threads"])
    models = {p: snakemake.input[f"P{p}"] for p in snakemake.params.fractions}
    evaluate_objects(
        snakemake.params.scene,
        models,
        Path(snakemake.input.frames).parent,
        snakemake.input.registration,
        Path(snakemake.output.errors).parent,
    )
