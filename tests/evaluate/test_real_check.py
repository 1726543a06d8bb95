"""Shipped weights on real frames (threedcal.evaluate.real_check): each frame's contact against the
ball's bound, its centroid against the located contact and its peak against the press, on a
synthetic folder whose answers are known."""

import json
import math

import cv2
import numpy as np
import pandas as pd
import pytest
from conftest import write_untrained_model

from threedcal.evaluate.real_check import (
    FINETUNED,
    SHIPPED,
    check_sets,
    frame_rows,
    load_real_set,
    table_figures,
)
from threedcal.model.inference import DepthEstimator

PX_PER_MM, BALL_MM = 10.0, 2.0
# contact centres (x, y) in the folder's 240 x 320 portrait frames, whole pixels once pooled by 2
# (so every disc is symmetric on its pixels); radius 14 px
CENTRES = [
    (60.5, 80.5),
    (180.5, 80.5),
    (60.5, 240.5),
    (180.5, 240.5),
    (120.5, 160.5),
    (100.5, 120.5),
]
RADIUS_PX = 14.0


def _folder(path, labelled: bool):
    """A ball folder: a smooth blank and frames with one uniformly brighter disc per contact."""
    path.mkdir()
    height, width = 320, 240
    yy, xx = np.mgrid[:height, :width].astype(float)
    blank = np.stack([100 + 0.1 * xx, 120 + 0.05 * yy, 110 + 0 * xx], axis=-1)
    cv2.imwrite(str(path / "background.png"), blank[..., ::-1].round().astype(np.uint8))
    names = []
    for k, (cx, cy) in enumerate(CENTRES):
        nx, ny = (xx - cx) / RADIUS_PX, (yy - cy) / RADIUS_PX
        frame = blank + np.where((nx**2 + ny**2 < 1)[..., None], 40.0, 0.0)
        names.append(f"{k:04d}.png")
        cv2.imwrite(str(path / names[-1]), frame.clip(0, 255).round()[..., ::-1].astype(np.uint8))
    (path / "dataset.yaml").write_text(
        f"px_per_mm: {PX_PER_MM}\nball_radius_mm: {BALL_MM}\nsource: synthetic\nlicense: none\n"
        "turn_to_sensor: counterclockwise\n"
    )
    if labelled:
        rows = [f"{n},{cx},{cy},{RADIUS_PX}" for n, (cx, cy) in zip(names, CENTRES, strict=True)]
        (path / "labels.csv").write_text(
            "image,center_x_px,center_y_px,radius_px\n" + "\n".join(rows)
        )
    return path


@pytest.fixture
def shipped(tmp_path):
    """A 'shipped' compact_tiny for sensor `fake` (landscape 120 x 160: the folder is turned)."""
    weights = tmp_path / "weights"
    weights.mkdir()
    write_untrained_model(
        weights / "fake.pt", "compact_tiny", np.zeros((120, 160, 3)), px_per_mm=5.0
    )
    model = {
        "preset": "compact_tiny",
        "batch_size": 2,
        "patch_px": 32,
        "contact_patches": 1,
        "background_patches": 1,
        "loss": "huber",
        "lr": 1e-3,
    }
    record = {"image_shape": [120, 160], "downscale": 2, "pretraining": {"model": model}}
    (weights / "fake.json").write_text(json.dumps(record))
    return weights


def test_each_frames_contact_centroid_and_peak_against_what_the_ball_allows(
    tmp_path, shipped, monkeypatch
):
    """The model's depth is replaced by known caps: frame k's contact is a disc of (k + 1) x 4 px
    radius in the weights' frame, 1 px right of the located contact; its peak 0.5 mm."""
    ts, located = load_real_set(_folder(tmp_path / "set", labelled=False))
    assert "locate_contact" in located and "6 of 6 frames" in located
    assert len(ts.frames) == len(CENTRES) and ts.samples["located"].all()
    # located from the image: the disc's own centre, exactly (a uniform disc's centroid)
    np.testing.assert_allclose(ts.center_px, CENTRES, atol=0.05)
    assert set(ts.split) == {"train", "val"}  # two halves by place

    def depth(self, frames):
        out = []
        for k, _ in enumerate(frames):
            h, w = self.image_shape
            yy, xx = np.mgrid[:h, :w].astype(float)
            # the located contact in the weights' frame: pooled by 2, then turned a quarter
            x, y = CENTRES[k]
            cx, cy = ((y + 0.5) / 2 - 0.5) + 1.0, (h - 1) - ((x + 0.5) / 2 - 0.5)
            out.append(np.where(np.hypot(xx - cx, yy - cy) <= (k + 1) * 4, 0.5, 0.0))
        return np.stack(out)

    monkeypatch.setattr(DepthEstimator, "depth", depth)
    rows = frame_rows(ts, shipped / "fake.pt", range(len(CENTRES)))
    bound = math.pi * (BALL_MM * PX_PER_MM / 2) ** 2  # 100 pi px at 5 px/mm
    assert rows["bound_px"].to_numpy() == pytest.approx(bound, abs=0.05)
    radii = (np.arange(len(CENTRES)) + 1) * 4
    assert (rows["within_bound"] == (rows["area_px"] <= bound)).all()
    assert rows["within_bound"].tolist() == [r <= 10 for r in radii]  # discs of 4 .. 24 px
    np.testing.assert_allclose(rows["centroid_error_mm"], 1.0 / 5.0, atol=0.01)  # 1 px
    assert (rows["peak_mm"] == 0.5).all()
    # allowed: the cap depth of the located radius (14 px = 1.4 mm of a 2 mm ball)
    np.testing.assert_allclose(rows["allowed_mm"], 2.0 - math.sqrt(4.0 - 1.4**2), atol=0.02)
    assert rows["peak_within"].all()


def test_the_stage_reads_every_set_and_fine_tunes_where_it_has_labels(tmp_path, shipped):
    sets = [
        {"real": str(_folder(tmp_path / "plain", labelled=False)), "sensor": "fake"},
        {"real": str(_folder(tmp_path / "labelled", labelled=True)), "sensor": "fake"},
    ]
    table, frames = check_sets(sets, tmp_path / "work", 4, 1e-3, 0, 1, weights_dir=shipped)
    by = {(r.set.split("/")[-1], r.weights, r.frames_read): r for r in table.itertuples()}
    assert set(by) == {
        ("plain", SHIPPED, "held-out half"),
        ("plain", SHIPPED, "all"),
        ("labelled", SHIPPED, "held-out half"),
        ("labelled", SHIPPED, "all"),
        ("labelled", FINETUNED, "held-out half"),  # only a labelled set is fine-tuned
    }
    assert by[("plain", SHIPPED, "all")].frames == len(CENTRES)
    held_out = by[("plain", SHIPPED, "held-out half")].frames
    assert 0 < held_out < len(CENTRES)
    assert (tmp_path / "work" / "labelled" / "model.pt").is_file()
    assert not (tmp_path / "work" / "plain").exists()
    assert isinstance(frames, pd.DataFrame) and set(frames["half"]) == {"fit", "check"}
    assert len(frames) == 3 * len(CENTRES)  # plain once, labelled shipped and fine-tuned


def test_frames_without_a_located_contact_count_for_area_not_for_centroid():
    rows = pd.DataFrame(
        {
            "area_ratio": [0.5, 0.9, 1.2, 0.8],
            "within_bound": [True, True, False, True],
            "centroid_error_mm": [0.1, np.nan, 0.3, 0.15],
            "peak_mm": [1.0, 1.2, 1.4, 0.9],
            "allowed_mm": [1.5, 1.5, 1.5, 1.5],
            "peak_within": [True, True, True, True],
        }
    )
    figures = table_figures(rows)
    assert figures["frames"] == 4 and figures["within_bound"] == 0.75
    assert figures["centroid_frames"] == 3
    assert figures["centroid_error_mm_median"] == pytest.approx(0.15)
    assert figures["centroid_within_0p2mm"] == pytest.approx(2 / 3)
    none = table_figures(rows.assign(centroid_error_mm=np.nan))
    assert none["centroid_frames"] == 0 and math.isnan(none["centroid_error_mm_median"])
