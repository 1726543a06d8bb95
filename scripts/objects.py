"""Rule `objects`: press the test objects on the simulated bench and score the predicted depth."""

import torch

from threedcal.evaluate.pressing import evaluate_objects
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.scene["torch_threads"])
    models = {p: snakemake.input[f"P{p}"] for p in snakemake.params.fractions}
    evaluate_objects(snakemake.params.scene, models, snakemake.output.errors.rsplit("/", 1)[0])
