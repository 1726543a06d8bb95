"""Quick calibration: the stopped model against its unit's full calibration (quick/arms.json) and
where it stopped (quick/stop.json), for the page and for each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.report.sections.markdown import (
    MISSING,
    estimate,
    markdown_table,
    missing_file,
    percent,
    percent_interval,
    read_json,
)
from threedcal.report.sections.records import recorded_config
from threedcal.study.config import has_arms


def quick_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Each compared quick calibration's stopped model against its unit's full calibration
    (arms.json), and its presses from scratch."""
    chosen = [n for n, r in scenes.items() if has_arms(recorded_config(r))]
    if not chosen:
        return []
    rows = []
    for name in chosen:
        path = results / name / "quick" / "arms.json"
        if not path.is_file():
            rows.append([f"`{name}`", missing_file(path, results)] + [MISSING] * 4)
            continue
        arms = read_json(path)
        targets = arms["targets"]
        mse, scratch = targets["validation_mse"], arms.get("scratch_same_round")
        worst = max(
            targets["objects"]["per_object"].items(), key=lambda o: o[1]["interval95_um"][1]
        )
        rows.append(
            [
                f"`{name}` vs `{arms['compare_with']}`",
                f"{arms.get('presses_in_all', arms['presses'])}, {arms['printer_minutes']:.1f}",
                f"{percent(mse['change'])} {percent_interval(*mse['interval95'])} ({mse['verdict']})",
                MISSING
                if scratch is None
                else f"{percent(scratch['change'])} {percent_interval(*scratch['interval95'])}",
                f"{worst[0]} {estimate(worst[1]['difference_um'], *worst[1]['interval95_um'])} "
                f"({targets['objects']['verdict']})",
                f"{targets['presses']['verdict']}, {targets['printer_minutes']['verdict']}",
            ]
        )
    return [
        "## Quick calibration",
        "",
        "The stopped model against the unit's P = 80 models; targets: "
        "+10 %, +10 µm (printer protocol), 50 presses (touch search included), 5 minutes. "
        "One unit a sensor; over units: `make quick-study` "
        "([statistics](explanation/statistics.md#a-quick-calibration-against-a-full-one)).",
        "",
        *markdown_table(
            ["scene", "presses, min", "MSE vs full", "scratch", "worst Δ Type 2 µm", "budget"],
            rows,
        ),
        "",
    ]


def quick_facts(root: Path) -> list[tuple[str, str]]:
    """The summary's rows of a quick scene: where its stop rule stopped, and its verdicts against
    the compared scene's P = 80."""
    facts = []
    quick = read_json(root / "quick" / "stop.json")
    if quick:
        facts.append(
            (
                "quick calibration",
                f"stopped ({quick['stopped']}) after {quick['presses']} presses in "
                f"{quick['round']} rounds ({quick.get('presses_in_all', quick['presses'])} with the "
                f"touch search and registration), {quick['printer_minutes']:.1f} printer minutes",
            )
        )
    arms = read_json(root / "quick" / "arms.json")
    if arms:
        facts.append(
            (
                f"quick against {arms['compare_with']}'s P = 80 (quick/arms.json)",
                "; ".join(target["line"] for target in arms["targets"].values()),
            )
        )
    return facts
