"""Rule `convergence`: every fraction's error against training time, and the change at twice the budget."""

from collections import defaultdict

import pandas as pd
import torch

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation import spatial_blocks
from threedcal.evaluate.convergence import (
    convergence_table,
    curve_figure,
    error_vs_time_table,
    snapshot_scores,
)
from threedcal.evaluate.validation import scoring_disc_mm
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.params.threads)
    inputs, steps = snakemake.input, int(snakemake.params.steps)
    keys = [tuple(key) for key in snakemake.params.models]
    trainset = TrainingSet.load(inputs.trainset)
    per_model = len(inputs.snapshots) // len(keys)
    snapshots = defaultdict(list)
    for index, path in enumerate(inputs.snapshots):
        snapshots[keys[index // per_model]].append(path)
    budget = (steps, pd.read_csv(inputs.budget_mse))
    twice = (2 * steps, pd.read_csv(inputs.twice_mse))
    curve = error_vs_time_table(
        snapshot_scores(snapshots, trainset),
        budget,
        twice,
        dict(zip(keys, inputs.twice_losses, strict=True)),
    )
    curve.to_csv(snakemake.output.curve, index=False, float_format="%.6g")
    blocks = spatial_blocks(budget[1], scoring_disc_mm(trainset))
    table = convergence_table(budget, twice, blocks)
    table.to_csv(snakemake.output.convergence, index=False, float_format="%.6g")
    curve_figure(
        curve,
        steps,
        snakemake.output.figure,
        f"{snakemake.wildcards.scene}: error against training",
    )
