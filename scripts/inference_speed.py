"""Rule `inference_speed`: depth frames/s of a scene's P = 80 model on CPU."""

import torch

from threedcal.logs import stage_log
from threedcal.report.inference_speed import measure_inference

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.threads)
    measure_inference(snakemake.input.model, snakemake.input.trainset, snakemake.output[0])
