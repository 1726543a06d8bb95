"""The rig's mount: a scene's `mount` (inline or a file) over the sensor profile's, key by key; the
bench keeps seating the sensor in the profile's base; the shipped weights keep their name."""

from __future__ import annotations

import pytest
import yaml

from threedcal.errors import ConfigError
from threedcal.mount import SensorMount, read_mount_file, write_mount_file
from threedcal.profiles import load_profile
from threedcal.study.config import validate_config
from threedcal.study.paths import stage_config
from threedcal.study.scene import scene_sensor
from threedcal.study.session import prepare, simulated_truth


def scene_with(mount, **extra) -> dict:
    config = {"scenes": {"s": {"sensor": "digit_fots", "printer": "ender3", "mount": mount}}}
    config["scenes"]["s"].update(extra)
    return validate_config(config)["scenes"]["s"]


def test_a_scene_mount_replaces_only_the_keys_it_gives():
    profile = load_profile("sensor", "digit_fots")["mount"]
    sensor = scene_sensor(scene_with({"x_offset_mm": 90.0, "z_touch_mm": 120.5}))
    assert sensor["mount"] == {**profile, "x_offset_mm": 90.0, "z_touch_mm": 120.5}
    assert sensor["name"] == "digit_fots"  # the profile, so the shipped weights, unchanged
    # without a mount: the profile's
    plain = validate_config({"scenes": {"s": {"sensor": "digit_fots", "printer": "ender3"}}})
    assert scene_sensor(plain["scenes"]["s"])["mount"] == profile


def test_a_mount_file_is_read_and_stages_see_its_values(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    found = SensorMount(95.25, 101.5, 121.0375, 2.5)
    assert write_mount_file("base.yaml", found, "measured by hand") is None
    text = (tmp_path / "base.yaml").read_text()
    assert text.startswith("# measured by hand\n")
    assert yaml.safe_load(text) == found.as_dict()
    scene = scene_with("base.yaml")
    assert scene["mount"] == "base.yaml"  # the config keeps the path (the page writes there)
    assert scene_sensor(scene)["mount"] == found.as_dict()
    # a stage's params hold the values: a changed file reruns the stage
    assert stage_config(scene, "collect")["mount"] == found.as_dict()
    assert stage_config(scene, "dataset")["mount"] == found.as_dict()
    # the collection probes where the mount says
    plan = prepare(scene)
    assert plan.sensor["mount"] == found.as_dict()


def test_a_mount_file_is_never_overwritten_silently(tmp_path):
    path = tmp_path / "base.yaml"
    path.write_text("x_offset_mm: 1.0\n")
    with pytest.raises(ConfigError, match="refusing to overwrite"):
        write_mount_file(path, SensorMount(1, 2, 3, 4), "new")
    assert path.read_text() == "x_offset_mm: 1.0\n"
    kept = write_mount_file(path, SensorMount(1, 2, 3, 4), "new", replace=True)
    assert kept.read_text() == "x_offset_mm: 1.0\n" and kept.name.startswith("base.yaml.")
    assert read_mount_file(path) == SensorMount(1, 2, 3, 4).as_dict()


def test_bad_mounts_are_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"scenes.s.mount: missing.yaml does not exist"):
        scene_with("missing.yaml")
    # `threedcal rig` starts before the file exists: it writes it
    config = {"scenes": {"s": {"sensor": "digit_fots", "printer": "ender3", "mount": "later.yaml"}}}
    scene = validate_config(config, new_mount=True)["scenes"]["s"]
    assert (
        scene_sensor(scene, missing_ok=True)["mount"]
        == load_profile("sensor", "digit_fots")["mount"]
    )
    (tmp_path / "bad.yaml").write_text("x_offset_mm: -3\nz_touch: 5\n")
    with pytest.raises(ConfigError, match=r"scenes.s.mount: bad.yaml is not a valid mount"):
        scene_with("bad.yaml")
    with pytest.raises(ConfigError, match=r"scenes.s.mount"):
        scene_with({"x_offset": 1.0})
    # a mount that puts the plan outside the printer's travel is refused before anything moves
    with pytest.raises(ConfigError, match=r"outside the printer's travel"):
        scene_with({"x_offset_mm": 230.0})


def test_the_bench_seats_the_sensor_in_the_profiles_base_whatever_the_scene_says():
    """A scene's mount is what its user measured; the bench's truth stays where it was."""
    plain = validate_config({"scenes": {"s": {"sensor": "digit_fots", "printer": "ender3"}}})
    moved = scene_with({"x_offset_mm": 100.0, "y_offset_mm": 100.0})
    truth = simulated_truth(plain["scenes"]["s"], prepare(plain["scenes"]["s"]))
    assert simulated_truth(moved, prepare(moved)) == truth


def test_a_custom_base_keeps_the_shipped_weights(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_mount_file("base.yaml", SensorMount(60.0, 70.0, 100.0, 2.0), "my base")
    config = {
        "scenes": {
            "s": {
                "sensor": "digit_fots",
                "printer": "ender3",
                "mount": "base.yaml",
                "model": {"preset": "context_half", "init": "pretrained"},
                "dataset": {"downscale": 2},
            }
        }
    }
    validate_config(config, check_files=True)  # the weights are found by the profile's name
