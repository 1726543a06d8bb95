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
    rows = []
    for protocol, shift in (("printer", 0.0), ("paper", -20.0)):
        for p, (overall, type1, type2) in ((80, (20.0, 5.0, 61.0)), (20, (30.0, 6.0, 90.0))):
            row = {"object": "pill", "P": p, "protocol": protocol, "presses": 10}
            for metric, value in zip(
                ("overall_um", "type1_um", "type2_um"), (overall, type1, type2 + shift), strict=True
            ):
                row.update({metric: value, f"{metric}_lo": value - 4, f"{metric}_hi": value + 4})
            rows.append({**row, "depth_ratio": 1.0 if protocol == "printer" else 0.9})
    pd.DataFrame(rows).to_csv(root / "a/objects/errors.csv", index=False)
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
    # P = 80 with its intervals, Type 2 at P = 20; the printer protocol first, then the paper's
    printer = "| printer | pill | 20 [16, 24] | 5 [1, 9] | 61 [57, 65] | 90 [86, 94] | 1.000 |"
    paper = "| paper | pill | 20 [16, 24] | 5 [1, 9] | 41 [37, 45] | 70 [66, 74] | 0.900 |"
    assert printer in text and paper in text and text.index(printer) < text.index(paper)
    assert "10 or more per object" in text
    assert "gradient RMSE 0.300 [0.280, 0.320] (lookup 0.370)" in text
    assert "cap depth MAE 200 [180, 221] µm (lookup 250 µm), 42 images, 6 grouped folds" in text
    assert (tmp_path / "summary.md").read_text() == text
