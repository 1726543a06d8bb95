"""Rule `environment`: versions, threads, seeds and hardware of this run."""

import json

from threedcal.logs import stage_log
from threedcal.report.environment import environment

with stage_log(snakemake.log[0]):
    record = environment(snakemake.params.config)
    with open(snakemake.output[0], "w") as f:
        json.dump(record, f, indent=2)
        f.write("\n")
