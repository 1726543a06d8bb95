"""Cross-validated real-data evaluation (threedcal.evaluate.crossval, ball_eval): folds, scoring, intervals."""

import json
import math

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from threedcal.dataset import folds as cv_folds
from threedcal.dataset.labels import sphere_depth, sphere_gradients
from threedcal.errors import ConfigError
from threedcal.evaluate import crossval
from threedcal.evaluate.ball_eval import ball_eval
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator
from threedcal.study import imported_jobs
from threedcal.study.dataset_stage import import_stage

PX_PER_MM, BALL_MM, SIZE = 10.0, 2.0, (64, 80)  # (width, height) of the rendered frames
TINY = {"preset": "compact", "epochs_base": 1, "patch_px": 24, "contact_patches": 2}


def write_rgb(path, image):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def presses(n, seed=0):
    """n ball presses (centre px, depth mm) spread over the frame, a few px apart at least."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform([18, 20], [SIZE[0] - 18, SIZE[1] - 20], (n, 2))
    return centres, rng.uniform(0.4, 0.9, n)


def render(centres, depths, seed=0):
    sim = GelSimulator(
        load_profile("sensor", "gelsight_mini"), seed, image_size=SIZE, px_per_mm=PX_PER_MM
    )
    frames = [
        sim.render(Sphere(BALL_MM), tuple(c), 0.0, float(d), frame_index=i + 1)
        for i, (c, d) in enumerate(zip(centres, depths, strict=True))
    ]
    return frames, sim.blank(0)


def make_ball_folder(root, n=12, seed=0, background=True, labels=True):
    """A user's own ball folder: simulated frames, background.png, labels.csv, dataset.yaml."""
    centres, depths = presses(n, seed)
    frames, blank = render(centres, depths, seed)
    names = [f"{i:04d}.png" for i in range(n)]
    for name, frame in zip(names, frames, strict=True):
        write_rgb(root / name, frame)
    if background:
        write_rgb(root / "background.png", blank)
    radius = np.sqrt(2 * BALL_MM * depths - depths**2) * PX_PER_MM
    if labels:
        pd.DataFrame(
            {
                "image": names,
                "center_x_px": centres[:, 0],
                "center_y_px": centres[:, 1],
                "radius_px": radius,
            }
        ).to_csv(root / "labels.csv", index=False)
    (root / "dataset.yaml").write_text(
        yaml.safe_dump({"px_per_mm": PX_PER_MM, "ball_radius_mm": BALL_MM})
    )
    return centres, radius


def make_py3dcal_folder(root, coordinates=6, seed=1):
    """A py3DCal-layout folder: two depths at each probe coordinate."""
    centres, _ = presses(coordinates, seed)
    centres = np.repeat(centres, 2, axis=0)
    depths = np.tile([0.5, 0.8], coordinates)
    frames, blank = render(centres, depths, seed)
    write_rgb(root / "blank_images/blank.png", blank)
    rows = []
    for i, (frame, (x, y), d) in enumerate(zip(frames, centres, depths, strict=True)):
        name = f"{i}_X{x:.2f}Y{y:.2f}Z{d}.png"
        write_rgb(root / "probe_images" / name, frame)
        rows.append((name, x / PX_PER_MM, y / PX_PER_MM, d, x, y))
    (root / "annotations").mkdir()
    pd.DataFrame(
        rows, columns=["img_name", "x_mm", "y_mm", "penetration_depth_mm", "x_px", "y_px"]
    ).to_csv(root / "annotations/annotations.csv", index=False)
    (root / "annotations/metadata.json").write_text(
        json.dumps({"px_per_mm": PX_PER_MM, "probe_radius_mm": BALL_MM})
    )


def trainset_of(folder, tmp_path, fmt="ball_folder"):
    scene = {
        "import": {"format": fmt, "path": str(folder)},
        "seed": 0,
        "dataset": {"downscale": 1, "max_slope_deg": 75},
    }
    import_stage(
        scene,
        tmp_path / "trainset",
        tmp_path / "splits.csv",
    )
    return tmp_path / "trainset"


# ------------------------------------------------------------------------------------ folds
def test_groups_join_close_presses_transitively_and_frames_of_one_coordinate():
    centres = np.array([[0, 0], [4, 0], [8, 0], [30, 0], [60, 0], [90, 0]], float)
    radius = np.full(6, 20.0)
    # 0.25 x 20 px = 5 px: 0-1 and 1-2 are linked (a chain), the others stand alone.
    assert cv_folds.press_groups(centres, radius, 0.25).tolist() == [0, 0, 0, 1, 2, 3]
    # a whole contact radius chains 0..3 (30 - 8 = 22 > 20 keeps 3 apart from 2)
    assert cv_folds.press_groups(centres, radius, 1.0).tolist() == [0, 0, 0, 1, 2, 3]
    assert cv_folds.press_groups(centres, radius, 1.6).tolist() == [0, 0, 0, 0, 0, 0]
    # frames of one probe coordinate share a group whatever their distance
    point = np.array([0, 1, 2, 3, 3, 4])
    assert cv_folds.press_groups(centres, radius, 0.0, point).tolist() == [0, 1, 2, 3, 3, 4]


def test_every_image_is_tested_once_and_no_group_straddles_folds():
    rng = np.random.default_rng(3)
    groups = rng.integers(0, 15, 40)
    fold = cv_folds.grouped_folds(groups, 5, seed=0)
    assert sorted(set(fold)) == [0, 1, 2, 3, 4]
    for g in np.unique(groups):
        assert len(set(fold[groups == g])) == 1
    sizes = np.bincount(fold)
    assert sizes.max() - sizes.min() <= np.bincount(groups).max()
    np.testing.assert_array_equal(fold, cv_folds.grouped_folds(groups, 5, seed=0))
    assert not np.array_equal(fold, cv_folds.grouped_folds(groups, 5, seed=1))


def test_too_few_images_or_groups_for_k_folds_is_a_clear_error():
    with pytest.raises(
        ConfigError, match=r"my_folder: 4 labelled image\(s\) .* cannot make 6 folds"
    ):
        cv_folds.grouped_folds(np.arange(4), 6, seed=0, where="my_folder")
    with pytest.raises(ConfigError, match="2 independent press group"):
        cv_folds.grouped_folds(np.array([0, 0, 0, 1, 1, 1]), 3, seed=0)
    with pytest.raises(ConfigError, match="fewer than 3 training images"):
        cv_folds.grouped_folds(np.arange(4), 2, seed=0)
    # one group holding most images cannot be spread over the folds
    with pytest.raises(ConfigError, match="largest 11 of 14"):
        cv_folds.grouped_folds(np.array([0] * 11 + [1, 2, 3]), 3, seed=0)
    with pytest.raises(ConfigError, match="cv.folds"):
        cv_folds.grouped_folds(np.arange(10), 1, seed=0)


def test_fold_trainset_marks_train_and_test_and_subsets_are_nested(tmp_path):
    from threedcal.dataset.trainset import TrainingSet

    make_ball_folder(tmp_path / "balls", n=12)
    ts = TrainingSet.load(trainset_of(tmp_path / "balls", tmp_path))
    folds = cv_folds.make_folds(ts, cv_folds.CVSettings.of(folds=3), seed=0)
    for fold in range(3):
        part = cv_folds.fold_trainset(ts, folds, fold)
        test = folds["fold"].to_numpy() == fold
        assert (part.split[test] == "test").all() and (part.split[~test] == "train").all()
        assert part.indices("train", percent=80).tolist() == np.flatnonzero(~test).tolist()
        assert len(part.indices("val")) == 0  # nothing of the test fold reaches training
        small, large = (set(cv_folds.training_images(folds, fold, k, seed=0)) for k in (2, 4))
        assert len(small) == 2 and small < large and not large & set(np.flatnonzero(test))
    with pytest.raises(ConfigError, match="n_train=99"):
        cv_folds.training_images(folds, 0, 99, seed=0)


# ------------------------------------------------------------------------------------ scoring
def _sphere_set(n=3):
    """A TrainingSet with exact labels and no frames that matter (scoring only reads the labels)."""
    from threedcal.dataset.trainset import TrainingSet

    shape = (60, 70)
    centres = np.array([[30.0, 28.0], [35.5, 31.0], [33.0, 30.5]])[:n]
    depths = np.array([0.5, 0.7, 0.3])[:n]
    contact = np.sqrt(2 * BALL_MM * depths - depths**2) * PX_PER_MM
    samples = pd.DataFrame(
        {
            "frame": range(n),
            "point": range(n),
            "center_x_px": centres[:, 0],
            "center_y_px": centres[:, 1],
            "depth_mm": depths,
            "eval_radius_px": 0.9 * contact,
            "split": ["train"] * n,
            "min_p": [80] * n,
        }
    )
    frames = np.zeros((n, *shape, 3), np.uint8)
    return TrainingSet(frames, np.zeros((*shape, 3), np.float32), samples, PX_PER_MM, BALL_MM)


def test_exact_prediction_scores_zero_and_a_depth_offset_scores_its_size():
    ts = _sphere_set()
    truth = crossval.Truth.of(ts)
    for i in range(3):
        c, d = tuple(ts.center_px[i]), float(ts.depth_mm[i])
        grads = sphere_gradients(ts.image_shape, c, BALL_MM, d, PX_PER_MM)
        cap = sphere_depth(ts.image_shape, c, BALL_MM, d, PX_PER_MM)
        assert crossval.image_errors(grads, cap, ts, i, truth) == (0.0, 0.0, 0.0, 0.0)
        mse, mae, bias, shape = crossval.image_errors(grads + 0.1, cap - 0.05, ts, i, truth)
        assert mse == pytest.approx(0.01, rel=1e-5)
        assert mae == pytest.approx(50.0) and bias == pytest.approx(-50.0)
        assert shape == pytest.approx(0.0, abs=1e-9)  # a constant offset leaves the shape exact
        # the cap of another depth (what a wrong radius label gives): offset only, same shape
        other = sphere_depth(ts.image_shape, c, BALL_MM, d + 0.1, PX_PER_MM)
        _, mae, bias, shape = crossval.image_errors(grads, other, ts, i, truth)
        assert mae == pytest.approx(100.0) and shape == pytest.approx(0.0, abs=1e-6)


def test_label_perturbation_moves_depth_with_the_contact_radius():
    ts = _sphere_set()
    zero = cv_folds.CVSettings.of(radius_sigma_px=0.0, centre_sigma_px=0.0)
    same = crossval.perturbed_truth(ts, zero, np.random.default_rng(0))
    np.testing.assert_allclose(same.depth_mm, ts.depth_mm)
    np.testing.assert_allclose(same.eval_radius_px, ts.eval_radius_px)
    moved = crossval.perturbed_truth(
        ts,
        cv_folds.CVSettings.of(radius_sigma_px=2.0, centre_sigma_px=1.0),
        np.random.default_rng(0),
    )
    contact = np.sqrt(2 * BALL_MM * moved.depth_mm - moved.depth_mm**2) * PX_PER_MM
    np.testing.assert_allclose(moved.eval_radius_px, 0.9 * contact)  # ratio kept
    assert not np.allclose(moved.depth_mm, ts.depth_mm)
    assert not np.allclose(moved.center_px, ts.center_px)


def test_group_bootstrap_interval_brackets_the_figure_and_pairs_methods():
    rng = np.random.default_rng(0)
    n = 30
    table = pd.DataFrame(
        {
            "group": np.arange(n) // 2,
            "fold": np.arange(n) % 3,
            "gradient_mse": rng.uniform(0.01, 0.05, n),
            "cap_depth_mae_um": rng.uniform(50, 150, n),
        }
    )
    worse = table.assign(cap_depth_mae_um=table["cap_depth_mae_um"] + 20)
    summary = crossval.summarise(
        {"model": table, "lookup": worse}, {}, cv_folds.CVSettings.of(bootstrap=500), seed=0
    )
    model = summary["model"]
    for metric in crossval.METRICS:
        lo, hi = model["interval95"][metric]
        assert lo < model[metric] < hi
    # a constant difference between the methods: a paired interval of zero width
    diff = model["versus_lookup"]["cap_depth_mae_um"]
    assert diff["difference"] == pytest.approx(-20)
    assert diff["interval95"] == pytest.approx([-20, -20])
    assert [f["n_test_images"] for f in model["folds"]] == [10, 10, 10]
    assert model["n_test_images"] == n


def test_duplicate_presses_bound_the_label_noise():
    folds = pd.DataFrame({"center_x_px": [0, 1, 50, 50.5], "center_y_px": [0, 0, 0, 0]})
    spread = crossval.label_spread_from_duplicates(folds, np.array([40, 44, 40, 38]), within_px=3)
    assert spread["pairs"] == 2
    assert spread["radius_sigma_px"] == pytest.approx(math.sqrt((16 + 4) / 2) / math.sqrt(2))


# ------------------------------------------------------------------------- end to end, any sensor
def run_cv(trainset, tmp_path, folds=3):
    cv = {"folds": folds, "bootstrap": 200, "label_draws": 3}
    cv_folds.write_folds(trainset, cv, 0, tmp_path / "folds.csv", where="the folder")
    methods = {
        m: imported_jobs.method_settings({"model": TINY}, m) for m in imported_jobs.CV_METHODS
    }
    for fold in range(folds):
        out = {m: tmp_path / m / f"fold{fold}" for m in methods}
        crossval.train_fold_methods(
            trainset, tmp_path / "folds.csv", fold, methods, 0, 1, out, progress=False
        )
    models = {m: [tmp_path / m / f"fold{f}" / "model.pt" for f in range(folds)] for m in methods}
    return ball_eval(
        trainset,
        tmp_path / "folds.csv",
        models,
        cv,
        0,
        1,
        tmp_path / "ball_eval.json",
        tmp_path / "images.csv",
        tmp_path / "errors.png",
        preset="compact",
    )


def test_a_users_ball_folder_is_cross_validated_end_to_end(tmp_path):
    make_ball_folder(tmp_path / "balls", n=9)
    result = run_cv(trainset_of(tmp_path / "balls", tmp_path), tmp_path)
    written = json.loads((tmp_path / "ball_eval.json").read_text())
    assert written == json.loads(json.dumps(result))
    for key in ("gradient_rmse", "cap_depth_mae_um", "n_test_images", "lookup", "interval95"):
        assert key in written
    assert written["n_test_images"] == written["lookup"]["n_test_images"] == 9
    assert written["protocol"]["folds"] == 3 and sum(written["protocol"]["fold_sizes"]) == 9
    lo, hi = written["interval95"]["cap_depth_mae_um"]
    assert lo <= written["cap_depth_mae_um"] <= hi
    assert "versus_lookup" in written and "label_uncertainty" in written
    images = pd.read_csv(tmp_path / "images.csv")
    assert sorted(images["method"].unique()) == ["lookup", "model"]
    assert (
        images.groupby("method")["frame"].apply(sorted).map(list).tolist() == [list(range(9))] * 2
    )
    assert (tmp_path / "errors.png").stat().st_size > 0


def test_a_py3dcal_dataset_keeps_each_coordinate_in_one_fold(tmp_path):
    make_py3dcal_folder(tmp_path / "py3dcal")
    trainset = trainset_of(tmp_path / "py3dcal", tmp_path, fmt="py3dcal")
    cv = {"folds": 3, "group_fraction": 0.0}
    table = cv_folds.write_folds(trainset, cv, 0, tmp_path / "folds.csv")
    pairs = table["fold"].to_numpy().reshape(-1, 2)
    assert (pairs[:, 0] == pairs[:, 1]).all()  # both depths of a coordinate in the same fold
    assert sorted(table["fold"].unique()) == [0, 1, 2]


def test_folders_that_cannot_support_the_evaluation_say_why(tmp_path):
    make_ball_folder(tmp_path / "few", n=4)
    with pytest.raises(ConfigError, match="the folder: 4 labelled image"):
        cv_folds.write_folds(
            trainset_of(tmp_path / "few", tmp_path),
            {"folds": 6},
            0,
            tmp_path / "f.csv",
            "the folder",
        )
    make_ball_folder(tmp_path / "nobg", n=4, background=False)
    with pytest.raises(ConfigError, match=r"background.png: missing \(blank frame\)"):
        trainset_of(tmp_path / "nobg", tmp_path / "x")
    make_ball_folder(tmp_path / "nolabels", n=4, labels=False)
    with pytest.raises(ConfigError, match=r"labels.csv: missing"):
        trainset_of(tmp_path / "nolabels", tmp_path / "y")
