"""results/summary.md: every scene's headline numbers on one page, read from the stage outputs."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.report.sections.ablation import ablation_lines, recommendation_facts
from threedcal.report.sections.collection import collection_facts
from threedcal.report.sections.host import environment_lines
from threedcal.report.sections.inference import inference_facts
from threedcal.report.sections.integrators import integrator_lines
from threedcal.report.sections.markdown import fact_table
from threedcal.report.sections.objects import object_lines
from threedcal.report.sections.quick import quick_facts
from threedcal.report.sections.real import ball_facts
from threedcal.report.sections.reskin import reskin_facts
from threedcal.report.sections.sim2real import sim2real_lines
from threedcal.report.sections.times import time_lines
from threedcal.study.config import is_imported
from threedcal.study.paths import has_sim2real


def scene_section(name: str, scene: Mapping, results: Path) -> list[str]:
    """A scene's facts in one table, then its sim-to-real, ablation and test-object tables."""
    root = results / name
    lines = [f"## {name}", "", f"{scene.get('description', '')}".strip(), ""]
    facts = [
        ("sensor", str(scene["sensor"])),
        *collection_facts(root),
        *quick_facts(root),
        *recommendation_facts(root / "stats"),
        *inference_facts(root),
        *ball_facts(root),
        *reskin_facts(root),
    ]
    lines += fact_table(facts) + [""]
    sim2real = root / "sim2real" / "errors.csv"
    if has_sim2real(scene) and sim2real.is_file():
        lines += sim2real_lines(pd.read_csv(sim2real, dtype={"k": str, "fold": str}))
    lines += ablation_lines(root / "stats")
    errors = root / "objects" / "errors.csv"
    if errors.is_file():
        lines += object_lines(pd.read_csv(errors))
    return lines


def write_study_summary(config: Mapping, results: str | Path, out: str | Path) -> str:
    """Write results/summary.md for the config's scenes and return its text."""
    results = Path(results)
    lines = ["# threedcal study summary", ""]
    scenes = config["scenes"]
    # Real frames first: what a user's sensor will meet outranks what the simulator trains and tests.
    real = [name for name, scene in scenes.items() if is_imported(scene)]
    if real:
        lines += [
            f"Scenes on real sensor frames first ({', '.join(real)}); every other scene is "
            "trained and tested in the simulator.",
            "",
        ]
    for name in real + [name for name in scenes if name not in real]:
        lines += scene_section(name, scenes[name], results)
    lines += integrator_lines(results)
    lines += time_lines(results)
    lines += environment_lines(results)
    text = "\n".join(lines)
    Path(out).write_text(text)
    return text
