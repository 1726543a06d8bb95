"""Rule `stats_twice`: the ablation's tests, learning curve and recommendation at twice the budget."""

from threedcal.logs import stage_log
from threedcal.study.stats_stage import twice_stage

with stage_log(snakemake.log[0]) as log:
    keys = [tuple(key) for key in snakemake.params.models]
    line = twice_stage(
        snakemake.wildcards.scene,
        {(p, r): snakemake.input[f"P{p}_r{r}"] for p, r in keys},
        snakemake.input.trainset,
        snakemake.input.splits,
        snakemake.params.settings,
        snakemake.params.seed,
        dict(snakemake.output.items()),
    )
    log.info("at twice the budget: %s", line)
