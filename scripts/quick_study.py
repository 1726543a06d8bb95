"""Rule `quick_study`: each unit's stopped quick model against its full calibration; the claim over units."""

import torch

from threedcal.collect.store_read import collected_store
from threedcal.logs import stage_log
from threedcal.study.quick_study import UnitPair, study_stage
from threedcal.study.scene import dataset_settings

with stage_log(snakemake.log[0]):
    torch.set_num_threads(snakemake.threads)
    inputs = snakemake.input
    pairs = [
        UnitPair(
            quick_scene=quick,
            full_scene=full,
            sensor=snakemake.params.sensors[quick],
            unit=snakemake.params.units[quick],
            quick_model=inputs[f"{quick}_model"],
            stop=inputs[f"{quick}_stop"],
            full_models=list(inputs[f"{full}_models"]),
            trainset=inputs[f"{full}_trainset"],
            splits=inputs[f"{full}_splits"],
            truth=inputs.get(f"{full}_truth"),
            store=collected_store(inputs[f"{full}_collected"])[0]
            if f"{full}_collected" in inputs.keys()
            else None,
            dataset=dataset_settings(snakemake.params.datasets[full]),
        )
        for quick, full in snakemake.params.pairs
    ]
    study_stage(pairs, dict(snakemake.output.items()))
