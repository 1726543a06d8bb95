"""Rule `stats`: validation MSE per coordinate, significance tests, recommendation and figures."""

from threedcal.evaluate.validation import stats_stage
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]) as log:
    fractions = snakemake.params.fractions
    line = stats_stage(
        snakemake.wildcards.scene,
        {p: snakemake.input[f"P{p}"] for p in fractions},
        dict(zip(fractions, snakemake.input.losses, strict=True)),
        snakemake.input.trainset,
        snakemake.input.splits,
        snakemake.params.summary,
        dict(snakemake.output.items()),
    )
    log.info(line)
