"""Rule `convergence`: the study's models against the same training at twice the budget."""

import torch

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.convergence import convergence_table, curve_figure, curve_table
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.threads)
    fractions = snakemake.params.fractions
    inputs = snakemake.input
    curve = curve_table(
        dict(zip(fractions, zip(inputs.study, inputs.study_losses, strict=True), strict=True)),
        dict(zip(fractions, zip(inputs.twice, inputs.twice_losses, strict=True), strict=True)),
        TrainingSet.load(inputs.trainset),
    )
    curve.to_csv(snakemake.output.curve, index=False, float_format="%.6g")
    convergence_table(curve).to_csv(snakemake.output.convergence, index=False, float_format="%.6g")
    curve_figure(
        curve, snakemake.output.figure, f"{snakemake.wildcards.scene}: error against training time"
    )
