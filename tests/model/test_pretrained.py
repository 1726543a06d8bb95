"""The weights shipped for `model.init: pretrained` (threedcal.pretrained), how they are made and their command."""

import json

import pytest
from test_model import TINY, synthetic_set

import threedcal.pretrained as pretrained
from threedcal.cli import main
from threedcal.errors import ConfigError
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings
from threedcal.pretrained import (
    SHIPPED_DIR,
    pretraining_digest,
    provenance,
    shipped_sensors,
    shipped_weights,
)
from threedcal.profiles import load_profile
from threedcal.study.config import load_config


def fake_shipped(directory, sensor="mini", shape=(40, 48)):
    directory.mkdir(parents=True, exist_ok=True)
    ts = synthetic_set()
    train(
        ts, directory / "build", 80, TrainSettings.of(preset="compact_tiny", **TINY), progress=False
    )
    (directory / "build" / "model.pt").rename(directory / f"{sensor}.pt")
    record = {"image_shape": list(shape), "downscale": 2, "sensor": sensor}
    (directory / f"{sensor}.json").write_text(json.dumps(record))
    return directory


def test_weights_are_found_by_sensor_and_refused_for_another_frame(tmp_path):
    shipped = fake_shipped(tmp_path / "p")
    assert shipped_weights("mini", (40, 48), shipped) == shipped / "mini.pt"
    with pytest.raises(
        ConfigError, match=r"no pretrained weights for sensor 'digit' \(shipped: mini\)"
    ):
        shipped_weights("digit", (40, 48), shipped)
    with pytest.raises(ConfigError, match=r"made for 40 x 48 px frames \(dataset.downscale: 2\)"):
        shipped_weights("mini", (80, 96), shipped)


def test_init_pretrained_starts_from_the_shipped_weights_of_the_sets_sensor(tmp_path, monkeypatch):
    shipped = fake_shipped(tmp_path / "p")
    monkeypatch.setattr(pretrained, "SHIPPED_DIR", shipped)
    ts = synthetic_set()
    settings = TrainSettings.of(preset="compact_tiny", init="pretrained", **{**TINY, "lr": 1e-12})
    with pytest.raises(ConfigError, match="sensor None"):
        train(ts, tmp_path / "a", 80, settings, progress=False)
    ts.meta = {"sensor": "mini"}
    tuned = train(ts, tmp_path / "b", 80, settings, progress=False)
    start = read_checkpoint(shipped / "mini.pt")["state_dict"]
    for name, value in start.items():  # a rate of 1e-12 leaves the start where it was
        assert (tuned["state_dict"][name] - value).abs().max() < 1e-6


@pytest.mark.parametrize("sensor", load_config("config.yaml")["pretraining"]["sensors"])
def test_the_shipped_weights_are_what_the_repositorys_recipe_makes(sensor):
    # A changed recipe (config.yaml's pretraining, the sensor profile) needs `make pretrained`.
    assert sensor in shipped_sensors()
    record = provenance(sensor)
    recipe = load_config("config.yaml")["pretraining"]
    assert record["settings_digest"] == pretraining_digest(recipe, load_profile("sensor", sensor))
    checkpoint = read_checkpoint(SHIPPED_DIR / f"{sensor}.pt")
    assert checkpoint["preset"] == record["preset"] == recipe["model"]["preset"]
    assert list(checkpoint["image_shape"]) == record["image_shape"]
    assert checkpoint.get("blank") is None  # a unit's blank means nothing to another unit
    assert (SHIPPED_DIR / f"{sensor}.pt").stat().st_size < 100_000  # small enough to ship


def test_the_command_installs_rebuilt_weights_and_says_whether_they_changed(
    tmp_path, monkeypatch, capsys
):
    built = fake_shipped(tmp_path / "built_flat")
    results = tmp_path / "results"
    (results / "mini").mkdir(parents=True)
    (built / "mini.pt").rename(results / "mini" / "model.pt")
    (built / "mini.json").rename(results / "mini" / "provenance.json")
    target = tmp_path / "package"
    monkeypatch.setattr(pretrained, "SHIPPED_DIR", target)
    assert main(["pretrained", "install", str(results)]) == 0
    assert "mini.pt: installed" in capsys.readouterr().out
    assert main(["pretrained", "install", str(results)]) == 0
    assert "mini.pt: unchanged (the same bytes)" in capsys.readouterr().out
    assert main(["pretrained", "install", str(tmp_path / "nothing")]) == 1
    assert "no */model.pt to install" in capsys.readouterr().err


def test_the_settings_digest_is_the_recipes_not_where_the_clone_lies():
    profile = load_profile("sensor", "digit_fots")
    moved = {**profile, "source": "/elsewhere/digit_fots.yaml"}
    recipe = load_config("config.yaml")["pretraining"]
    assert pretraining_digest(recipe, moved) == pretraining_digest(recipe, profile)
    changed = {**profile, "name": "another"}
    assert pretraining_digest(recipe, changed) != pretraining_digest(recipe, profile)


def test_the_settings_digest_ignores_the_profiles_citations_not_its_constants():
    """A docs page that moves changes a profile's `source` text, not the recipe."""
    profile = load_profile("sensor", "digit_fots")
    recipe = load_config("config.yaml")["pretraining"]
    cited = {**profile, "unit_variation": {**profile["unit_variation"], "source": "elsewhere"}}
    assert pretraining_digest(recipe, cited) == pretraining_digest(recipe, profile)
    moved = {**profile, "px_per_mm": profile["px_per_mm"] + 0.1}
    assert pretraining_digest(recipe, moved) != pretraining_digest(recipe, profile)
