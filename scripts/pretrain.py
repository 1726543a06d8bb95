"""Rule `pretrain`: one sensor's pretrained weights and their provenance."""

from pathlib import Path

from threedcal.logs import stage_log
from threedcal.model.pretrained import pretrain_shipped_weights

with stage_log(snakemake.log[0]):
    pretrain_shipped_weights(
        snakemake.wildcards.sensor,
        snakemake.params.pretraining,
        Path(snakemake.output.model).parent,
        code_digest=snakemake.params.code,
    )
