"""Rule `object_presses`: the printer presses the test objects (simulated bench or a real rig)."""

from pathlib import Path

from threedcal.cli import ask_on_console
from threedcal.evaluate.object_presses import press_objects
from threedcal.logs import stage_log
from threedcal.study.pressing import objects_setup

with stage_log(snakemake.log[0]) as log:
    summary = press_objects(
        objects_setup(snakemake.params.scene, f"scenes.{snakemake.wildcards.scene}"),
        snakemake.input.registration,
        Path(snakemake.output.frames).parent,
        name=snakemake.wildcards.scene,
        ask=ask_on_console,  # a real rig asks for each object to be mounted
    )
    log.info("object presses: %s", summary)
