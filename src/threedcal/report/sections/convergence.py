"""Has the training converged? Every model trained on to twice the budget (stats/convergence.csv)
and the ablation read again there (stats/twice/), for the page and for each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.evaluate.ablation_reading import curve_summary
from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    markdown_table,
    missing_file,
    percent,
)
from threedcal.report.sections.records import recorded_config, simulated_cell
from threedcal.study.fractions import convergence_fractions


def reading_line(folder: Path) -> str | None:
    """A reading's recommendation.txt in one line: the equivalence test's answer, then the
    learning curve's (learning_curve.csv beside it) and whether the two differ; None without it."""
    path = folder / "recommendation.txt"
    if not path.is_file():
        return None
    lines = path.read_text().strip().splitlines()
    text = lines[0]
    curve = folder / "learning_curve.csv"
    if curve.is_file():
        text += f"; learning curve: {curve_summary(pd.read_csv(curve))}"
        if any(line.startswith("the readings differ") for line in lines[1:]):
            text += " (the two differ: why in recommendation.txt)"
    return text


def convergence_lines(path: Path) -> list[str]:
    """The convergence check in one sentence per P (stats/convergence.csv), and the ablation read
    again at twice the budget (stats/twice/recommendation.txt)."""
    if not path.is_file():
        return []
    table = pd.read_csv(path)
    parts = [
        f"P = {row.P} % {row.budget_mse:.5f} after {row.steps} steps, {row.twice_mse:.5f} after "
        f"{row.twice_steps} ({row.change:+.1%}, {row.ci_low:+.1%} to {row.ci_high:+.1%})"
        for row in table.itertuples()
    ]
    lines = [
        "",
        "Convergence (every model trained on to twice the budget, mean validation MSE; "
        f"stats/convergence.csv): {'; '.join(parts)}.",
    ]
    twice = reading_line(path.parent / "twice")
    if twice:
        lines += ["", f"At twice the budget: {twice}"]
    return lines


def convergence_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if convergence_fractions(recorded_config(r))}
    if not chosen:
        return []
    rows, readings = [], []
    for name, record in chosen.items():
        path = results / name / "stats" / "convergence.csv"
        sim = simulated_cell(record)
        if not path.is_file():
            rows.append([f"`{name}`", sim, MISSING, missing_file(path, results)] + [MISSING] * 4)
            continue
        for row in pd.read_csv(path).itertuples():
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    str(row.P),
                    f"{row.steps} / {row.twice_steps}",
                    f"{row.budget_mse:.5f}",
                    f"{row.twice_mse:.5f}",
                    f"{percent(row.change)} [{percent(row.ci_low)}, {percent(row.ci_high)}]",
                    str(row.replicates),
                ]
            )
        for label, leaf in (
            ("the budget", "recommendation.txt"),
            ("twice", "twice/recommendation.txt"),
        ):
            line = reading_line((results / name / "stats" / leaf).parent)
            if line:
                readings.append(f"- `{name}` at {label}: {line}")
    return [
        "## Has the training converged? Twice the budget",
        "",
        "Protocol: every model trains the same steps (the budget) in cycles ending at a quarter, "
        "a half, all and twice the budget, scored by mean validation MSE "
        "(`stats/error_vs_time.csv`); the change at twice pairs models by replicate and "
        "block, 95 % interval (`stats/convergence.csv`); `stats/twice/` reads the "
        "ablation there.",
        "",
        *markdown_table(
            [
                "scene",
                SIM_COLUMN,
                "P %",
                "steps",
                "validation MSE",
                "at twice the steps",
                "change [95 % interval]",
                "replicates",
            ],
            rows,
        ),
        "",
        *(
            ["How many points to probe, read at the budget and at twice it:", "", *readings, ""]
            if readings
            else []
        ),
    ]
