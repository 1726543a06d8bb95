"""Rule `stats_overview`: the spread of validation MSE against P, every ablation scene on one axis."""

import pandas as pd

from threedcal.evaluate.validation import std_figure
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    tables = {
        scene: pd.read_csv(path)
        for scene, path in zip(snakemake.params.scenes, snakemake.input, strict=True)
    }
    std_figure(tables, snakemake.output[0])
