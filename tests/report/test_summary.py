import json

import pandas as pd

from threedcal.evaluate.ablation import TEST_COLUMNS
from threedcal.report.sections.convergence import convergence_lines
from threedcal.report.summary import write_study_summary
from threedcal.study.quick_arms import arms_table, verdicts


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
    (root / "a/stats/recommendation.txt").write_text(
        "probe at least 60 points (...)\nlearning curve: ...\n"
        "the readings differ: the TOST says 60 points (P = 5 %), the curve 40 (...)\n"
    )
    pd.DataFrame(
        [
            {"quantity": "points_within_margin", "value": 12, "low": 12, "high": 30}
            | {"note": "at or below the smallest fraction"},
            {"quantity": "level", "value": 0.9},
        ]
        + [{"quantity": "observed_mse", "P": p, "points": 12 * p} for p in (1, 5, 80)]
    ).to_csv(root / "a/stats/learning_curve.csv", index=False)
    rows = []
    for protocol, shift in (("printer", 0.0), ("paper", -20.0)):
        for p, (overall, type1, type2) in ((80, (20.0, 5.0, 61.0)), (20, (30.0, 6.0, 90.0))):
            row = {"object": "pill", "P": p, "protocol": protocol, "presses": 10, "replicates": 3}
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
    (root / "b/sim2real").mkdir()
    errors = []
    for k, n_train, condition, mae in (
        ("8", 8, "sim+real", 90.0),
        ("8", 8, "real-only", 140.0),
        ("all", 35.0, "real-only", 100.0),
    ):
        for fold in ("0", "1", "all"):
            errors.append(
                {"k": k, "n_train": n_train, "condition": condition, "fold": fold}
                | {"n_test_images": 7, "gradient_rmse": 0.1, "cap_depth_mae_um": mae}
                | {"gradient_rmse_lo": 0.09, "gradient_rmse_hi": 0.11}
                | {"cap_depth_mae_um_lo": mae - 10, "cap_depth_mae_um_hi": mae + 10}
            )
    pd.DataFrame(errors).to_csv(root / "b/sim2real/errors.csv", index=False)
    config = {
        "scenes": {
            "a": {"sensor": "digit", "description": "sim"},
            "b": {
                "sensor": "gelsight_mini",
                "import": {"format": "ball_folder", "path": "x"},
                "sim_to_real": {"enabled": True},
            },
        }
    }
    text = write_study_summary(config, root, tmp_path / "summary.md")
    # the scene on real frames leads, though the config lists it second
    assert "Scenes on real sensor frames first (b); every other scene is" in text
    assert text.index("## b") < text.index("## a")
    assert "Sim-to-real (held-out real images of folds 0, 1;" in text
    assert "| 8 | sim+real | 0.100 [0.090, 0.110] | 90 [80, 100] |" in text
    assert "| all (35) | real-only | 0.100 [0.090, 0.110] | 100 [90, 110] |" in text
    assert "2.00 h (7200 s)" in text
    assert "0.100 px / 0.250 px" in text
    assert "| recommendation (equivalence test) | probe at least 60 points (...) |" in text
    assert (
        "| learning curve (stats/learning_curve.csv) | at or below 12 points (90 % interval at "
        "or below 12 to 30) |"
    ) in text
    assert (
        "| equivalence test against the curve | the readings differ: the TOST says 60 points "
        "(P = 5 %), the curve 40 (...) |"
    ) in text
    # P = 80 with its intervals, Type 2 at P = 20; the printer protocol first, then the paper's
    printer = "| printer | pill | 20 [16, 24] | 5 [1, 9] | 61 [57, 65] | 90 [86, 94] | 1.000 |"
    paper = "| paper | pill | 20 [16, 24] | 5 [1, 9] | 41 [37, 45] | 70 [66, 74] | 0.900 |"
    assert printer in text and paper in text and text.index(printer) < text.index(paper)
    assert "10 or more per object" in text
    assert "the 3 replicate models of each P [95 % interval, presses and models both" in text
    assert "gradient RMSE 0.300 [0.280, 0.320] (lookup 0.370)" in text
    assert "cap depth MAE 200 [180, 221] µm (lookup 250 µm), 42 images, 6 grouped folds" in text
    assert (tmp_path / "summary.md").read_text() == text


def test_summary_sets_the_three_test_families_side_by_side_and_names_disagreements(tmp_path):
    stats_dir = tmp_path / "results/a/stats"
    stats_dir.mkdir(parents=True)
    rows = []
    for p, paper_significant in ((5, True), (20, False)):
        for replicate in range(3):
            for test in ("t", "mannwhitney"):
                rows.append(
                    {
                        "family": "paper",
                        "test": test,
                        "P": p,
                        "replicate": replicate,
                        "significant": paper_significant,
                        "conclusion": "worse" if paper_significant else "no significant difference",
                        "relative_change": 0.3,
                    }
                )
    common = {"replicates": 3, "blocks": 6, "n": 160}
    rows += [
        {
            "family": "paired",
            "P": 5,
            "estimate": 0.3,
            "relative_change": 0.30,
            "ci_low": 0.1,
            "ci_high": 0.5,
            "p_adjusted": 0.002,
            "significant": True,
            "conclusion": "worse",
            **common,
        },
        {
            "family": "paired",
            "P": 20,
            "estimate": 0.04,
            "relative_change": 0.04,
            "ci_low": -0.1,
            "ci_high": 0.2,
            "p_adjusted": 0.4,
            "significant": False,
            "conclusion": "no significant difference",
            **common,
        },
        {
            "family": "equivalence",
            "P": 5,
            "estimate": 0.3,
            "relative_change": 0.30,
            "ci_low": 0.2,
            "ci_high": 0.4,
            "significant": False,
            "conclusion": "not equivalent: a larger P is not",
            **common,
        },
        {
            "family": "equivalence",
            "P": 20,
            "estimate": 0.04,
            "relative_change": 0.04,
            "ci_low": -0.05,
            "ci_high": 0.15,
            "significant": False,
            "conclusion": "not equivalent: the interval is wider than the margin allows (too little "
            "power)",
            **common,
        },
    ]
    rows += [  # the placebo: P = 80 % against itself, r0 with r1 flagged by U only
        {
            "family": "placebo",
            "test": test,
            "P": 80,
            "replicate": 1,
            "against": 0,
            "relative_change": -0.12,
            "significant": test == "mannwhitney",
        }
        for test in ("t", "mannwhitney")
    ]
    pd.DataFrame(rows, columns=TEST_COLUMNS).to_csv(stats_dir / "tests.csv", index=False)
    pd.DataFrame(
        [
            {
                "P": p,
                "replicates": r,
                "spacing_mm": s,
                "validation_points": n,
                "power_equivalence": power,
            }
            for p in (5, 20)
            for r, s, n, power in ((3, 0.5, 160, 0.4), (5, 0.5, 160, 0.85), (5, 1.0, 40, 0.6))
        ]
    ).to_csv(stats_dir / "power.csv", index=False)
    text = write_study_summary(
        {"scenes": {"a": {"sensor": "digit"}}}, tmp_path / "results", tmp_path / "summary.md"
    )
    assert "| 5 | +30.0 % | 3/3 / 3/3 | worse (p = 0.002, interval +10.0 % to +50.0 %)" in text
    assert next(row for row in text.splitlines() if row.startswith("| 5 |")).count("| agree |")
    line = next(row for row in text.splitlines() if row.startswith("| 20 |"))
    assert "0/3 / 0/3" in line
    assert (
        "disagree: the paper's tests find no difference, yet equivalence is not shown "
        "(interval -5.0 % to +15.0 %)" in line
    )
    assert "5 replicates at 0.5 mm (160 validation points): 85%" in line
    assert (
        "Placebo (`family = placebo`): the paper's tests between two trainings of P = 80 % (the "
        "same fraction: no effect of P): t significant in 0 of 1 pairs, U in 1 of 1; their mean "
        "MSE differ by 12.0 %." in text
    )


def test_summary_states_the_convergence_check_per_fraction(tmp_path):
    path = tmp_path / "convergence.csv"
    assert convergence_lines(path) == []
    pd.DataFrame(
        {
            "P": [1, 80],
            "replicates": [8, 8],
            "steps": [2000, 2000],
            "budget_mse": [0.004, 0.002],
            "twice_steps": [4000, 4000],
            "twice_mse": [0.0041, 0.0019],
            "change": [0.025, -0.05],
            "ci_low": [0.01, -0.07],
            "ci_high": [0.04, -0.03],
        }
    ).to_csv(path, index=False)
    (line,) = [text for text in convergence_lines(path) if text]
    assert "P = 1 % 0.00400 after 2000 steps, 0.00410 after 4000 (+2.5%, +1.0% to +4.0%)" in line
    assert "P = 80 % 0.00200 after 2000 steps, 0.00190 after 4000 (-5.0%, -7.0% to -3.0%)" in line
    (path.parent / "twice").mkdir()
    (path.parent / "twice/recommendation.txt").write_text("probe at least 150 points: ...\n")
    assert convergence_lines(path)[-1] == "At twice the budget: probe at least 150 points: ..."


def test_a_compared_quick_scene_has_its_verdicts_in_one_line(tmp_path):
    root = tmp_path / "results"
    (root / "q/quick").mkdir(parents=True)
    rows = []
    for arm, round_ in (("quick", 3), ("stopped", None), ("full", None)):
        base = {"arm": arm, "round": round_, "presses": 2956 if arm == "full" else 30}
        base |= {"printer_min": 6.5, "steps": 900, "replicates": 1, "value": 1.0}
        base |= {"value_lo": 0.9, "value_hi": 1.1}
        rows.append(
            base
            | {"metric": "validation_mse", "object": ""}
            | {"change": 0.2, "change_lo": 0.15, "change_hi": 0.25}
        )
        rows.append(
            base
            | {"metric": "type2_um", "object": "pill"}
            | {"change": 2.0, "change_lo": -1.0, "change_hi": 5.0}
        )
    (root / "q/quick/arms.json").write_text(
        json.dumps(verdicts(arms_table(rows), "q", "full_scene"))
    )
    config = {"scenes": {"q": {"sensor": "digit", "description": "quick"}}}
    text = write_study_summary(config, root, tmp_path / "summary.md")
    line = next(x for x in text.splitlines() if "quick against full_scene's P = 80" in x)
    assert "mean validation MSE within 10% of full_scene's P = 80: not met (+20.0%" in line
    assert "every object (printer protocol): met (highest bound: pill +2.0 µm" in line
    assert "at most 50 presses: met (30 in all" in line
    assert "at most 5 printer minutes (motion model): not met (6.50)" in line
