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


def test_on_the_bench_the_truth_scored_change_decides_and_the_other_is_reported(tmp_path):
    from threedcal.study.quick_study import study_figure, study_summary

    both = table({"digit_fots": [0.60, 1.50, 2.60, 1.20]})
    both["truth_change"] = [0.05, -0.03, 0.08, 0.01]
    both["truth_change_lo"] = both["truth_change"] - 0.2
    both["truth_change_hi"] = both["truth_change"] + 0.2
    both[["change_lo", "change_hi"]] = np.column_stack([both["change"] - 0.3, both["change"] + 0.3])
    summary = study_summary(both)
    assert summary["column"] == "truth_change" and summary["scored_against"] == "the bench's truth"
    claim = summary["claims"]["digit_fots"]
    assert claim["change"] == pytest.approx(0.0275) and claim["verdict"] == "undecided"
    assert "scored against the bench's truth" in claim["line"]
    other = summary["against_full_labels"]["digit_fots"]
    assert other["change"] == pytest.approx(1.475) and other["verdict"] == "not met"
    study_figure(both, summary, tmp_path / "units.png")
    assert (tmp_path / "units.png").stat().st_size > 10_000

    # one unit without a truth (a real rig): every unit is scored against the full labels alone
    both.loc[0, "truth_change"] = math.nan
    fallback = study_summary(both)
    assert fallback["column"] == "change" and "against_full_labels" not in fallback
    assert fallback["claims"]["digit_fots"]["change"] == pytest.approx(1.475)
    study_figure(both, fallback, tmp_path / "units_real.png")


def test_off_the_bench_there_is_no_truth_set():
    from threedcal.study.quick_study import UnitPair, _truth_set

    pair = UnitPair("q", "f", "digit_fots", None, "m.pt", "stop.json", ["f.pt"], "ts", "splits.csv")
    assert _truth_set(pair, pd.DataFrame()) is None
