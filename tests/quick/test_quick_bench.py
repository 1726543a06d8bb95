"""The quick calibration on the simulated bench, end to end with a tiny network and budget."""

import json

import numpy as np
import pandas as pd
import pytest
import zarr
from conftest import snapshot

from threedcal.collect.store import StoreError
from threedcal.collect.store_read import open_checked
from threedcal.model.inference import DepthEstimator
from threedcal.profiles import load_profile
from threedcal.sim.bench import draw_truth
from threedcal.study.config import validate_config
from threedcal.study.quick_loop import ROUND_COLUMNS, quick_stage


def scene(margin: float) -> dict:
    config = {
        "seed": 2,
        "torch_threads": 1,
        "scenes": {
            "q": {
                "sensor": "digit_fots",
                "printer": "ender3",
                "plan": {
                    "pattern": "quick",
                    "depth_mm": 1.0,
                    "frames": 1,
                    "round_presses": 6,
                    "max_presses": 18,
                    # each press pauses 0.25 mm deep to register; 8 presses find the gel
                    "registration": {"depth_mm": 0.25, "each_press": True},
                    "touch_search": {"method": "bisect", "presses": 8, "points": 1, "frames": 2},
                },
                "bench": {"unit": 1},
                "dataset": {"downscale": 2},
                "model": {
                    "preset": "compact_tiny",
                    "batch_size": 4,
                    "patch_px": 32,
                    "contact_patches": 2,
                    "background_patches": 1,
                    "lr": 3.0e-3,
                },
                # margin 0.99: any round that is not worth 99 % stops it, so round 2 does
                "quick": {"steps": 10, "margin": margin},
            }
        },
    }
    return validate_config(config)["scenes"]["q"]


def run(folder, margin):
    outputs = {
        "model": folder / "quick/model.pt",
        "rounds": folder / "quick/rounds.csv",
        "stop": folder / "quick/stop.json",
        "work": folder / "quick/rounds",
    }
    quick_stage(
        "q",
        scene(margin),
        store=folder / "raw.zarr",
        staging=folder / ".partial/raw.zarr",
        progress=False,
        **outputs,
    )
    return outputs


@pytest.mark.long
@pytest.mark.slow
def test_rounds_stop_record_model_and_replay(tmp_path):
    outputs = run(tmp_path, margin=0.99)
    rounds = pd.read_csv(outputs["rounds"])
    stop = json.loads(outputs["stop"].read_text())
    assert tuple(rounds.columns) == ROUND_COLUMNS
    # round 1 cannot measure an improvement; round 2's bound lies below 0.99: stopped there
    assert rounds["round"].tolist() == [1, 2] and rounds["presses"].tolist() == [6, 12]
    assert np.isnan(rounds["improvement"].iloc[0]) and rounds["decision"].iloc[0] == "continue"
    assert rounds["improvement_upper"].iloc[1] < 0.99
    assert rounds["decision"].iloc[1] == "stop: improvement below margin"
    assert (rounds["presses_scored"] == 6).all()  # every press inside the view is labelled
    assert (rounds["mse_low"] < rounds["mse"]).all() and (rounds["mse"] < rounds["mse_high"]).all()
    assert rounds["printer_s"].is_monotonic_increasing
    # each round's presses read by the model before it: the untrained start may see none
    assert rounds["contact_area_ratio"].notna().all()
    assert (rounds["contact_area_ratio"].iloc[1:] > 0).all()
    assert stop["stopped"] == "improvement below margin" and stop["presses"] == 12
    assert stop["printer_minutes"] == pytest.approx(rounds["printer_s"].iloc[-1] / 60, abs=0.01)
    # the starting weights and one model a round; the final one is usable as is
    assert sorted(p.name for p in outputs["work"].iterdir()) == ["r0", "r1", "r2"]
    estimator = DepthEstimator.from_checkpoint(outputs["model"], device="cpu")
    assert estimator.preset == "compact_tiny" and estimator.image_shape == (160, 120)
    # the store, in place and finished with the rows it holds; the rest never pressed
    store = tmp_path / "raw.zarr"
    attrs = zarr.open_group(str(store), mode="r").attrs
    captured = zarr.open_group(str(store), mode="r")["captured"][:]
    rows = attrs["captured_rows"]
    assert attrs["complete"] and captured[:rows].all() and not captured[rows:].any()
    assert len(captured) - rows == 12  # round 3 (6 presses, 2 rows each) was never collected
    # 8 presses found the gel within 0.02 mm of the bench's hidden truth, each at a depth the
    # search chose inside its window; every press registered, through the profile's lens
    assert stop["touch_presses"] == 8 and stop["presses_in_all"] == 8 + 12
    registration = stop["registration"]
    truth = draw_truth(load_profile("sensor", "digit_fots"), scene(0.99)["bench"], 2)
    assert registration["touch_method"] == "bisect"
    assert abs(registration["touch_offset_mm"] - truth.touch_offset_mm) <= 0.02
    depths = open_checked(store)["depth_mm"].values[: 8 * 2 : 2]
    assert depths[0] == pytest.approx(0.3) and (depths >= -0.2).all() and len(set(depths)) == 8
    assert registration["lens_free"] in ("none", "kappa1", "all")
    assert registration["contacts_used"] >= 5
    assert attrs["quick"]["stopped"] == "improvement below margin"
    assert attrs["runs"][-1]["ended_at_row"] == rows  # one run, ended at the round's boundary
    assert open_checked(store)["point"].values.max() == rows - 1
    assert not (tmp_path / ".partial/raw.zarr").exists()
    # a rerun replays the rounds from the store, untouched: the same decisions and model
    before = snapshot(store)
    first_model = outputs["model"].read_bytes()
    run(tmp_path, margin=0.99)
    assert snapshot(store) == before
    replayed = pd.read_csv(outputs["rounds"]).drop(columns="train_s")
    pd.testing.assert_frame_equal(replayed, rounds.drop(columns="train_s"))
    assert outputs["model"].read_bytes() == first_model
    # a stop rule that would now go on past the store is refused, naming the store
    with pytest.raises(StoreError, match="asks for more"):
        run(tmp_path, margin=0.01)
    assert snapshot(store) == before


def test_a_rounds_contact_area_is_its_median_press_over_the_probes_disc_and_warns(
    monkeypatch, caplog
):
    """The figure the rounds table records, on depth maps of known contact; a round whose median
    press reads more than the probe can touch is warned of, naming the sensor and the fix."""
    import logging
    import math
    from types import SimpleNamespace

    import threedcal.model.inference as inference
    from threedcal.study.quick_loop import QuickLoop

    shape, px_per_mm, radius = (40, 50), 5.0, 2.0  # the disc: pi 10^2 = 314 px
    areas = [100, 2000, 400, 600]  # plan rows 10..13; the round scores rows 11..13
    maps = [np.zeros(shape) for _ in areas]
    for depth, area in zip(maps, areas, strict=True):
        depth.reshape(-1)[:area] = 0.3

    class Estimator:
        def depth(self, frames):
            return np.stack([maps[int(f[0, 0, 0])] for f in frames])

    monkeypatch.setattr(
        inference.DepthEstimator, "from_checkpoint", classmethod(lambda cls, *a, **k: Estimator())
    )
    frames = np.zeros((4, *shape, 3), np.uint8)
    frames[:, 0, 0, 0] = np.arange(4)
    trainset = SimpleNamespace(
        samples=pd.DataFrame({"plan_row": [10, 11, 12, 13]}),
        frames=frames,
        sphere_radius_mm=radius,
        px_per_mm=px_per_mm,
    )
    loop = QuickLoop.__new__(QuickLoop)
    loop.sensor = {"name": "digit_fots"}
    bound = math.pi * (radius * px_per_mm) ** 2
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        ratio = loop._contact_area_ratio("model.pt", trainset, 11, 14, 3)
    assert ratio == pytest.approx(600 / bound)  # the median of 2000, 400, 600
    assert "digit_fots, quick calibration round 3" in caplog.text
    assert "600 px" in caplog.text and "Calibrate this unit" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="threedcal"):
        assert loop._contact_area_ratio("model.pt", trainset, 10, 11, 1) == pytest.approx(
            100 / bound
        )
        assert math.isnan(loop._contact_area_ratio("model.pt", trainset, 20, 30, 2))
    assert not caplog.text
