"""Rule `realism`: per (real folder, sensor), optics fitted on one half of the real images and the
simulator's image statistics compared with the other half (one table per pair)."""

from pathlib import Path

from threedcal.logs import stage_log
from threedcal.sim.fit import realism_report

with stage_log(snakemake.log[0]):
    texts = [
        realism_report(
            real,
            sensor,
            snakemake.params.seed,
            split_seed=snakemake.params.split_seed,
            gel_mechanics=mechanics,
        )[0]
        for real, sensor, mechanics in snakemake.params.sets
    ]
    Path(snakemake.output.table).write_text("\n".join(texts))
