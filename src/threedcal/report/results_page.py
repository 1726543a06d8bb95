"""docs/results.md: the results page, written from a finished study's `results/` folder alone.

`threedcal report results-page` (and `make results-page`) call `write_results_page`. The scenes are
read from their own records (`results/{scene}/scene.json`, in the order of `environment.json`), so
the page needs no config and says only what that study ran. Every table says which protocol made
its figures and whether the simulator made both the training and the test frames: in a column, or,
where every row has the same value, in one line above the table (`DESCRIPTIVE` columns only,
threedcal.report.sections.markdown).

Provenance is the threedcal version, the host and the date of the last job, all from the study's
own files; no commit hash (the docs carry hashes only in the changelog).

A page section exists when some scene asks for it (its recorded config), whatever its files hold;
a missing file leaves a row that says so. So the page's layout (`page_layout`: headings and table
columns) depends on the scenes and on which descriptive columns are the same on every row, and
tests/report/test_results_page.py compares the committed page's layout with the generator's.
"""

from __future__ import annotations

from pathlib import Path

from threedcal.errors import ConfigError
from threedcal.report.sections.ablation import ablation_section
from threedcal.report.sections.convergence import convergence_section
from threedcal.report.sections.host import provenance_lines
from threedcal.report.sections.inference import inference_section
from threedcal.report.sections.integrators import integrators_section
from threedcal.report.sections.markdown import SIM_COLUMN
from threedcal.report.sections.objects import objects_section
from threedcal.report.sections.quick import quick_section
from threedcal.report.sections.real import real_check_section, real_section
from threedcal.report.sections.records import load_scenes, scenes_section
from threedcal.report.sections.reskin import reskin_section
from threedcal.report.sections.times import time_section

TITLE = "Results of the default study"


def reading_lines() -> list[str]:
    return [
        "Each table names its protocol and says, in a column or (where every row agrees) in a "
        f"line above it, whether the *{SIM_COLUMN}*. Brackets: 95 % intervals unless said "
        "otherwise. Files: [outputs](reference/outputs.md).",
        "",
    ]


def results_page(results: str | Path, *, title: str = TITLE) -> str:
    """The page's Markdown."""
    results = Path(results)
    scenes = load_scenes(results)
    lines = [
        f"# {title}",
        "",
        *provenance_lines(results),
        *reading_lines(),
        *scenes_section(scenes),
        *objects_section(scenes, results),
        *quick_section(scenes, results),
        *ablation_section(scenes, results),
        *convergence_section(scenes, results),
        *real_section(scenes, results),
        *real_check_section(results),
        *reskin_section(scenes, results),
        *inference_section(scenes, results),
        *integrators_section(results),
        *time_section(results),
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_results_page(results: str | Path, out: str | Path, *, title: str = TITLE) -> str:
    results = Path(results)
    if not load_scenes(results):
        raise ConfigError(
            f"{results}: no scene records (*/scene.json): not the results folder of a study"
        )
    text = results_page(results, title=title)
    Path(out).write_text(text)
    return text


def page_layout(text: str) -> list[str]:
    """The page's shape, without its figures: every heading and every table's header row."""
    lines = text.splitlines()
    layout = []
    for i, line in enumerate(lines):
        if line.startswith("#"):
            layout.append(line.strip())
        elif (
            line.startswith("|")
            and i + 1 < len(lines)
            and lines[i + 1].startswith("|")
            and "-" in lines[i + 1]
            and set(lines[i + 1].replace("|", "").strip()) <= set("-: ")
        ):
            layout.append(line.strip())
    return layout
