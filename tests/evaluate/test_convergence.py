"""Error against training time (threedcal.evaluate.convergence): every cycle end of the ablation's
lockstep trainings scored as the stats stage scores the study's models, and the change at twice
the budget paired by replicate and block."""

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "model"))
from test_lockstep import settings, two_replicate_set  # noqa: E402

from threedcal.evaluate.convergence import (  # noqa: E402
    CONVERGENCE_COLUMNS,
    CURVE_COLUMNS,
    convergence_table,
    curve_figure,
    error_vs_time_table,
    snapshot_scores,
)
from threedcal.evaluate.validation import coordinate_mse  # noqa: E402
from threedcal.model.checkpoint import read_checkpoint  # noqa: E402
from threedcal.model.inference import DepthEstimator  # noqa: E402
from threedcal.model.lockstep import Member, train_lockstep  # noqa: E402

KEYS = [(20, 0), (80, 0), (80, 1)]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("convergence")
    ts = two_replicate_set()
    members = [Member(p, r, root / f"P{p}/r{r}") for p, r in KEYS]
    train_lockstep(ts, members, settings(), 8, twice=True, progress=False)
    return ts, root


def test_every_cycle_end_is_scored_as_the_stats_stage_scores_and_timed(runs):
    ts, root = runs
    snapshots = {
        key: sorted((root / f"P{key[0]}/r{key[1]}/snapshots").glob("*.pt")) for key in KEYS
    }
    scores = snapshot_scores(snapshots, ts)
    assert sorted(scores["steps"].unique()) == [2, 4]
    first = read_checkpoint(snapshots[(80, 1)][0])
    expected = coordinate_mse(DepthEstimator(first, device="cpu"), ts)["mse"].mean()
    row = scores[(scores["P"] == 80) & (scores["replicate"] == 1) & (scores["steps"] == 2)]
    assert float(row["mse"].iloc[0]) == pytest.approx(expected)
    budget = pd.DataFrame(
        [
            {"P": p, "replicate": r, "point": k, "mse": 0.01 * (k + 1)}
            for p, r in KEYS
            for k in range(3)
        ]
    )
    twice = budget.assign(mse=budget["mse"] * 0.9)
    losses = {key: root / f"P{key[0]}/r{key[1]}/twice/losses.csv" for key in KEYS}
    curve = error_vs_time_table(scores, (8, budget), (16, twice), losses)
    assert list(curve.columns) == list(CURVE_COLUMNS)
    assert curve.groupby(["P", "replicate"])["steps"].apply(list).map(tuple).unique().tolist() == [
        (2, 4, 8, 16)
    ]
    for _, model in curve.groupby(["P", "replicate"]):
        assert model["seconds"].notna().all() and model["seconds"].is_monotonic_increasing
    at_budget = curve[(curve["steps"] == 8) & (curve["P"] == 80) & (curve["replicate"] == 0)]
    assert float(at_budget["mse"].iloc[0]) == pytest.approx(0.02)


def test_the_change_at_twice_the_budget_is_paired_by_replicate_and_block():
    rng = np.random.default_rng(0)
    rows = []
    for p in (5, 80):
        for r in range(4):
            for k in range(12):
                rows.append(
                    {
                        "P": p,
                        "replicate": r,
                        "point": k,
                        "x_mm": k % 4,
                        "y_mm": k // 4,
                        "mse": 0.01 + 0.002 * rng.random(),
                    }
                )
    budget = pd.DataFrame(rows)
    twice = budget.assign(mse=budget["mse"] * np.where(budget["P"] == 80, 0.95, 1.0))
    blocks = pd.Series(np.arange(12) % 6, index=np.arange(12))
    table = convergence_table((1000, budget), (2000, twice), blocks).set_index("P")
    assert list(table.reset_index().columns) == list(CONVERGENCE_COLUMNS)
    assert table.loc[80, "change"] == pytest.approx(-0.05)
    # an exact 5 % drop on every coordinate: the interval is that point
    assert table.loc[80, "ci_low"] == pytest.approx(-0.05, abs=1e-6)
    assert table.loc[80, "ci_high"] == pytest.approx(-0.05, abs=1e-6)
    assert table.loc[5, "change"] == pytest.approx(0.0) and table.loc[5, "replicates"] == 4
    noisy = budget.assign(mse=budget["mse"] * (1 + 0.05 * rng.standard_normal(len(budget))))
    table = convergence_table((1000, budget), (2000, noisy), blocks).set_index("P")
    assert table.loc[5, "ci_low"] < table.loc[5, "change"] < table.loc[5, "ci_high"]
    assert table.loc[5, "twice_steps"] == 2000 and table.loc[5, "steps"] == 1000


def test_the_figure_draws_every_fraction(runs, tmp_path):
    curve = pd.DataFrame(
        {
            "P": [1] * 4 + [80] * 4,
            "replicate": [0] * 8,
            "steps": [250, 500, 1000, 2000] * 2,
            "seconds": [1.0, 2.0, 4.0, 8.0] * 2,
            "mse": [0.02, 0.018, 0.017, 0.0172, 0.012, 0.010, 0.009, 0.0088],
        }
    )
    curve_figure(curve, 1000, tmp_path / "curve.png", "test")
    assert (tmp_path / "curve.png").stat().st_size > 10_000
