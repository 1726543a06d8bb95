"""The convergence check (threedcal.evaluate.convergence): the study's models against the same
training at twice its budget, scored as the stats stage scores them."""

import sys
from pathlib import Path

import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "model"))
from test_model import TINY, synthetic_set  # noqa: E402

from threedcal.evaluate.convergence import (  # noqa: E402
    CONVERGENCE_COLUMNS,
    CURVE_COLUMNS,
    convergence_table,
    curve_figure,
    curve_table,
)
from threedcal.evaluate.validation import coordinate_mse  # noqa: E402
from threedcal.model.inference import DepthEstimator  # noqa: E402
from threedcal.model.train import TrainSettings, train  # noqa: E402

RULE = {"rule": "doubling", "first_cycle": 3, "max_steps": 12}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("convergence")
    ts = synthetic_set(n=12)
    settings = TrainSettings.of(
        preset="compact_tiny", seed=2, lr=1e-2, stopping=RULE, **{**TINY, "batch_size": 2}
    )
    study = train(ts, root / "study", 80, settings, progress=False)
    train(
        ts,
        root / "twice",
        80,
        settings,
        progress=False,
        budget_scale=2.0,
        min_steps=2 * study["training"]["steps"],
        snapshot_every=1,
    )
    return ts, root, study


def test_the_curve_scores_every_snapshot_and_the_study_model_as_the_stats_stage_does(runs):
    ts, root, study = runs
    curve = curve_table(
        {80: (root / "study/model.pt", root / "study/losses.csv")},
        {80: (root / "twice/snapshots", root / "twice/losses.csv")},
        ts,
    )
    assert list(curve.columns) == list(CURVE_COLUMNS)
    snapshots = sorted((root / "twice/snapshots").glob("step*.pt"))
    assert (curve["run"] == "twice").sum() == len(snapshots) >= 2
    own = curve[curve["run"] == "study"].iloc[0]
    expected = coordinate_mse(DepthEstimator(study, device="cpu"), ts)["mse"].mean()
    assert own["mse"] == pytest.approx(expected)
    assert own["steps"] == study["training"]["steps"]
    twice = curve[curve["run"] == "twice"]
    assert twice["seconds"].is_monotonic_increasing and twice["seconds"].notna().all()
    assert own["seconds"] == pytest.approx(pd.read_csv(root / "study/losses.csv")["seconds"].sum())


def test_the_table_compares_the_study_with_twice_its_budget(runs, tmp_path):
    ts, root, _ = runs
    curve = pd.DataFrame(
        {
            "P": [80, 80, 80, 1, 1],
            "run": ["study", "twice", "twice", "study", "twice"],
            "steps": [100, 150, 200, 40, 80],
            "seconds": [10.0, 15.0, 20.0, 4.0, 8.0],
            "mse": [0.02, 0.0195, 0.019, 0.04, 0.044],
        }
    )
    table = convergence_table(curve).set_index("P")
    assert list(table.reset_index().columns) == list(CONVERGENCE_COLUMNS)
    assert table.loc[80, "twice_steps"] == 200 and table.loc[80, "change"] == pytest.approx(-0.05)
    assert table.loc[1, "change"] == pytest.approx(0.10)
    curve_figure(curve, tmp_path / "curve.png", "test")
    assert (tmp_path / "curve.png").stat().st_size > 10_000
