"""Rule `object_presses`: the printer presses the test objects (simulated bench or a real rig)."""

from pathlib import Path

from threedcal.evaluate.pressing import press_objects
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]) as log:
    summary = press_objects(
        snakemake.params.scene,
        snakemake.input.registration,
        Path(snakemake.output.frames).parent,
        name=snakemake.wildcards.scene,
    )
    log.info("object presses: %s", summary)
