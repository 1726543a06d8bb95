"""A quick scene's bad input is refused by the config check, before any printer moves."""

import pytest
from conftest import write_untrained_model

from threedcal.cli import main
from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.paths import scene_targets
from threedcal.study.quick_loop import quick_stage


def quick_scene(**changes) -> dict:
    scene = {
        "sensor": "digit_fots",
        "printer": "ender3",
        "plan": {
            "pattern": "quick",
            "depth_mm": 1.0,
            "frames": 1,
            "registration": {"spacing_mm": 1.0, "depth_mm": 0.25},
        },
        "dataset": {"downscale": 2},
        "model": {"preset": "context_half", "init": "pretrained"},
    }
    for key, value in changes.items():
        scene[key] = {**scene[key], **value} if isinstance(value, dict) and key in scene else value
    return {"scenes": {"q": scene}}


def refused(**changes) -> str:
    with pytest.raises(ConfigError) as error:
        validate_config(quick_scene(**changes))
    return str(error.value)


def test_example_config_checks_and_asks_only_for_the_quick_outputs(repo, capsys):
    assert main(["config", "check", str(repo / "config/quick.yaml")]) == 0
    out = capsys.readouterr().out
    assert "results/digit_quick/quick/model.pt" in out and "stop.json" in out
    assert "raw.zarr" not in out and "models/P80" not in out
    scene = validate_config(quick_scene())["scenes"]["q"]
    assert scene_targets("q", scene) == [
        "results/q/scene.json",
        "results/q/quick/model.pt",
        "results/q/quick/rounds.csv",
        "results/q/quick/stop.json",
    ]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"plan": {"round_presses": 3}}, "scenes.q.plan.round_presses: 3 presses a round cannot"),
        (
            {"plan": {"round_presses": 10, "max_presses": 8}},
            "scenes.q.plan.max_presses: 8 is fewer than one round",
        ),
        (
            {"plan": {"area_mm": [0.0, 0.0, 16.0, 18.0]}},
            "scenes.q.plan.area_mm: [0, 0, 16, 18] mm reaches outside what the camera sees",
        ),
        (
            {"plan": {"area_mm": [5.0, 5.0, 5.0, 9.0]}},
            "scenes.q.plan.area_mm: [5.0, 5.0, 5.0, 9.0] is empty",
        ),
        ({"quick": {"margin": 1.5}}, "scenes.q.quick.margin: 1.5 is not a relative improvement"),
        ({"quick": {"confidence": 0.3}}, "scenes.q.quick.confidence: 0.3 must lie in [0.5, 1)"),
        (
            {"model": {"preset": "compact_tiny"}},
            "scenes.q.model.preset: 'compact_tiny', but the shipped digit_fots weights",
        ),
        ({"dataset": {"downscale": 1}}, "the digit_fots weights were made for 160 x 120 px"),
        ({"sensor": "digit"}, "no pretrained weights for sensor 'digit'"),
        # the first round registers through the profile's lens: 5 whole contacts at least
        (
            {"plan": {"round_presses": 4, "registration": {"spacing_mm": 0.0}}},
            "scenes.q.plan.registration: its first round's 4 presses would leave about 2 "
            "contacts whole in the frame; the first round's registration needs 5",
        ),
        (
            {"plan": {"round_presses": 4, "registration": {"depth_mm": 0.25, "each_press": True}}},
            "its first round's 4 presses (paused 0.25 mm deep) would leave about 4 contacts",
        ),
        (
            {"plan": {"registration": {"depth_mm": 1.0, "each_press": True}}},
            "scenes.q.plan.registration.depth_mm: 1.0 must lie above plan.depth_mm (1.0)",
        ),
        (
            {"plan": {"registration": {"spacing_mm": 1.0, "depth_mm": 0.25, "each_press": True}}},
            "scenes.q.plan.registration: each_press registers the rounds' presses; a lattice",
        ),
        (
            {"plan": {"touch_search": {"method": "bisect", "presses": 3}}},
            "scenes.q.plan.touch_search.presses: 3 is less than the minimum of 4",
        ),
        ({"ablation": [20, 80]}, "scenes.q.ablation: a quick calibration"),
        ({"objects": ["pill"]}, "scenes.q.objects: a quick calibration"),
    ],
)
def test_bad_quick_input_is_named(changes, message):
    assert message in refused(**changes)


def test_a_checkpoint_init_for_another_network_is_refused_before_collecting(tmp_path):
    import numpy as np

    weights = write_untrained_model(tmp_path / "w.pt", "compact", np.zeros((160, 120, 3)))
    scene = validate_config(quick_scene(model={"init": weights, "preset": "compact_tiny"}))
    outputs = {k: tmp_path / "quick" / k for k in ("model", "rounds", "stop", "work")}
    with pytest.raises(ConfigError, match="holds a 'compact' network, model.preset is"):
        quick_stage(
            "q",
            scene["scenes"]["q"],
            store=tmp_path / "raw.zarr",
            staging=tmp_path / ".partial" / "raw.zarr",
            progress=False,
            **outputs,
        )
    assert not (tmp_path / ".partial").exists() and not (tmp_path / "raw.zarr").exists()


@pytest.mark.slow
def test_workflow_schedules_the_quick_stage_alone(repo, tmp_path):
    """config/quick.yaml: the quick stage, not the collect/dataset/train stages of a grid scene."""
    from conftest import scheduled_jobs

    jobs = scheduled_jobs(tmp_path, repo / "config/quick.yaml")
    rules = sorted(rule for rule, _ in jobs)
    assert ("quick", {"scene": "digit_quick"}) in jobs
    assert not {"collect", "dataset_collected", "train"} & set(rules), rules
