"""The quick calibration over units (threedcal.study.quick_study): the claim's interval over units on
tables with known answers, and the workflow target that is never part of `all`."""

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from threedcal.study.quick_study import COLUMNS, over_units


def table(changes: dict[str, list[float]], presses=48, minutes=1.9) -> pd.DataFrame:
    rows = []
    for sensor, values in changes.items():
        for unit, change in enumerate(values, start=11):
            row = dict.fromkeys(COLUMNS, math.nan)
            row.update(sensor=sensor, unit=unit, change=change, presses_in_all=presses)
            row.update(printer_min=minutes)
            rows.append(row)
    return pd.DataFrame(rows, columns=list(COLUMNS))


def test_the_claims_interval_is_students_t_over_the_units():
    changes = [0.031, -0.012, 0.054, 0.008]
    claim = over_units(table({"digit_fots": changes}))["digit_fots"]
    expected = stats.t.interval(0.95, 3, loc=np.mean(changes), scale=stats.sem(changes))
    assert claim["units"] == 4 and claim["change"] == pytest.approx(np.mean(changes))
    assert claim["interval"] == pytest.approx(list(expected))
    assert claim["verdict"] == "met"  # [-0.025, +0.066] lies inside ±10 %
    assert claim["most_presses"] == 48 and claim["presses_verdict"] == "met"
    assert (
        claim["minutes_verdict"] == "met"
        and "(+2.0%, 95% interval -2.5% to +6.6%)" in claim["line"]
    )


@pytest.mark.parametrize(
    ("changes", "verdict"),
    [
        ([0.02, 0.09, 0.15, -0.01], "undecided"),  # astride +10 %
        ([0.21, 0.25, 0.19, 0.23], "not met"),  # wholly past it
        ([-0.21, -0.25, -0.19, -0.23], "not met"),  # better by more than 10 % is outside too
    ],
)
def test_the_claim_holds_only_when_the_whole_interval_lies_inside_ten_percent(changes, verdict):
    assert over_units(table({"gelsight_mini": changes}))["gelsight_mini"]["verdict"] == verdict


def test_sensors_are_judged_apart_and_together():
    both = over_units(
        table({"digit_fots": [0.01, 0.03, 0.02, 0.04], "gelsight_mini": [0.0, 0.02]}, 51, 5.2)
    )
    assert set(both) == {"digit_fots", "gelsight_mini", "all"}
    assert both["all"]["units"] == 6
    assert both["all"]["change"] == pytest.approx(np.mean([0.01, 0.03, 0.02, 0.04, 0.0, 0.02]))
    assert (
        both["all"]["presses_verdict"] == "not met" and both["all"]["minutes_verdict"] == "not met"
    )
    one = over_units(table({"digit_fots": [0.05]}))["digit_fots"]
    assert math.isnan(one["interval"][0]) and one["verdict"] == "undecided"  # one unit says nothing


def test_the_study_target_asks_for_each_units_quick_and_full_calibration_and_is_not_in_all(repo):
    import subprocess

    out = subprocess.run(
        [
            str(repo / ".venv/bin/snakemake"),
            "quick_study",
            "-n",
            "--quiet",
            "rules",
            "--configfile",
            str(repo / "config/quick_study.yaml"),
        ],
        cwd=repo,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    jobs = dict(
        line.split() for line in out.splitlines() if line.strip() and line.split()[-1].isdigit()
    )
    assert jobs["quick"] == "8" and jobs["quick_study"] == "1" and jobs["train"] == "16"
    assert "quick_arms" not in jobs  # quick.arms: false
