"""Sim-to-real stage (threedcal.evaluate.sim2real): simulated presses, nested k subsets, same budget,
errors against k, and clear errors for folders and settings that cannot support it."""

import dataclasses

import numpy as np
import pandas as pd
import pytest
import torch
from test_crossval import (
    BALL_MM,
    PX_PER_MM,
    TINY,
    make_ball_folder,
    make_py3dcal_folder,
    trainset_of,
)

from threedcal.dataset import folds as cv_folds
from threedcal.dataset.labels import contact_radius_mm
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.evaluate import sim2real, sim2real_scores, sim2real_settings, sim2real_simulate
from threedcal.model.checkpoint import read_checkpoint
from threedcal.study import imported_jobs

S2R = {
    "frames": 6,
    "depth_mm": [0.4, 0.9],
    "profile": "as_is",
    "pretrain_epochs": 1,
    "finetune_epochs": 1,
}


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """A user's ball folder (12 simulated 'real' presses), its model-ready set and 3 folds."""
    root = tmp_path_factory.mktemp("s2r")
    make_ball_folder(root / "balls", n=12)
    trainset = trainset_of(root / "balls", root)
    cv_folds.write_folds(trainset, {"folds": 3}, 0, root / "folds.csv")
    return root, trainset


def test_simulated_presses_match_the_real_set_and_are_labelled_exactly(real):
    root, trainset = real
    profile = imported_jobs.sensor_profile({"sensor": "gelsight_mini"})
    sim = sim2real_simulate.write_simulated(trainset, profile, S2R, 3, root / "sim", progress=False)
    again = sim2real_simulate.simulate_trainset(
        TrainingSet.load(trainset), profile, sim2real_settings.SimToRealSettings.of(**S2R), 3, False
    )
    ts = TrainingSet.load(root / "sim")
    real_ts = TrainingSet.load(trainset)
    assert ts.image_shape == real_ts.image_shape and ts.px_per_mm == PX_PER_MM
    assert ts.sphere_radius_mm == BALL_MM and len(ts.frames) == 6
    assert np.array_equal(ts.frames, again.frames)  # seeded: same config, same bytes
    assert list(ts.split).count("val") == 1
    assert ((ts.depth_mm >= 0.4) & (ts.depth_mm <= 0.9)).all()
    # the whole contact inside the image
    reach = np.array([contact_radius_mm(BALL_MM, d) for d in ts.depth_mm]) * PX_PER_MM
    height, width = ts.image_shape
    assert (ts.center_px - reach[:, None] >= 0).all()
    assert (ts.center_px[:, 0] + reach <= width - 1).all()
    assert (ts.center_px[:, 1] + reach <= height - 1).all()
    # the press is where its label says: the colour change peaks inside the contact
    for i in range(len(ts.frames)):
        change = np.abs(ts.frames[i].astype(float) - ts.blank).sum(axis=2)
        rows, cols = np.indices(change.shape)
        inside = np.hypot(cols - ts.center_px[i, 0], rows - ts.center_px[i, 1]) <= reach[i]
        assert change[inside].mean() > 3 * change[~inside].mean()
    assert sim.meta["source"] == "simulated gelsight_mini presses"


def _fitted_frames(profile_yaml):
    head = profile_yaml.read_text().splitlines()[0]
    return {int(name[len("frame") :]) for name in head.split("(")[1].split(")")[0].split(", ")}


def test_fitted_profile_sees_only_the_folds_training_images(real, tmp_path):
    """profile: fitted (the default) fits the optics to the frames outside the held-out folds and
    the blank: the fitted profile names them, and no test frame of those folds."""
    root, trainset = real
    folds = pd.read_csv(root / "folds.csv")
    profile = imported_jobs.sensor_profile({"sensor": "gelsight_mini"})
    fitted = {**S2R, "profile": "fitted"}
    with pytest.raises(ConfigError, match="needs the scene's folds"):
        sim2real_simulate.write_simulated(trainset, profile, fitted, 3, tmp_path / "none", False)
    sims = {}
    for group in ((0,), (1,), (0, 1)):
        out = tmp_path / sim2real_settings.group_name(group)
        sims[group] = sim2real_simulate.write_simulated(
            trainset, profile, fitted, 3, out, False, folds_path=root / "folds.csv", held_out=group
        )
        named = _fitted_frames(out / "profile.yaml")
        assert named == set(folds.loc[~folds["fold"].isin(group), "frame"])
        assert not named & set(folds.loc[folds["fold"].isin(group), "frame"])
    as_is = sim2real_simulate.write_simulated(trainset, profile, S2R, 3, tmp_path / "as_is", False)
    # Same seed, same presses; only the optics differ, per fold and from the built-in profile.
    assert np.array_equal(sims[(0,)].center_px, as_is.center_px)
    assert not np.array_equal(sims[(0,)].frames, as_is.frames)
    assert not np.array_equal(sims[(0,)].frames, sims[(1,)].frames)
    assert not np.array_equal(sims[(0, 1)].frames, sims[(0,)].frames)


def test_folds_share_a_pretraining_when_their_fit_can_leave_them_all_out():
    """One simulated set and pretraining for the chosen folds when some folds are left out (fitted
    to those, on which every chosen fold trains); one per fold when all are chosen; one for all
    with profile: as_is (no real image seen)."""
    of = sim2real_settings.SimToRealSettings.of
    assert sim2real_settings.pretraining_groups(of(folds=[2, 0, 1]), 6) == [(0, 1, 2)]
    assert sim2real_settings.pretraining_groups(of(), 3) == [(0,), (1,), (2,)]
    assert sim2real_settings.pretraining_groups(of(profile="as_is"), 3) == [(0, 1, 2)]
    assert sim2real_settings.group_name((0, 1, 2)) == "0-1-2"
    assert sim2real_settings.parse_group("0-1-2") == (0, 1, 2)
    with pytest.raises(ConfigError, match="not a group of folds"):
        sim2real_settings.parse_group("a-b")
    scene = {"cv": {"folds": 6}, "sim_to_real": {"folds": [0, 1, 2]}}
    assert imported_jobs.group_of(scene, 1) == "0-1-2"
    assert imported_jobs.group_of({"cv": {"folds": 3}, "sim_to_real": {}}, 1) == "1"
    with pytest.raises(ConfigError, match="fold 4 is not evaluated"):
        imported_jobs.group_of(scene, 4)


def test_a_py3dcal_layout_import_is_fitted_the_same_way_and_too_few_images_say_why(tmp_path):
    make_py3dcal_folder(tmp_path / "py3dcal")
    trainset = trainset_of(tmp_path / "py3dcal", tmp_path, fmt="py3dcal")
    folds = cv_folds.write_folds(
        trainset, {"folds": 3, "group_fraction": 0.0}, 0, tmp_path / "folds.csv"
    )
    profile = imported_jobs.sensor_profile({"sensor": "gelsight_mini"})
    fitted = {**S2R, "profile": "fitted"}
    out = tmp_path / "sim"
    sim2real_simulate.write_simulated(
        trainset, profile, fitted, 0, out, False, folds_path=tmp_path / "folds.csv", held_out=[2]
    )
    assert _fitted_frames(out / "profile.yaml") == set(folds.loc[folds["fold"] != 2, "frame"])
    # Two training images cannot pin the optics down: the error says which key to change.
    two = folds.assign(fold=np.where(folds["frame"] < 2, 1, 0))
    two.to_csv(tmp_path / "two.csv", index=False)
    with pytest.raises(ConfigError, match="2 training images lie outside fold 0.*profile: as_is"):
        sim2real_simulate.write_simulated(
            trainset,
            profile,
            fitted,
            0,
            tmp_path / "x",
            False,
            folds_path=tmp_path / "two.csv",
            held_out=[0],
        )


def test_k_subsets_of_a_fold_are_nested_and_k_cannot_exceed_the_pool(real):
    root, trainset = real
    ts = TrainingSet.load(trainset)
    folds = cv_folds.read_folds(root / "folds.csv", ts)
    pool = int((folds["fold"] != 0).sum())
    picked = {
        k: set(np.flatnonzero(cv_folds.fold_trainset(ts, folds, 0, k, 5).split == "train"))
        for k in (2, 4, pool)
    }
    assert len(picked[2]) == 2 and picked[2] < picked[4] < picked[pool]
    assert sim2real.n_train_of(folds, 0, "all") == pool
    with pytest.raises(
        ConfigError, match=f"fold 0 has {pool} real training images, fewer than k = 99"
    ):
        sim2real.n_train_of(folds, 0, 99)


def test_fine_tuning_starts_from_the_pretrained_model_with_the_same_steps(real, tmp_path):
    root, trainset = real
    sim_dir = tmp_path / "sim"
    sim2real_simulate.write_simulated(
        trainset, imported_jobs.sensor_profile({"sensor": "gelsight_mini"}), S2R, 0, sim_dir, False
    )
    sim2real.pretrain(sim_dir, TINY, S2R, 0, 1, tmp_path / "pre", progress=False)
    pre = tmp_path / "pre" / "model.pt"
    runs = {}
    still = {**TINY, "lr": 1e-12}  # fine-tuning that cannot move the weights: where did it start?
    for condition, init, k in (
        ("sim_real", pre, 2),
        ("real_only", None, 2),
        ("real_only", None, "all"),
    ):
        out = tmp_path / condition / str(k)
        runs[condition, k] = sim2real.train_k(
            trainset, root / "folds.csv", 0, k, condition, still, S2R, 0, 1, out, init, False
        )
    pool = 8  # 12 images, 3 folds of 4
    # k images train pool / k times the epochs of all of them: the same optimiser steps
    assert runs["sim_real", 2]["training"]["epochs"] == pool // 2
    assert runs["real_only", 2]["training"]["epochs"] == pool // 2
    assert runs["real_only", "all"]["training"]["epochs"] == 1
    assert runs["sim_real", 2]["training"]["settings"]["init"] == str(pre)
    assert "init" not in runs["real_only", 2]["training"]["settings"]
    # fine-tuning started from the pretrained weights, not from a fresh initialisation
    start = read_checkpoint(pre)["state_dict"]
    tuned = read_checkpoint(tmp_path / "sim_real" / "2" / "model.pt")["state_dict"]
    scratch = read_checkpoint(tmp_path / "real_only" / "2" / "model.pt")["state_dict"]
    weights = [k for k, v in start.items() if v.dtype.is_floating_point and v.numel() > 100]
    assert all(torch.allclose(tuned[k], start[k], atol=1e-6) for k in weights)
    assert not all(torch.allclose(scratch[k], start[k], atol=1e-6) for k in weights)
    # one job trains every k of a (condition, fold), each the model train_k makes alone
    both = {**S2R, "k": [2, "all"]}
    sim2real.train_fold_ks(
        trainset,
        root / "folds.csv",
        0,
        "real_only",
        still,
        both,
        0,
        1,
        tmp_path / "f0",
        None,
        False,
    )
    for k in (2, "all"):
        alone = read_checkpoint(tmp_path / "real_only" / str(k) / "model.pt")["state_dict"]
        looped = read_checkpoint(sim2real.k_model(tmp_path / "f0", k))["state_dict"]
        assert all(torch.equal(alone[name], looped[name]) for name in alone)
    with pytest.raises(ConfigError, match="sim_real needs"):
        sim2real.train_k(
            trainset, root / "folds.csv", 0, 2, "sim_real", TINY, S2R, 0, 1, tmp_path / "x"
        )


def test_errors_against_k_pool_folds_with_intervals_and_a_perfect_model_scores_zero(real, tmp_path):
    root, trainset = real
    ts = TrainingSet.load(trainset)
    folds = cv_folds.read_folds(root / "folds.csv", ts)
    rows = []
    for condition, offset in (("sim+real", 0.0), ("real-only", 0.1)):
        for k in ("2", "all"):
            for frame, fold, group in folds[["frame", "fold", "group"]].itertuples(index=False):
                rows.append(
                    {
                        "condition": condition,
                        "k": k,
                        "fold": fold,
                        "frame": frame,
                        "group": group,
                        "gradient_mse": offset**2,
                        "cap_depth_mae_um": 1000 * offset,
                        "predicted_at": f"{condition} frame",
                    }
                )
    errors = sim2real_scores.summarise_k(pd.DataFrame(rows), folds, 200, 0, scored_at="80x64 px")
    pooled = errors[errors["fold"] == "all"].set_index(["condition", "k"])
    assert pooled.loc[("sim+real", "2"), "gradient_rmse"] == 0
    assert pooled.loc[("real-only", "all"), "cap_depth_mae_um"] == pytest.approx(100)
    assert pooled.loc[("real-only", "all"), "n_train"] == 8
    assert pooled.loc[("real-only", "2"), "cap_depth_mae_um_lo"] == pytest.approx(100)
    assert len(errors) == 4 * (3 + 1)  # per fold and pooled, per (condition, k)
    # every row names the frame its model predicted in and the one it was scored at
    assert set(errors["scored_at"]) == {"80x64 px"}
    assert set(pooled.loc["real-only", "predicted_at"]) == {"real-only frame"}
    sim2real_scores.error_figure(errors, tmp_path / "e.png", "test")
    assert (tmp_path / "e.png").stat().st_size > 0


def test_settings_and_scenes_that_cannot_support_it_say_why(real, tmp_path):
    root, trainset = real
    with pytest.raises(ConfigError, match="deeper than the ball's radius"):
        sim2real_simulate.write_simulated(
            trainset,
            imported_jobs.sensor_profile({"sensor": "gelsight_mini"}),
            {"depth_mm": [0.5, 2.5], "profile": "as_is"},
            0,
            tmp_path / "a",
            False,
        )
    small = TrainingSet.load(trainset)
    small = dataclasses.replace(
        small, frames=small.frames[:, :30, :30], blank=small.blank[:30, :30], samples=small.samples
    )
    with pytest.raises(ConfigError, match="too wide for the 30 x 30 px images"):
        sim2real_simulate.simulate_trainset(
            small,
            imported_jobs.sensor_profile({"sensor": "gelsight_mini"}),
            sim2real_settings.SimToRealSettings.of(depth_mm=[0.5, 1.9]),
            0,
            False,
        )
    with pytest.raises(ConfigError, match="sim_to_real.folds: \\[7\\] outside the 3"):
        sim2real_settings.chosen_folds(sim2real_settings.SimToRealSettings.of(folds=[0, 7]), 3)
    with pytest.raises(ConfigError, match="sim_to_real"):
        sim2real_settings.SimToRealSettings.of(k=[0])
    # a folder without a blank frame is refused by the import, before any simulation
    make_ball_folder(tmp_path / "nobg", n=4, background=False)
    with pytest.raises(ConfigError, match=r"background.png: missing \(blank frame\)"):
        trainset_of(tmp_path / "nobg", tmp_path / "y")


def mini_set(trainset, tmp_path):
    """The fixture's set as the import stage writes it for a gelsight_mini scene (meta.sensor)."""
    ts = TrainingSet.load(trainset)
    ts.meta = {**(ts.meta or {}), "sensor": "gelsight_mini"}
    ts.save(tmp_path / "mini")
    return tmp_path / "mini"


def fake_shipped(ts_dir, directory):
    """A weights folder as threedcal.pretrained ships it, for this set's sensor at half its frame
    turned a quarter (32 x 40 for the 80 x 64 portrait frames): fresh compact weights, no blank."""
    import json

    from threedcal.dataset.reframe import reframe
    from threedcal.model.checkpoint import save_checkpoint
    from threedcal.model.train import save_initial
    from threedcal.model.train_settings import TrainSettings

    recipe = {
        **TINY,
        "patch_px": 16,
        "batch_size": 4,
        "stopping": {
            "rule": "epochs",
            "holdout": 0.2,
            "first_cycle": 2,
            "max_steps": 8,
            "min_gain": 0.05,
        },
    }
    framed, _ = reframe(TrainingSet.load(ts_dir), (32, 40), "test")
    directory.mkdir(parents=True, exist_ok=True)
    settings = TrainSettings.of(**recipe, seed=5, torch_threads=1)
    checkpoint = save_initial(framed, directory / "gelsight_mini.pt", settings)
    checkpoint["blank"] = None
    save_checkpoint(directory / "gelsight_mini.pt", checkpoint)
    record = {
        "sensor": "gelsight_mini",
        "image_shape": [32, 40],
        "downscale": 2,
        "preset": "compact",
        "pretraining": {"model": recipe},
    }
    (directory / "gelsight_mini.json").write_text(json.dumps(record))
    return directory / "gelsight_mini.pt"


def test_shipped_weights_fine_tune_on_the_same_k_images_in_their_frame_and_score_back(
    real, tmp_path
):
    root, trainset = real
    trainset = mini_set(trainset, tmp_path)
    weights = fake_shipped(trainset, tmp_path / "shipped")
    still = {"shipped": True, "shipped_lr": 1e-12}  # cannot move the weights: where did it start?
    out = tmp_path / "k4"
    checkpoint = sim2real.train_shipped(
        trainset, root / "folds.csv", 1, 4, still, 0, 1, out, False, weights_dir=weights.parent
    )
    assert (out / "losses.csv").is_file()
    assert checkpoint["training"]["reframe"] == {
        "full_shape": [80, 64],
        "factor": 2,
        "turned": True,
    }
    assert tuple(checkpoint["image_shape"]) == (32, 40)
    trained = checkpoint["training"]
    assert trained["settings"]["init"] == str(weights) and trained["settings"]["lr"] == 1e-12
    # the model's own holdout decides how long: the k images split between fitting and judging
    assert trained["settings"]["stopping"]["rule"] == "doubling"
    assert trained["fit_frames"] + trained["holdout_frames"] == 4
    start = read_checkpoint(weights)["state_dict"]
    tuned = read_checkpoint(out / "model.pt")["state_dict"]
    assert all(torch.allclose(tuned[k], start[k], atol=1e-6) for k in start)
    # scored at the set's own frame: gradients brought back to 80 x 64 and integrated there
    ts = TrainingSet.load(trainset)
    folds = cv_folds.read_folds(root / "folds.csv", ts)
    test = folds.loc[folds["fold"] == 1, "frame"]
    frames, predicted_at = sim2real_scores.predict_frames(ts, test, out / "model.pt", 1)
    assert predicted_at == "32x40 px (80x64 pooled 2x, turned a quarter)"
    grads, depth = frames[int(test.iloc[0])]
    assert grads.shape == (80, 64, 2) and depth.shape == (80, 64)
    images = sim2real_scores.score_models(
        ts, folds, {("shipped+real", "4"): {1: out / "model.pt"}}, 1
    )
    assert set(images["predicted_at"]) == {predicted_at} and len(images) == len(test)
    # another set's frames are not the ones it was trained on
    wide = dataclasses.replace(
        ts, frames=np.tile(ts.frames, (1, 2, 2, 1)), blank=np.tile(ts.blank, (2, 2, 1))
    )
    with pytest.raises(ConfigError, match="not the set it was trained on"):
        sim2real_scores.predict_frames(wide, test, out / "model.pt", 1)


def test_shipped_weights_are_refused_for_a_sensor_without_them_or_frames_that_cannot_reach_them(
    real, tmp_path
):
    root, trainset = real
    trainset = mini_set(trainset, tmp_path)
    weights = fake_shipped(trainset, tmp_path / "shipped")
    ts = TrainingSet.load(trainset)
    other = dataclasses.replace(ts, meta={**ts.meta, "sensor": "digit"})
    with pytest.raises(
        ConfigError, match="sim_to_real.shipped: no shipped weights for sensor 'digit'"
    ):
        sim2real.shipped_for(other, weights.parent)
    record = weights.with_suffix(".json")
    record.write_text(record.read_text().replace("[32, 40]", "[30, 30]"))
    with pytest.raises(ConfigError, match="sim_to_real.shipped: 80 x 64 px frames .* 30 x 30"):
        sim2real.train_shipped(
            trainset,
            root / "folds.csv",
            1,
            4,
            {"shipped": True},
            0,
            1,
            tmp_path / "x",
            False,
            weights_dir=weights.parent,
        )
    assert not (tmp_path / "x").exists()
    # the condition is trained and scored only when asked for
    assert "shipped_real" not in sim2real_settings.SimToRealSettings.of().conditions
    scene = {"cv": {"folds": 3}, "sim_to_real": {"shipped": True, "k": [4], "folds": [1]}}
    inputs = imported_jobs.sim2real_inputs("balls", scene)
    assert inputs["shipped_real"] == ["results/balls/sim2real/shipped_real/fold1"]
