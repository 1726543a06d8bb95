"""The scenes as a study recorded them (results/{scene}/scene.json: config, profiles, software),
so that the results page needs no config and says only what that study ran."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    SIMULATED,
    markdown_table,
    read_json,
)
from threedcal.rig import is_magnetic
from threedcal.study.config import is_imported


def load_scenes(results: str | Path) -> dict[str, dict]:
    """{scene: its record (scene.json: config, profiles, software)}, in the study's order."""
    results = Path(results)
    records = {path.parent.name: read_json(path) for path in sorted(results.glob("*/scene.json"))}
    environment = read_json(results / "environment.json") or {}
    order = [name for name in environment.get("scene_seeds", {}) if name in records]
    return {name: records[name] for name in order + sorted(set(records) - set(order))}


def recorded_config(record: Mapping) -> dict:
    """The scene's config as the workflow's predicates read it (threedcal.study.paths, .config); a
    record that wrote `import: null` for a scene that imports nothing counts as not imported."""
    config = dict(record.get("config") or {})
    if not config.get("import"):
        config.pop("import", None)
    return config


def recorded_sensor(record: Mapping) -> Mapping:
    """The recorded sensor profile (not looked up again: a profile given by path may not resolve
    where the page is written)."""
    return (record.get("profiles") or {}).get("sensor") or {}


def is_simulated(record: Mapping) -> bool:
    """The simulated bench (`port: sim`) rendered both the frames trained on and those tested."""
    return (
        not is_imported(recorded_config(record))
        and str(recorded_config(record).get("port", "sim")) == "sim"
    )


def frames_of(record: Mapping) -> str:
    """The scenes table's SIM_COLUMN cell: whether the simulator made a scene's frames (a ReSkin's
    readings), and where real ones came from."""
    if is_imported(recorded_config(record)):
        return f"no (real images, `{recorded_config(record)['import'].get('path', 'imported')}`)"
    readings = " (readings)" if is_magnetic(recorded_sensor(record)) else ""
    if is_simulated(record):
        return f"{SIMULATED}{readings}"
    return f"no (real printer and sensor{readings}, port {recorded_config(record).get('port')})"


def simulated_cell(record: Mapping) -> str:
    """The SIM_COLUMN's cell of a scene's own figures."""
    if is_simulated(record):
        return SIMULATED
    return "no (real images)" if is_imported(recorded_config(record)) else "no (real sensor frames)"


def scenes_section(scenes: Mapping[str, dict]) -> list[str]:
    """One row a scene."""
    rows = [
        [
            f"`{name}`",
            str(recorded_config(record).get("sensor", MISSING)),
            str(recorded_config(record).get("printer") or MISSING),
            frames_of(record),
        ]
        for name, record in scenes.items()
    ]
    return [
        "## Scenes",
        "",
        *markdown_table(["scene", "sensor", "printer", SIM_COLUMN], rows),
        "",
    ]
