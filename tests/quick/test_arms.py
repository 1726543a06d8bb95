"""The three-arm measurement's numbers (threedcal.study.quick_arms) on synthetic scores with known
answers, its verdicts computed from the table, and the config check of `quick.compare_with`."""

import copy
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.paths import arms_scenes, scene_targets
from threedcal.study.quick_arms import (
    ArmModel,
    arms_table,
    difference_interval,
    judged,
    mean_interval_blocks,
    object_rows,
    relative_change,
    stopped_arm,
    validation_rows,
    verdicts,
)


def test_one_replicate_mean_interval_is_the_t_interval_over_blocks():
    values = np.array([1.0, 3.0, 2.0, 6.0, 4.0])
    mean, low, high = mean_interval_blocks(values[None, :])
    expected = stats.t.interval(0.95, 4, loc=values.mean(), scale=stats.sem(values))
    assert mean == pytest.approx(3.2)
    assert (low, high) == pytest.approx(expected, rel=1e-9)


def test_relative_change_is_fiellers_interval():
    """One model against one model on K blocks: the ratio's bounds solve Fieller's quadratic
    (mean(s) − θ mean(r))² = t² var(s − θ r) / K, written out here."""
    rng = np.random.default_rng(3)
    reference = rng.uniform(1.0, 2.0, 12)
    sample = 1.25 * reference + rng.normal(0, 0.1, 12)
    change, low, high = relative_change(sample[None, :], reference[None, :])
    k = sample.size
    t2 = stats.t.ppf(0.975, k - 1) ** 2
    ms, mr = sample.mean(), reference.mean()
    vs, vr = sample.var(ddof=1), reference.var(ddof=1)
    c = np.cov(sample, reference, ddof=1)[0, 1]
    a = mr**2 - t2 * vr / k
    b = -2 * (ms * mr - t2 * c / k)
    roots = np.sort(np.roots([a, b, ms**2 - t2 * vs / k]).real)
    assert change == pytest.approx(ms / mr - 1, rel=1e-12)
    assert (low, high) == pytest.approx(tuple(roots - 1), abs=1e-7)
    assert low < change < high


def _model(arm, round_, replicates=1, presses=10, minutes=1.0):
    paths = tuple(f"{arm}{round_}_{r}.pt" for r in range(replicates))
    return ArmModel(arm, round_, presses, minutes, 100, paths)


def test_validation_rows_pair_the_arms_on_blocks():
    points = np.arange(8)
    blocks = pd.Series(points // 2, index=points, name="block")  # four blocks of two
    reference = np.array([1.0, 3.0, 2.0, 2.0, 4.0, 2.0, 3.0, 5.0])
    scores = pd.concat(
        [
            pd.DataFrame(
                {
                    "arm": "quick",
                    "round": 1,
                    "replicate": 0,
                    "point": points,
                    "mse": reference + np.repeat([2.0, 3.5, 3.0, 2.5], 2),
                }
            ),
            pd.DataFrame(
                {"arm": "full", "round": -1, "replicate": 0, "point": points, "mse": reference}
            ),
        ]
    )
    quick, full = _model("quick", 1), _model("full", None)
    rows = validation_rows([quick, full], scores, blocks)
    assert [r["arm"] for r in rows] == ["quick", "full"]
    # block means of the reference: 2, 2, 3, 4 -> grand mean 2.75
    assert rows[1]["value"] == pytest.approx(2.75) and math.isnan(rows[1]["change"])
    assert rows[0]["value"] == pytest.approx(5.5)
    assert rows[0]["change"] == pytest.approx(1.0)  # twice the mean error: +100 %
    assert rows[0]["change_lo"] < 1.0 < rows[0]["change_hi"]
    assert rows[0]["value_lo"] < rows[0]["value"] < rows[0]["value_hi"]


def test_object_rows_pair_each_arm_with_full_on_the_presses():
    quick = [3.0, 5.0, 4.0, 8.0]
    full = [2.0, 2.5, 3.0, 4.5]
    presses = pd.DataFrame(
        {
            "object": "pill",
            "press": list(range(4)) * 2,
            "P": [0] * 4 + [1] * 4,  # position in the model list
            "replicate": 0,
            "type2_um": quick + full,
        }
    )
    rows = object_rows([_model("quick", 2), _model("full", None)], presses)
    quick_row, full_row = rows
    difference = np.subtract(quick, full)
    expected = stats.t.interval(0.95, 3, loc=difference.mean(), scale=stats.sem(difference))
    assert quick_row["object"] == "pill" and quick_row["value"] == pytest.approx(5.0)
    assert quick_row["change"] == pytest.approx(difference.mean())
    assert (quick_row["change_lo"], quick_row["change_hi"]) == pytest.approx(expected)
    assert full_row["value"] == pytest.approx(3.0) and math.isnan(full_row["change"])


def test_the_stopped_point_is_the_runs_last_model():
    points = [_model("quick", k, presses=10 * k, minutes=1.0 + k) for k in range(3)]
    stopped = stopped_arm(points)
    assert stopped.arm == "stopped" and stopped.round is None and stopped.key == ("stopped", -1)
    assert stopped.paths == points[-1].paths
    assert (stopped.presses, stopped.printer_min) == (20, 3.0)


def test_object_differences_of_independent_runs_widen_with_their_spread():
    """Three quick runs against two full replicates, paired on the presses: the difference of
    their means, its interval wider than the presses' alone by the runs' spread (a run effect
    shifts every press of its run alike), and presses without a Type 2 pixel left out."""
    rng = np.random.default_rng(5)
    press = rng.normal(0, 3.0, 8)
    own = 20 + press + rng.normal(0, 2.0, (3, 1)) + rng.normal(0, 0.5, (3, 8))
    reference = 15 + press + rng.normal(0, 0.5, (2, 8))
    mean, low, high = difference_interval(own, reference)
    u = own.mean(axis=0) - reference.mean(axis=0)  # per press: what the presses alone say
    presses_alone = stats.t.interval(0.95, 7, loc=u.mean(), scale=stats.sem(u))
    assert mean == pytest.approx(own.mean() - reference.mean())
    assert low < mean < high and high - low > presses_alone[1] - presses_alone[0]
    own[0, 2] = np.nan  # a press without a Type 2 pixel in one run: left out of every run
    mean, _, _ = difference_interval(own, reference)
    keep = np.arange(8) != 2
    assert mean == pytest.approx(own[:, keep].mean() - reference[:, keep].mean())


def test_judged_on_an_interval():
    assert judged(-0.2, 0.08, 0.10) == "met"
    assert judged(0.11, 0.3, 0.10) == "not met"
    assert judged(0.05, 0.2, 0.10) == "undecided"


def _table(mse_change, pill_change, presses=40, minutes=4.0) -> pd.DataFrame:
    rows = []
    points = (("quick", 0), ("quick", 4), ("stopped", None), ("scratch", 4), ("full", None))
    for arm, round_ in points:
        rows.append(
            {
                "arm": arm,
                "round": round_,
                "presses": 2956 if arm == "full" else (0 if round_ == 0 else presses),
                "printer_min": 60.0 if arm == "full" else minutes,
                "steps": 1200,
                "replicates": 3 if arm == "full" else 1,
                "metric": "validation_mse",
                "object": "",
                "value": 1.0,
                "value_lo": 0.9,
                "value_hi": 1.1,
                "change": math.nan if arm == "full" else mse_change[0] + (arm == "scratch"),
                "change_lo": math.nan if arm == "full" else mse_change[1],
                "change_hi": math.nan if arm == "full" else mse_change[2],
            }
        )
        for name, change in (("pill", pill_change), ("pawn", (1.0, -2.0, 4.0))):
            rows.append(
                {
                    **rows[0],
                    "arm": arm,
                    "round": round_,
                    "metric": "type2_um",
                    "object": name,
                    "change": change[0],
                    "change_lo": change[1],
                    "change_hi": change[2],
                }
            )
    return arms_table(rows)


def test_verdicts_are_computed_from_the_stopped_models():
    stop = {"scene": "q", "round": 4, "decision": "stop: improvement below margin"}
    record = verdicts(_table((0.04, -0.01, 0.09), (3.0, -1.0, 8.0)), "q", "full", stop=stop)
    targets = record["targets"]
    assert record["stop"] == stop and record["presses"] == 40
    assert targets["validation_mse"]["verdict"] == "met"
    assert targets["objects"]["verdict"] == "met"
    assert targets["presses"]["verdict"] == "met" and targets["printer_minutes"]["verdict"] == "met"
    assert record["scratch_same_round"]["change"] == pytest.approx(1.04)
    assert "+4.0 %" in targets["validation_mse"]["line"].replace("%", " %")
    # one object past the bound, an MSE interval astride it, too many presses and minutes
    record = verdicts(_table((0.08, 0.02, 0.2), (14.0, 11.0, 17.0), 51, 5.5), "q", "full")
    targets = record["targets"]
    assert targets["validation_mse"]["verdict"] == "undecided"
    assert targets["objects"]["verdict"] == "not met"
    assert targets["objects"]["per_object"]["pawn"]["verdict"] == "met"
    assert "pill +14.0 µm" in targets["objects"]["line"]
    assert targets["presses"]["verdict"] == "not met" and "(51 in all" in targets["presses"]["line"]
    assert targets["printer_minutes"]["verdict"] == "not met"


# ---- the config check -----------------------------------------------------------------------


def config(full_changes=None, quick_changes=None) -> dict:
    full = {
        "sensor": "digit_fots",
        "printer": "ender3",
        "plan": {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1},
        "bench": {"unit": 1},
        "dataset": {"downscale": 2},
        "ablation": [20, 80],
        "objects": ["pill"],
        "model": {"preset": "context_half", "init": "pretrained"},
    }
    quick = {
        "sensor": "digit_fots",
        "printer": "ender3",
        "plan": {
            "pattern": "quick",
            "depth_mm": 1.0,
            "frames": 1,
            "registration": {"spacing_mm": 1.0, "depth_mm": 0.25},
        },
        "bench": {"unit": 1},
        "dataset": {"downscale": 2},
        "model": {"preset": "context_half", "init": "pretrained"},
        "quick": {"compare_with": "full"},
    }
    full.update(full_changes or {})
    quick.update(quick_changes or {})
    return {"scenes": {"full": full, "q": quick}}


def test_a_compared_quick_scene_asks_for_the_arms():
    scenes = validate_config(config())["scenes"]
    targets = scene_targets("q", scenes["q"])
    assert "results/q/quick/arms.csv" in targets and "results/q/quick/scratch" in targets
    assert "results/q/quick/arms.json" in targets and "results/q/quick/arms.png" in targets
    assert validate_config(config(full_changes={"ablation": []}))  # one model at P = 80 is enough


@pytest.mark.parametrize(
    ("full_changes", "quick_changes", "message"),
    [
        ({}, {"quick": {"compare_with": "nope"}}, "no other scene 'nope' in this config"),
        ({}, {"quick": {"compare_with": "q"}}, "no other scene 'q'"),
        ({"bench": {"unit": 2}}, {}, "bench.unit 1 here, 2 there"),
        ({"bench": {"unit": 1, "seating_offset_mm": 0.2}}, {}, "bench.seating_offset_mm 0.4 here"),
        ({"seed": 3}, {}, "seed 0 here, 3 there"),
        ({"sensor": "gelsight_mini"}, {}, "sensor 'digit_fots' here, 'gelsight_mini' there"),
        ({"probe": {"radius_mm": 3.0}}, {}, "probe.radius_mm 2.0 here, 3.0 there"),
        ({"ablation": [5, 20]}, {}, "full trains no P = 80 models"),
        ({"objects": []}, {}, "full presses no test objects (its `objects`), which the arms"),
    ],
)
def test_compare_with_refused_naming_the_key(full_changes, quick_changes, message):
    with pytest.raises(ConfigError) as error:
        validate_config(config(full_changes, quick_changes))
    assert "scenes.q.quick.compare_with: " in str(error.value)
    assert message in str(error.value)


def test_a_unit_of_the_quick_study_is_compared_without_arms_or_objects():
    """quick.arms: false (make quick-study's units): compared, but no arms stage, so the full
    calibration needs no test objects."""
    checked = validate_config(
        config({"objects": []}, {"quick": {"compare_with": "full", "arms": False}})
    )
    assert arms_scenes(checked) == []
    assert not any("arms" in t for t in scene_targets("q", checked["scenes"]["q"]))
    assert arms_scenes(validate_config(config())) == ["q"]


def test_compare_with_only_for_quick_scenes():
    bad = config()
    bad["scenes"]["full"]["quick"] = {"compare_with": "q"}
    with pytest.raises(ConfigError, match=r"scenes.full.quick.compare_with: only a quick scene"):
        validate_config(bad)


def test_the_presses_target_counts_the_touch_search_and_registration_too():
    """50 presses in rounds after 116 touch-search and registration presses are 166 presses."""
    record = verdicts(_table((0.04, -0.01, 0.09), (3.0, -1.0, 8.0)), "q", "full", setup_presses=116)
    presses = record["targets"]["presses"]
    assert presses["value"] == record["presses"] + 116 == record["presses_in_all"]
    assert (
        presses["verdict"] == "not met"
        and "116 touch search and any registration lattice" in presses["line"]
    )


def test_every_arm_is_scored_with_the_validation_sets_blank(tmp_path):
    """A model carrying another blank (its own lens's rectification) is scored as if it carried
    the validation set's: the two checkpoints below differ only in their blank."""
    from conftest import write_untrained_model

    from threedcal.dataset.trainset import TrainingSet
    from threedcal.study.quick_arms import validation_scores

    rng = np.random.default_rng(0)
    blank = np.full((40, 48, 3), 100.0, np.float32)
    frames = np.clip(blank + rng.normal(0, 20, (4, 40, 48, 3)), 0, 255).astype(np.uint8)
    samples = pd.DataFrame(
        {
            "frame": np.arange(4),
            "point": np.arange(4),
            "center_x_px": [20.0, 24.0, 28.0, 22.0],
            "center_y_px": [18.0, 20.0, 22.0, 24.0],
            "depth_mm": [0.5, 0.6, 0.7, 0.8],
            "eval_radius_px": np.full(4, 6.0),
            "split": ["train", "train", "val", "val"],
            "min_p": [80, 80, 0, 0],
        }
    )
    trainset = TrainingSet(frames, blank, samples, px_per_mm=8.0, sphere_radius_mm=2.0)
    other_blank = np.roll(trainset.blank + 7.0, 2, axis=1)  # brighter and shifted
    own = write_untrained_model(tmp_path / "own.pt", "compact_tiny", trainset.blank, px_per_mm=8.0)
    shifted = write_untrained_model(
        tmp_path / "shifted.pt", "compact_tiny", other_blank, px_per_mm=8.0
    )
    splits = pd.DataFrame(
        {
            "point": trainset.point,
            "x_mm": trainset.point * 1.0,
            "y_mm": np.zeros(len(trainset.point)),
        }
    ).drop_duplicates("point")
    models = [
        ArmModel("full", None, 4, 1.0, 0, (own,)),
        ArmModel("quick", 1, 4, 1.0, 0, (shifted,)),
    ]
    scores = validation_scores(models, trainset, splits)
    full, quick = (scores[scores["arm"] == arm]["mse"].to_numpy() for arm in ("full", "quick"))
    assert len(full) == 2 and np.all(full > 0)
    np.testing.assert_array_equal(quick, full)
    with pytest.raises(ConfigError, match="dataset.downscale must agree"):
        small = write_untrained_model(
            tmp_path / "small.pt", "compact_tiny", trainset.blank[::2, ::2]
        )
        validation_scores([ArmModel("quick", 1, 4, 1.0, 0, (small,))], trainset, splits)


# ---- runs of one quick calibration (quick.run) --------------------------------------------


def with_runs(*runs: dict) -> dict:
    """config() with quick scenes q2, q3, ... changed from q by each dict."""
    out = config()
    for i, changes in enumerate(runs, start=2):
        scene = copy.deepcopy(out["scenes"]["q"])
        for key, value in changes.items():
            scene[key] = {**scene.get(key, {}), **value} if isinstance(value, dict) else value
        out["scenes"][f"q{i}"] = scene
    return out


def test_a_run_presses_its_own_design_and_trains_with_its_own_seed(tmp_path):
    """Run 2 draws other quick presses after the same touch search and registration lattice, and
    fine-tunes with the seed's replicate 1; run 1 is the calibration as it always was."""
    from threedcal.dataset.splits import replicate_seed
    from threedcal.study.quick_loop import QuickLoop
    from threedcal.study.session import prepare

    scenes = validate_config(with_runs({"quick": {"run": 2}}))["scenes"]
    plans, seeds = [], []
    for name in ("q", "q2"):
        prepared = prepare(scenes[name])
        loop = QuickLoop(scenes[name], prepared.plan, tmp_path, tmp_path, {}, {})
        plans.append(prepared.plan)
        seeds.append(loop.train_settings.seed)
    one, two = plans
    first = int((one["phase"] == "grid").to_numpy().argmax())
    assert one.iloc[:first].equals(two.iloc[:first]) and len(one) == len(two)
    assert not one.iloc[first:][["x_mm", "y_mm"]].equals(two.iloc[first:][["x_mm", "y_mm"]])
    assert seeds == [scenes["q"]["seed"], replicate_seed(scenes["q"]["seed"], 1)]
