"""Rule `realism`: per (real folder, sensor), optics fitted on one half of the real images and the
simulator's image statistics compared with the other half (one table per pair), and the 2-D halo
comparison of every pair (its table lines, a CSV and a figure)."""

from pathlib import Path

from threedcal.logs import stage_log
from threedcal.realism import halo2d
from threedcal.realism.folder import realism_run

with stage_log(snakemake.log[0]):
    runs = [
        (
            real,
            sensor,
            realism_run(
                real,
                sensor,
                snakemake.params.seed,
                split_seed=snakemake.params.split_seed,
                gel_mechanics=mechanics,
            ),
        )
        for real, sensor, mechanics in snakemake.params.sets
    ]
    Path(snakemake.output.table).write_text("\n".join(run.text for *_, run in runs))
    halos = [(real, sensor, run.halo) for real, sensor, run in runs]
    halo2d.write_csv(halos, snakemake.output.halo_csv)
    halo2d.draw(halos, snakemake.output.halo_png)
