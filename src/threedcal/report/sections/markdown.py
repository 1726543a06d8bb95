"""Markdown tables and figures as both documents write them, and the results files they read."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

SIMULATED = "yes"
# The column every page table carries: did the simulator render both the frames trained on and
# those tested?
SIM_COLUMN = "simulator made training and test frames"
SIM_READINGS = SIM_COLUMN.replace("frames", "readings")
# Columns that describe a table's rows rather than measure them: one whose value is the same on
# every row becomes a line above the table instead of a repeated cell.
DESCRIPTIVE = ("scene", "sensor", SIM_COLUMN, SIM_READINGS, "protocol", "torch threads")
MISSING = "—"


def read_json(path: Path) -> dict | None:
    """A results JSON file, or None where the study has not written it."""
    return json.loads(path.read_text()) if path.is_file() else None


def markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table; each DESCRIPTIVE column whose value is the same on every row leaves the
    table for one line above it (a study where the value varies keeps the column)."""
    keep, same = list(range(len(header))), []
    for i, name in enumerate(header):
        values = {str(row[i]) for row in rows}
        if name in DESCRIPTIVE and len(values) == 1 and len(keep) > 1:
            same.append(f"*{name}* {values.pop()}")
            keep.remove(i)
    lines = ["Every row: " + "; ".join(same) + ".", ""] if same else []
    return [
        *lines,
        "| " + " | ".join(header[i] for i in keep) + " |",
        "|" + "|".join("---" for _ in keep) + "|",
        *("| " + " | ".join(str(row[i]) for i in keep) + " |" for row in rows),
    ]


def fact_table(facts: list[tuple[str, str]]) -> list[str]:
    """A two-column table of (what, figure) rows without a header."""
    return ["| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in facts]


def estimate(value, lo=None, hi=None, digits: int = 0) -> str:
    """'74 [70, 78]': a figure with its interval (the interval left out where it is unknown)."""
    if value is None or pd.isna(value):
        return MISSING
    text = f"{value:.{digits}f}"
    if lo is None or hi is None or pd.isna(lo) or pd.isna(hi):
        return text
    return f"{text} [{lo:.{digits}f}, {hi:.{digits}f}]"


def cross_validated(figures: Mapping, key: str, digits: int) -> str:
    """A figure of ball_eval.json with its interval95 bounds where it has them."""
    lo, hi = (figures.get("interval95", {}).get(key) or [None, None])[:2]
    return estimate(figures.get(key), lo, hi, digits)


def figure(value, digits: int = 2) -> str:
    """A float to `digits` places, anything else as it is, None as MISSING."""
    if value is None:
        return MISSING
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def bounds_suffix(figures: Mapping, key: str, digits: int) -> str:
    """' [lo, hi]' of a cross-validated figure's 95 % interval, or nothing."""
    bounds = figures.get("interval95", {}).get(key)
    return f" [{bounds[0]:.{digits}f}, {bounds[1]:.{digits}f}]" if bounds else ""


def percent(value: float) -> str:
    return f"{value * 100:+.1f} %"


def percent_interval(low: float, high: float) -> str:
    """'[-2.9, +14.6]': an interval of relative changes, in percent."""
    return f"[{low * 100:+.1f}, {high * 100:+.1f}]"


def missing_file(path: Path, results: Path) -> str:
    """A page cell for a file the study did not write."""
    return f"not in these results (`{path.relative_to(results.parent).as_posix()}`)"
