import json

import pandas as pd

from threedcal.report.summary import write_summary


def test_summary_collects_each_scenes_headline_numbers(tmp_path):
    root = tmp_path / "results"
    (root / "a/collect").mkdir(parents=True)
    (root / "a/dataset").mkdir()
    (root / "a/stats").mkdir()
    (root / "a/objects").mkdir()
    (root / "b").mkdir()
    (root / "a/collect/summary.json").write_text(
        json.dumps(
            {
                "points": 300,
                "frames": 900,
                "duration_s": 30.0,
                "frames_per_s": 30.0,
                "estimated_hardware_s": 7200,
            }
        )
    )
    (root / "a/dataset/registration.json").write_text(
        json.dumps({"residual_px": 0.1, "error_px": 0.25, "touch_offset_mm": 0.05})
    )
    (root / "a/stats/recommendation.txt").write_text("probe at least 60 points (...)\n")
    pd.DataFrame(
        [
            {"object": "pill", "P": 80, "overall_um": 20.0, "type1_um": 5.0, "type2_um": 61.0},
            {"object": "pill", "P": 20, "overall_um": 30.0, "type1_um": 6.0, "type2_um": 90.0},
        ]
    ).to_csv(root / "a/objects/errors.csv", index=False)
    (root / "b/ball_eval.json").write_text(
        json.dumps(
            {
                "gradient_rmse": 0.3,
                "cap_depth_mae_um": 200.0,
                "interval95": {"gradient_rmse": [0.28, 0.32], "cap_depth_mae_um": [180.0, 221.0]},
                "lookup": {"gradient_rmse": 0.37, "cap_depth_mae_um": 250.0},
                "n_test_images": 42,
                "protocol": {"folds": 6},
            }
        )
    )
    config = {
        "scenes": {"a": {"sensor": "digit", "description": "sim"}, "b": {"sensor": "gelsight_mini"}}
    }
    text = write_summary(config, root, tmp_path / "summary.md")
    assert "2.00 h (7200 s)" in text
    assert "0.100 px / 0.250 px" in text
    assert "probe at least 60 points" in text
    assert "| pill | 20 | 5 | 61 | 90 |" in text  # P = 80, with Type 2 at P = 20
    assert "gradient RMSE 0.300 [0.280, 0.320] (lookup 0.370)" in text
    assert "cap depth MAE 200 [180, 221] µm (lookup 250 µm), 42 images, 6 grouped folds" in text
    assert (tmp_path / "summary.md").read_text() == text
