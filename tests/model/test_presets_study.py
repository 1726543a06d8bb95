"""The presets stage (threedcal.model.presets_study): every preset trained alike, the scene's own
preset read from the study's model instead of trained twice."""

import pandas as pd
import pytest
from test_crossval import TINY, make_ball_folder, trainset_of

from threedcal.dataset.trainset import TrainingSet
from threedcal.model.presets_study import COLUMNS, compare_presets
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings


def test_a_preset_already_trained_is_read_not_trained_again_and_scores_as_a_fresh_training(
    tmp_path,
):
    make_ball_folder(tmp_path / "balls", n=8)
    ts = TrainingSet.load(trainset_of(tmp_path / "balls", tmp_path))
    settings = TrainSettings.of(**TINY, seed=0, torch_threads=1)
    # the study's own model of the scene's preset at P = 80 (replicate 0)
    train(ts, tmp_path / "P80", 80, settings, progress=False)
    reused = compare_presets(ts, settings, ["compact"], {"compact": tmp_path / "P80/model.pt"})
    fresh = compare_presets(ts, settings, ["compact", "lookup"])
    assert list(reused.columns) == COLUMNS and list(fresh["preset"]) == ["compact", "lookup"]
    # the same training: the same figures; its seconds are the ones its losses.csv records
    for column in ("gradient_rmse", "cap_depth_mae_um"):
        assert reused.loc[0, column] == fresh.loc[0, column]
    recorded = pd.read_csv(tmp_path / "P80/losses.csv")["seconds"].sum()
    assert reused.loc[0, "train_s"] == pytest.approx(recorded, abs=0.01)
    assert (fresh["train_s"] > 0).all()
