"""Rule `stats`: validation MSE per coordinate, the ablation's tests, recommendation, power and figures."""

from threedcal.logs import stage_log
from threedcal.study.stats_stage import stats_stage

with stage_log(snakemake.log[0]) as log:
    keys = [tuple(key) for key in snakemake.params.models]
    line = stats_stage(
        snakemake.wildcards.scene,
        {(p, r): snakemake.input[f"P{p}_r{r}"] for p, r in keys},
        dict(zip(keys, snakemake.input.losses, strict=True)),
        snakemake.input.trainset,
        snakemake.input.splits,
        snakemake.input.get("summary"),
        snakemake.params.settings,
        snakemake.params.seed,
        dict(snakemake.output.items()),
    )
    log.info(line)
