"""Rule `realism`: the simulator's image statistics against real sensor frames (table)."""

from threedcal.logs import stage_log
from threedcal.sim.realism import realism_report

with stage_log(snakemake.log[0]):
    realism_report(
        snakemake.params.real,
        snakemake.params.sensor,
        snakemake.params.seed,
        snakemake.output.table,
    )
