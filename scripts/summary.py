"""Rule `summary`: results/summary.md, every scene's headline numbers on one page."""

from threedcal.logs import stage_log
from threedcal.report.summary import write_study_summary

with stage_log(snakemake.log[0]):
    write_study_summary(snakemake.params.config, "results", snakemake.output[0])
