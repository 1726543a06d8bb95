"""Rule `real_check`: the shipped weights on every real set of the config's `real_check` block."""

from pathlib import Path

from threedcal.evaluate.real_check import check_sets
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    settings = snakemake.params.settings
    table, frames = check_sets(
        settings["sets"],
        Path(snakemake.output.table).parent / "finetuned",
        settings["finetune_steps"],
        settings["finetune_lr"],
        snakemake.params.seed,
        snakemake.threads,
    )
    table.to_csv(snakemake.output.table, index=False, float_format="%.4g")
    frames.to_csv(snakemake.output.frames, index=False, float_format="%.4g")
