"""Rule `integration_study`: results/integration/error_vs_time.{csv,png} and reading.md."""

from threedcal.depth.study import run_study, write_study
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    study = snakemake.params.study
    table = run_study(
        sizes=study["sizes"],
        scenarios=study["scenarios"],
        methods=study["methods"],
        dtypes=study["dtypes"],
        repeats=study["repeats"],
        time_budget_s=study["time_budget_s"],
        seed=snakemake.params.seed,
        workers=study["workers"],
        method_max_pixels=study["method_max_pixels"],
    )
    write_study(table, snakemake.output.csv, snakemake.output.png, snakemake.output.reading)
