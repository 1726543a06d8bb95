import numpy as np
import pandas as pd
import pytest

from threedcal.dataset.labels import local_dome, sphere_gradients
from threedcal.dataset.trainset import TrainingSet, coordinate_channels, downscale, model_inputs
from threedcal.errors import ConfigError
from threedcal.study.dataset_stage import import_stage


def small_set(n=4, shape=(40, 30)):
    rng = np.random.default_rng(0)
    samples = pd.DataFrame(
        {
            "frame": np.arange(n),
            "point": np.arange(n) // 2,
            "center_x_px": [10.3, 11.0, 20.5, 15.0][:n],
            "center_y_px": [12.0, 25.2, 20.0, 30.7][:n],
            "depth_mm": [0.5, 0.8, 1.0, 1.2][:n],
            "eval_radius_px": [10.0] * n,
            "split": ["train", "train", "val", "val"][:n],
            "min_p": [80, 80, 0, 0][:n],
        }
    )
    return TrainingSet(
        frames=rng.integers(0, 256, (n, *shape, 3), dtype=np.uint8),
        blank=rng.uniform(0, 255, (*shape, 3)).astype(np.float32),
        samples=samples,
        px_per_mm=8.0,
        sphere_radius_mm=2.0,
    )


def test_coordinate_channels_span_minus_one_to_one_and_follow_windows():
    full = coordinate_channels(5, 4)
    assert full[0, 0].tolist() == pytest.approx([-1, -1 / 3, 1 / 3, 1])
    assert full[1, :, 0].tolist() == pytest.approx([-1, -0.5, 0, 0.5, 1])
    window = (slice(1, 3), slice(2, 4))
    np.testing.assert_array_equal(coordinate_channels(5, 4, window), full[:, 1:3, 2:4])


def test_coordinate_channels_are_shared_and_read_only():
    # one grid per image size, handed out as views: a caller that wrote into one would change
    # every later frame's input, so writing raises
    grid = coordinate_channels(6, 7, (slice(0, 3), slice(1, 4)))
    assert np.shares_memory(grid, coordinate_channels(6, 7))
    with pytest.raises(ValueError, match="read-only"):
        grid[0, 0, 0] = 5.0
    assert coordinate_channels(6, 7)[0, 0, 1] == pytest.approx(-1 + 2 / 6)


def test_inputs_and_labels_of_a_window_equal_the_window_of_the_full_image():
    ts = small_set()
    window = (slice(5, 25), slice(3, 21))
    np.testing.assert_allclose(ts.inputs(1, window), ts.inputs(1)[:, 5:25, 3:21], atol=1e-7)
    np.testing.assert_allclose(ts.labels(1, window), ts.labels(1)[:, 5:25, 3:21], atol=1e-7)
    frame = ts.frames[1].astype(np.float32)
    np.testing.assert_allclose(ts.inputs(1)[0], (frame[..., 0] - ts.blank[..., 0]) / 255, atol=1e-6)
    assert model_inputs(ts.frames[0], ts.blank).shape == (5, 40, 30)


def test_split_and_subset_indices():
    ts = small_set()
    assert ts.indices("train").tolist() == [0, 1]
    assert ts.indices("val").tolist() == [2, 3]
    assert ts.indices("train", percent=5).tolist() == []


def test_a_set_whose_samples_do_not_number_its_frames_is_refused():
    """Training and scoring take sample i's frame as frames[i]: a subset that kept the full set's
    frame numbers (or frames of another count) would train on other frames' labels."""
    ts = small_set()
    subset = ts.samples.iloc[[0, 2]].reset_index(drop=True)
    with pytest.raises(ConfigError, match="number the rows 0..N-1"):
        TrainingSet(ts.frames[[0, 2]], ts.blank, subset, 8.0, 2.0)
    renumbered = subset.assign(frame=[0, 1])
    TrainingSet(ts.frames[[0, 2]], ts.blank, renumbered, 8.0, 2.0)  # accepted
    with pytest.raises(ConfigError, match="2 samples for 4 frames"):
        TrainingSet(ts.frames, ts.blank, renumbered, 8.0, 2.0)


def test_save_load_round_trip(tmp_path):
    ts = small_set()
    ts.save(tmp_path / "set")
    back = TrainingSet.load(tmp_path / "set")
    np.testing.assert_array_equal(np.asarray(back.frames), ts.frames)
    np.testing.assert_array_equal(back.labels(2), ts.labels(2))
    assert back.px_per_mm == 8.0 and back.sphere_radius_mm == 2.0
    (tmp_path / "set/meta.json").unlink()
    with pytest.raises(ConfigError, match="meta.json: missing"):
        TrainingSet.load(tmp_path / "set")


def test_downscale_keeps_the_sphere_where_it_was():
    ts = small_set()
    half = downscale(ts, 2)
    assert half.frames.shape == (4, 20, 15, 3) and half.px_per_mm == 4.0
    # Pooled labels ≈ labels of the pooled geometry: compare the depth-weighted centre of the contact.
    full_mask = np.abs(ts.labels(3)).sum(0) > 0
    half_mask = np.abs(half.labels(3)).sum(0) > 0
    rows, cols = np.nonzero(full_mask)
    rows_h, cols_h = np.nonzero(half_mask)
    assert (cols_h.mean() + 0.5) * 2 - 0.5 == pytest.approx(cols.mean(), abs=0.6)
    assert (rows_h.mean() + 0.5) * 2 - 0.5 == pytest.approx(rows.mean(), abs=0.6)


def test_build_imported_real_folder(tmp_path, real_data):
    scene = {
        "import": {"format": "ball_folder", "path": str(real_data / "gelsight_ball_fots")},
        "seed": 4,
        "dataset": {"downscale": 2, "max_slope_deg": 70},
    }
    ts = import_stage(
        scene,
        tmp_path / "trainset",
        tmp_path / "splits.csv",
    )
    splits = pd.read_csv(tmp_path / "splits.csv")
    assert len(splits) == 42 and (splits["split"] == "val").sum() == 8
    back = TrainingSet.load(tmp_path / "trainset")
    assert back.frames.shape == (42, 160, 120, 3) and back.max_slope_deg == 70
    assert back.px_per_mm == pytest.approx(19.58 / 2)
    assert ts.indices("val").size == 8


def test_a_domed_sets_labels_are_measured_from_its_dome_in_every_window_and_after_saving(tmp_path):
    """meta `dome` (the profile's gel.dome, which the dataset stage records) makes each frame's
    labels the depth below the undeformed dome about that frame's press, window or not."""
    ts = small_set()
    dome = {"kx_per_mm": 0.05, "ky_per_mm": 0.02, "apex_x_mm": 0.3, "apex_y_mm": 0.0}
    ts.meta = {"dome": dome}
    expected = sphere_gradients(
        ts.image_shape,
        tuple(ts.center_px[2]),
        2.0,
        1.0,
        8.0,
        dome=local_dome(dome, ts.center_px[2], ts.image_shape, 8.0),
    ).transpose(2, 0, 1)
    np.testing.assert_allclose(ts.labels(2), expected, atol=1e-7)
    flat = small_set().labels(2)
    assert np.abs(ts.labels(2) - flat).max() > 0.05
    window = (slice(5, 25), slice(3, 21))
    np.testing.assert_allclose(ts.labels(2, window), ts.labels(2)[:, 5:25, 3:21], atol=1e-7)
    ts.save(tmp_path / "set")
    np.testing.assert_array_equal(TrainingSet.load(tmp_path / "set").labels(2), ts.labels(2))


def test_kept_labels_equal_the_labels_computed_for_each_window_to_the_bit():
    """Labels are computed once per frame over the box its press can reach, then cut per window:
    every window, one that crosses the box's edge or lies outside it included, equals the labels
    computed for that window alone (so a model trains to the same bits either way)."""
    ts = small_set(shape=(120, 110))
    ts.meta = {"dome": {"kx_per_mm": 0.05, "ky_per_mm": 0.02}}
    for i in range(4):
        cx, cy = ts.center_px[i]
        for r0, c0 in ((0, 0), (3, 40), (50, 2), (90, 80), (int(cy) - 7, int(cx) - 9)):
            r0, c0 = max(r0, 0), max(c0, 0)
            window = (slice(r0, r0 + 30), slice(c0, c0 + 30))
            h, w = ts.labels(i, window).shape[1:]
            direct = sphere_gradients(
                (h, w),
                (cx - c0, cy - r0),
                2.0,
                float(ts.depth_mm[i]),
                8.0,
                dome=ts.dome_at(i),
            ).transpose(2, 0, 1)
            np.testing.assert_array_equal(ts.labels(i, window), direct)
    assert set(ts._label_boxes) == {0, 1, 2, 3}
