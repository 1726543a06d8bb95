"""A store labelled through a registration known beforehand (threedcal.dataset.build.labelled_through):
with the dataset stage's own fit it is the dataset stage's set; with the bench's truth its labels
move by exactly the difference of the two affines; its points and splits are the splits table's."""

import json

import numpy as np
import pandas as pd
import pytest

from threedcal.dataset.build import labelled_through
from threedcal.dataset.camera_fit import AffineFit
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.lens import RadialLens
from threedcal.sim.bench import BenchTruth
from threedcal.study.scene import dataset_settings


def _fit(matrix, lens) -> AffineFit:
    return AffineFit(
        np.asarray(matrix, float), 0.0, np.zeros(0, bool), RadialLens.from_record(lens)
    )


def _relabelled(calibration, fit, offset, splits=None):
    scene, folder, _ = calibration
    splits = pd.read_csv(folder / "splits.csv") if splits is None else splits
    return labelled_through(dataset_settings(scene), folder / "raw.zarr", fit, offset, splits)


def test_through_the_stages_own_fit_it_is_the_stages_set(paper_digit_calibration):
    _, folder, _ = paper_digit_calibration
    record = json.loads((folder / "reg.json").read_text())
    built = TrainingSet.load(folder / "ts")
    fit = _fit(record["affine_px_per_mm"], record["lens"])
    again = _relabelled(paper_digit_calibration, fit, record["touch_offset_mm"])
    columns = ["frame", "point", "split", "min_p"]
    pd.testing.assert_frame_equal(again.samples[columns], built.samples[columns])
    np.testing.assert_array_equal(np.asarray(again.frames), np.asarray(built.frames))
    np.testing.assert_allclose(again.center_px, built.center_px, atol=1e-5)
    # reg.json keeps the touch offset to 0.1 µm
    np.testing.assert_allclose(again.depth_mm, built.depth_mm, atol=1e-4)


def test_through_the_truth_labels_move_by_the_difference_of_the_affines(paper_digit_calibration):
    scene, folder, _ = paper_digit_calibration
    record = json.loads((folder / "reg.json").read_text())
    truth = BenchTruth.read(folder / "truth.json")
    fitted = TrainingSet.load(folder / "ts")
    through = _relabelled(
        paper_digit_calibration,
        _fit(truth.affine_px_per_mm, truth.lens),
        truth.touch_offset_mm,
    )
    splits = pd.read_csv(folder / "splits.csv").set_index("point")
    mine = through.samples.set_index("point")
    theirs = fitted.samples.set_index("point")
    shared = mine.index.intersection(theirs.index)
    assert len(shared) >= 0.9 * len(theirs)  # the truth may put a few edge presses out of view
    mount = dataset_settings(scene).sensor["mount"]  # plan mm → printer mm
    xy = splits.loc[shared, ["x_mm", "y_mm"]].to_numpy(float)
    xy = xy + [mount["x_offset_mm"], mount["y_offset_mm"]]
    factor = int(fitted.meta.get("downscale", 1))
    true_px = _fit(truth.affine_px_per_mm, None).ideal(xy)
    moved = (true_px - _fit(record["affine_px_per_mm"], None).ideal(xy)) / factor
    measured = (
        mine.loc[shared, ["center_x_px", "center_y_px"]].to_numpy()
        - theirs.loc[shared, ["center_x_px", "center_y_px"]].to_numpy()
    )
    np.testing.assert_allclose(measured, moved, atol=1e-5)
    assert np.abs(moved).max() > 0.01  # the fit is not the truth: the test can tell them apart
    # the depth moves by the touch heights' difference (the dome's sag moves with the centre)
    step = truth.touch_offset_mm - record["touch_offset_mm"]
    change = mine.loc[shared, "depth_mm"].to_numpy() - theirs.loc[shared, "depth_mm"].to_numpy()
    assert np.median(change) == pytest.approx(step, abs=2e-3)
    assert (mine.loc[shared, "split"] == splits.loc[shared, "split"]).all()


def test_points_follow_the_splits_table_and_a_table_without_them_is_refused(
    paper_digit_calibration,
):
    _, folder, _ = paper_digit_calibration
    record = json.loads((folder / "reg.json").read_text())
    fit = _fit(record["affine_px_per_mm"], record["lens"])
    splits = pd.read_csv(folder / "splits.csv")
    part = splits[splits["split"] == "val"]
    only = _relabelled(paper_digit_calibration, fit, record["touch_offset_mm"], part)
    assert set(only.samples["point"]) == set(part["point"])
    assert (only.samples["split"] == "val").all()
    with pytest.raises(ConfigError, match="no column x_mm"):
        _relabelled(paper_digit_calibration, fit, 0.0, splits.drop(columns="x_mm"))
