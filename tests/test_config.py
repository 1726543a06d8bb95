import copy

import pytest
import yaml

from threedcal.config import load_config, training_fractions, validate_config
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile

SIM_SCENE = {"sensor": "digit", "printer": "ender3"}


def config_with(**scene):
    return {"scenes": {"s": {**SIM_SCENE, **scene}}}


def error_of(config) -> str:
    with pytest.raises(ConfigError) as exc:
        validate_config(config, source="my.yaml")
    return str(exc.value)


def test_defaults_are_filled_and_scene_inherits_seed_and_threads():
    config = validate_config({"seed": 5, "torch_threads": 3, "scenes": {"s": dict(SIM_SCENE)}})
    scene = config["scenes"]["s"]
    assert scene["seed"] == 5 and scene["torch_threads"] == 3
    assert scene["port"] == "sim" and scene["probe"] == {"radius_mm": 2.0}
    assert scene["model"]["preset"] == "compact" and scene["model"]["lr"] == 1e-4
    assert scene["integrators"] == ["poisson_dst"]


def test_validation_does_not_mutate_the_input():
    config = config_with()
    before = copy.deepcopy(config)
    validate_config(config)
    assert config == before


def test_unknown_key_names_the_key_path_and_allowed_keys():
    message = error_of(config_with(model={"preset": "compact", "epoch": 3}))
    assert "my.yaml" in message
    assert "scenes.s.model: unknown key 'epoch'" in message
    assert "epochs_base" in message  # the allowed keys are listed


def test_bad_enum_value_lists_allowed_values():
    message = error_of(config_with(model={"preset": "huge"}))
    assert (
        "scenes.s.model.preset: 'huge' is not allowed (allowed: touchnet, compact, compact_tiny, context, multiscale, lookup)"
        in message
    )


def test_bad_list_item_names_its_index():
    message = error_of(config_with(integrators=["poisson_dst", "magic"]))
    assert "scenes.s.integrators[1]: 'magic' is not allowed" in message


def test_ablation_fraction_out_of_range():
    assert "scenes.s.ablation[0]: 0 is less than the minimum of 1" in error_of(
        config_with(ablation=[0])
    )


def test_every_problem_is_reported_at_once():
    message = error_of({"seed": -1, "scenes": {"s": {**SIM_SCENE, "sensr": 1}}})
    assert "seed: -1" in message and "unknown key 'sensr'" in message


def test_unknown_sensor_profile_lists_builtins():
    message = error_of(config_with(sensor="digi"))
    assert "scenes.s.sensor: no built-in sensor profile 'digi'" in message
    assert "digit" in message and "gelsight_mini" in message


def test_profile_path_must_exist(tmp_path):
    message = error_of(config_with(sensor=str(tmp_path / "nope.yaml")))
    assert "nope.yaml' does not exist" in message


def test_simulated_scene_needs_a_printer_and_imported_scene_refuses_one():
    assert "printer: required" in error_of({"scenes": {"s": {"sensor": "digit"}}})
    imported = {
        "sensor": "digit",
        "printer": "ender3",
        "import": {"format": "ball_folder", "path": "x"},
    }
    assert "imported scene has no printer" in error_of({"scenes": {"s": imported}})


def test_scene_names_must_be_path_safe():
    assert "must match" in error_of({"scenes": {"a/b": dict(SIM_SCENE)}})


def test_training_fractions_default_to_one_full_model():
    assert training_fractions({"ablation": []}) == [80]
    assert training_fractions({"ablation": [80, 5, 20]}) == [5, 20, 80]


def test_shipped_configs_are_valid(repo):
    for path in [repo / "config.yaml", *sorted((repo / "tests/config").glob("*.yaml"))]:
        assert load_config(path)["scenes"], path


def test_invalid_yaml_names_the_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("scenes: [unclosed\n")
    with pytest.raises(ConfigError, match="broken.yaml: not valid YAML"):
        load_config(path)


def test_invalid_profile_names_file_and_key(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text(yaml.safe_dump({"name": "cam", "type": "optical"}))
    with pytest.raises(ConfigError) as exc:
        load_profile("sensor", path)
    assert "cam.yaml: invalid sensor profile" in str(exc.value)
    assert "type: 'optical' is not allowed (allowed: vision, magnetic)" in str(exc.value)
