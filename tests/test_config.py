import copy
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.study.config import load_config, validate_config
from threedcal.study.fractions import ablation_replicates, model_keys, training_fractions
from threedcal.study.training import train_settings

REPO = Path(__file__).resolve().parents[1]
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
        "scenes.s.model.preset: 'huge' is not allowed (allowed: touchnet, compact, compact_tiny, context, context_half, multiscale, lookup)"
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


def test_ablation_takes_a_list_or_fractions_with_replicates():
    plain = validate_config(config_with(ablation=[80, 5]))["scenes"]["s"]
    full = validate_config(config_with(ablation={"fractions": [5, 80], "replicates": 3}))
    defaults = {"steps": 2000, "convergence": False, "batching": "auto"}
    assert plain["ablation"] == {"fractions": [80, 5], "replicates": 1, **defaults}
    assert full["scenes"]["s"]["ablation"] == {"fractions": [5, 80], "replicates": 3, **defaults}
    assert model_keys(full["scenes"]["s"]) == [(5, 0), (5, 1), (5, 2), (80, 0), (80, 1), (80, 2)]
    assert ablation_replicates(validate_config(config_with())["scenes"]["s"]) == 1
    assert "scenes.s.ablation.replicates: 0 is less than the minimum of 1" in error_of(
        config_with(ablation={"fractions": [5, 80], "replicates": 0})
    )
    assert "scenes.s.ablation: unknown key 'reps'" in error_of(
        config_with(ablation={"fractions": [5, 80], "reps": 3})
    )
    assert "scenes.s.ablation: 'fractions' is a required property" in error_of(
        config_with(ablation={"replicates": 3})
    )
    # neither a list nor a mapping: both are named (was "'all' is not of type 'object'")
    message = error_of(config_with(ablation="all"))
    assert message.endswith("scenes.s.ablation: 'all' is not of type 'array' or 'object'")


def test_stats_settings_default_to_the_papers_alpha_and_a_ten_percent_margin():
    assert validate_config(config_with())["stats"] == {
        "alpha": 0.01,
        "equivalence_margin": 0.10,
        "equivalence_alpha": 0.05,
        "power_simulations": 1000,
        "curve_bootstrap": 2000,
    }
    assert "stats.equivalence_margin: 1.5 is greater than or equal to the maximum of 1" in error_of(
        {**config_with(), "stats": {"equivalence_margin": 1.5}}
    )


def test_shipped_configs_are_valid(repo):
    shipped = [
        *sorted((repo / "config").glob("*.yaml")),
        *sorted((repo / "tests/config").glob("*.yaml")),
    ]
    for path in [repo / "config.yaml", *shipped]:
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


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"dome": {"kx_per_mm": 0.013}}, "gel.dome: 'ky_per_mm' is a required property"),
        ({"dome": 3}, "gel.dome: 3 is not of type 'null' or 'object'"),
        ({"scatter_dn": [41.4, 48.3]}, "lights[0].scatter_dn: [41.4, 48.3] is too short"),
        ({"scatter_dn": "red"}, "lights[0].scatter_dn: 'red' is not of type 'number' or 'array'"),
    ],
)
def test_a_key_with_alternatives_reports_what_is_wrong_in_the_one_it_was_meant_as(
    tmp_path, edit, message
):
    """Repro: a dome missing ky_per_mm was reported as `gel.dome: {...} is not of type 'null'`,
    three scatter levels given as two as `is not of type 'number'`: the alternative not meant."""
    profile = load_profile("sensor", "digit")
    profile.pop("source", None)
    if "dome" in edit:
        profile["gel"]["dome"] = edit["dome"]
    else:
        profile["lights"][0]["scatter_dn"] = edit["scatter_dn"]
    path = tmp_path / "my_digit.yaml"
    path.write_text(yaml.safe_dump(profile))
    with pytest.raises(ConfigError) as exc:
        load_profile("sensor", path)
    assert str(exc.value) == f"{path}: invalid sensor profile\n  {message}"


# ---- issue 22: `config check` catches what a run would ------------------------------------


def check(tmp_path, text, capsys):
    from threedcal.cli import main

    path = tmp_path / "c.yaml"
    path.write_text(text)
    code = main(["config", "check", str(path)])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    return code, captured.err


def test_duplicate_scene_names_are_refused(tmp_path, capsys):
    """Repro: two scenes of one name were "valid" (YAML kept the last one silently)."""
    text = "scenes:\n  a: {sensor: digit, printer: ender3}\n  a: {sensor: gelsight_mini, printer: ender3}\n"
    code, err = check(tmp_path, text, capsys)
    assert code == 1 and "line 3: duplicate key 'a' (first on line 2)" in err


def test_duplicate_keys_are_refused_in_profiles_too(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("name: x\nname: y\n")
    with pytest.raises(ConfigError, match=r"p.yaml: line 2: duplicate key 'name'"):
        load_profile("printer", path)


def test_depth_beyond_the_sensors_penetration_is_refused(tmp_path, capsys):
    """Repro: a depth beyond the sensor's maximum penetration was "valid"."""
    text = "scenes:\n  s: {sensor: gelsight_mini, printer: ender3, plan: {depth_mm: 9.0}}\n"
    code, err = check(tmp_path, text, capsys)
    # point 78: the first grid row, after the touch search's 3 x 26 rows
    assert code == 1 and "scenes.s.plan, point 78: depth 9 mm" in err
    assert "beyond the sensor's maximum" in err


def test_points_outside_the_gel_are_refused(tmp_path, capsys):
    plan = tmp_path / "plan.csv"
    plan.write_text("x,y,depth,frames\n1,1,1,1\n500,1,1,1\n")
    text = f"scenes:\n  s: {{sensor: digit, printer: ender3, plan: {{csv: {plan}}}}}\n"
    code, err = check(tmp_path, text, capsys)
    assert code == 1 and "plan.csv), line 3: point (500, 1) mm lies outside the gel" in err


def test_missing_import_path_is_refused(tmp_path, capsys):
    """Repro: a missing import.path was "valid"."""
    text = f"scenes:\n  b: {{sensor: gelsight_mini, import: {{format: ball_folder, path: {tmp_path / 'nope'}}}}}\n"
    code, err = check(tmp_path, text, capsys)
    assert code == 1 and "scenes.b.import.path:" in err and "nope: does not exist" in err


def test_bad_fault_name_is_refused(tmp_path, capsys):
    """Repro: a bad bench.faults name was "valid" (and left an empty store behind at run time)."""
    text = "scenes:\n  s: {sensor: digit, printer: ender3, bench: {faults: 'checksum,chksum'}}\n"
    code, err = check(tmp_path, text, capsys)
    assert code == 1 and "scenes.s.bench.faults: unknown fault kind(s) 'chksum'" in err
    assert not (tmp_path / "results").exists()


def test_plans_over_the_size_limit_are_refused_with_their_point_count(tmp_path, capsys):
    """Repro: plan.spacing_mm 0.0001 tried to allocate 215 GiB."""
    text = "scenes:\n  s: {sensor: digit, printer: ender3, plan: {spacing_mm: 0.0001}}\n"
    code, err = check(tmp_path, text, capsys)
    assert code == 1 and "scenes.s.plan: spacing_mm=0.0001: the plan would have" in err
    assert re.search(r"would have [\d,]{14,} probe points", err) and "limits: 100,000 points" in err


def test_the_shipped_configs_pass_config_check(repo, capsys):
    from threedcal.cli import main

    for path in (repo / "config.yaml", repo / "config/paper.yaml", repo / "tests/config/test.yaml"):
        assert main(["config", "check", str(path)]) == 0, capsys.readouterr().err


def test_train_settings_have_no_defaults_of_their_own_the_schema_fills_them():
    import dataclasses

    from threedcal.model.train_settings import TrainSettings
    from threedcal.schema import load_schema

    fields = dataclasses.fields(TrainSettings)
    assert all(f.default is dataclasses.MISSING for f in fields)
    schema = load_schema("config")
    model = schema["$defs"]["model"]["properties"]
    settings = TrainSettings.of()
    for f in fields:
        if f.name in model:
            default = model[f.name]["default"]
            if model[f.name].get("type") == "object":  # a block: its keys' defaults
                default = {k: v["default"] for k, v in model[f.name]["properties"].items()}
            assert getattr(settings, f.name) == default, f.name
    assert settings.seed == schema["properties"]["seed"]["default"]
    validated = load_config(Path(__file__).parent / "config/test.yaml")
    scene = next(iter(validated["scenes"].values()))
    from_config = train_settings(scene)
    assert from_config == TrainSettings.of(
        seed=scene["seed"], torch_threads=scene["torch_threads"], **scene["model"]
    )
    with pytest.raises(ConfigError, match="no_such_key"):
        TrainSettings.of(no_such_key=1)


def test_configuration_page_is_the_schema_reference_and_every_key_is_described():
    from threedcal.schema import schema_keys, with_reference

    page = Path(__file__).resolve().parents[1] / "docs/reference/configuration.md"
    assert page.read_text() == with_reference(page.read_text()), (
        "docs/reference/configuration.md is out of date with the schema: run "
        "`.venv/bin/threedcal config reference --write docs/reference/configuration.md`"
    )
    keys = schema_keys("config")
    assert len(keys) > 50
    assert [path for path, node in keys if not node.get("description")] == []
    paths = [path for path, _ in keys]
    assert "scenes.<name>.model.preset" in paths and "scenes.<name>.pressing.mount.x_mm" in paths


def test_reference_needs_its_markers():
    from threedcal.schema import with_reference

    with pytest.raises(ConfigError, match="markers"):
        with_reference("# a page without them\n")


def test_a_magnetic_sensor_names_its_board_as_reader_not_camera():
    message = error_of(config_with(sensor="reskin", camera="/dev/ttyACM0"))
    assert "scenes.s.camera" in message and "reader" in message
    message = error_of(config_with(reader="/dev/ttyACM0"))
    assert "scenes.s.reader" in message and "camera" in message
    ok = validate_config(config_with(sensor="reskin", reader="/dev/ttyACM0"))
    assert ok["scenes"]["s"]["reader"] == "/dev/ttyACM0"


def test_cv_settings_have_no_defaults_of_their_own_the_schema_fills_them():
    import dataclasses

    from threedcal.dataset.folds import CVSettings
    from threedcal.schema import load_schema

    fields = dataclasses.fields(CVSettings)
    assert all(f.default is dataclasses.MISSING for f in fields)
    cv = load_schema("config")["$defs"]["cv"]["properties"]
    settings = CVSettings.of()
    assert {f.name: getattr(settings, f.name) for f in fields} == {
        f.name: cv[f.name]["default"] for f in fields
    }
    assert CVSettings.of(folds=3).folds == 3
    with pytest.raises(ConfigError, match="folds"):
        CVSettings.of(folds=0)


def test_sim_to_real_needs_an_imported_vision_scene_and_valid_k():
    collected = {**SIM_SCENE, "sim_to_real": {"enabled": True}}
    assert "sim_to_real.enabled: the sim-to-real stage needs an imported scene" in error_of(
        {"scenes": {"s": collected}}
    )
    imported = {
        "sensor": "gelsight_mini",
        "import": {"format": "ball_folder", "path": "x"},
        "sim_to_real": {"enabled": True, "k": [4, "some"]},
    }
    assert "sim_to_real.k" in error_of({"scenes": {"s": imported}})
    imported["sim_to_real"]["k"] = [4, "all"]
    assert (
        validate_config({"scenes": {"s": imported}})["scenes"]["s"]["sim_to_real"]["frames"] == 300
    )


def test_shipped_weights_in_sim_to_real_need_weights_for_the_sensor_and_frames_that_reach_them():
    imported = {
        "sensor": "digit",
        "import": {"format": "ball_folder", "path": "x"},
        "sim_to_real": {"enabled": True, "shipped": True},
    }
    assert "sim_to_real.shipped: no shipped weights for sensor 'digit'" in error_of(
        {"scenes": {"s": imported}}
    )
    imported["sensor"] = "gelsight_mini"
    scene = validate_config({"scenes": {"s": imported}})["scenes"]["s"]
    assert scene["sim_to_real"]["shipped_lr"] == 1e-3
    # `config check` reads the frames: the real Mini set (stored 320 x 240 portrait, read turned
    # into the Mini's landscape frame) reaches the 120 x 160 weights pooled by 2; pooled by 3
    # first (80 x 106) it cannot
    imported["import"]["path"] = "data/gelsight_ball_fots"
    validate_config({"scenes": {"s": imported}}, check_files=True)
    imported["dataset"] = {"downscale": 3}
    with pytest.raises(ConfigError, match="sim_to_real.shipped: the imported 80 x 106 px frames"):
        validate_config({"scenes": {"s": imported}}, check_files=True)


def test_test_objects_are_checked_with_the_config_not_after_the_collection(tmp_path, capsys):
    """Repro: `objects: [pil]` (a typo), a missing STL or one that cannot be read passed
    `config check` and the Snakefile's validation; the run collected and trained, then failed at
    the pressing stage. Names and files are checked by validate_config, what an STL holds by
    check_object_files (the workflow and `config check` call both)."""
    from threedcal.cli import main
    from threedcal.evaluate.mesh import Mesh, write_stl
    from threedcal.evaluate.objects import PARAMS, check_object_files, make_object
    from threedcal.object_refs import BUILTIN_OBJECTS

    assert set(BUILTIN_OBJECTS) == set(PARAMS)  # one list of the built-ins the stage can build
    mine = write_stl(make_object("pill"), tmp_path / "mine.STL")
    empty = tmp_path / "empty.stl"
    empty.write_text("solid x\nendsolid x\n")
    sheet = write_stl(Mesh(np.eye(3), [[0, 1, 2]], "sheet"), tmp_path / "sheet.stl")
    missing = tmp_path / "missing.stl"
    message = error_of(config_with(objects=["pill", "pil", str(missing), str(mine)]))
    assert message.splitlines()[1:] == [
        "  scenes.s.objects[1]: test object 'pil' is neither a built-in (hemispheres, pill, pawn) "
        "nor a mesh file (.stl, .obj, .ply, .off)",
        f"  scenes.s.objects[2]: mesh file '{missing}' does not exist",
    ]
    good = validate_config(config_with(objects=["pill", "pawn", "hemispheres", str(mine)]))
    check_object_files(good)
    bad = validate_config(config_with(objects=["pill", str(empty), str(sheet), str(mine)]))
    with pytest.raises(ConfigError) as info:
        check_object_files(bad, source="my.yaml")
    assert str(info.value).splitlines() == [
        "my.yaml: invalid config",
        f"  scenes.s.objects[1]: {empty}: no triangle read (an empty STL file, or not one)",
        f"  scenes.s.objects[2]: {sheet}: the mesh is not a closed (watertight), consistently "
        "wound surface; repair it (e.g. in your CAD tool or slicer) and export again",
    ]
    study = tmp_path / "study.yaml"
    study.write_text(yaml.safe_dump(bad))
    assert main(["config", "check", str(study)]) == 1
    assert f"scenes.s.objects[1]: {empty}: no triangle read" in capsys.readouterr().err


def test_realism_folders_and_sensors_are_named_by_config_check(tmp_path, capsys):
    """Repro: `realism: {real: missing/}` passed `config check`; Snakemake refused it later."""
    real = REPO / "data/gelsight_ball_fots"
    text = (
        "scenes:\n  s: {sensor: digit, printer: ender3}\n"
        f"realism: {{real: {tmp_path / 'missing'}, also: [{{real: {real}, sensor: digi}}]}}\n"
    )
    code, err = check(tmp_path, text, capsys)
    assert code == 1
    assert f"realism.real: {tmp_path / 'missing'} is not a folder" in err
    assert "realism.also[0].sensor: " in err and "digi" in err
    good = f"scenes:\n  s: {{sensor: digit, printer: ender3}}\nrealism: {{real: {real}}}\n"
    assert check(tmp_path, good, capsys)[0] == 0


def test_two_test_objects_of_one_name_are_refused_naming_both_keys(tmp_path):
    """Repro: `objects: [pill, cad/pill.stl]` passed; the pressing stage keys its tables, figures
    and mounts by the name, so one pill silently replaced the other."""
    from threedcal.evaluate.mesh import write_stl
    from threedcal.evaluate.objects import check_object_files, make_object

    mine = write_stl(make_object("pawn"), tmp_path / "pill.stl")
    config = validate_config(config_with(objects=["pill", "pawn", str(mine)]))
    with pytest.raises(ConfigError) as info:
        check_object_files(config, source="my.yaml")
    assert str(info.value).splitlines() == [
        "my.yaml: invalid config",
        f"  scenes.s.objects[2]: {str(mine)!r} has the name 'pill', as objects[0] has; "
        "rename one file",
    ]


def test_scenes_that_share_a_yaml_alias_are_separate_after_validation(tmp_path):
    from threedcal.study.config import load_config

    path = tmp_path / "c.yaml"
    path.write_text(
        "scenes:\n"
        "  a: {sensor: gelsight_mini, import: {format: ball_folder, path: x}, model: &m {lr: 0.01}}\n"
        "  b: {sensor: gelsight_mini, import: {format: ball_folder, path: y}, model: *m}\n"
    )
    config = load_config(path)
    config["scenes"]["a"]["model"]["lr"] = 0.5
    assert config["scenes"]["b"]["model"]["lr"] == 0.01


def test_config_check_refuses_pretrained_weights_for_a_sensor_without_them(tmp_path):
    from threedcal.errors import ConfigError
    from threedcal.study.config import validate_config

    scene = {"sensor": "digit", "printer": "ender3", "model": {"init": "pretrained"}}
    validate_config({"scenes": {"s": scene}})  # the workflow finds them when it plans a training
    with pytest.raises(
        ConfigError, match=r"scenes.s.model.init: pretrained: no pretrained weights"
    ):
        validate_config({"scenes": {"s": scene}}, check_files=True)


def test_a_real_printer_with_the_simulated_camera_is_refused_by_the_config_check():
    """collect refuses it before the printer moves; the config check names it before anything runs."""
    message = error_of(config_with(port="/dev/ttyUSB0"))
    assert "scenes.s" in message and "camera: port '/dev/ttyUSB0' is a real printer" in message
    ok = validate_config(config_with(port="/dev/ttyUSB0", camera="/dev/video0"))
    assert ok["scenes"]["s"]["camera"] == "/dev/video0"


def test_a_model_device_torch_does_not_know_is_refused_at_parse_time():
    """Before the collection, not at its training: `gpu` is no torch device."""
    assert "scenes.s.model.device: 'gpu' does not match" in error_of(
        config_with(model={"device": "gpu"})
    )
    for device in ("auto", "cpu", "cuda", "cuda:1", "mps"):
        validate_config(config_with(model={"device": device}))
