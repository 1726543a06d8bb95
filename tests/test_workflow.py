"""The Snakemake DAG: per-scene targets, config errors at parse time, caching, and one end-to-end run."""

import json
import re

import pandas as pd
import pytest
import yaml
from conftest import (
    dry_run_jobs,
    load_file_module,
    scheduled_jobs,
    snakemake,
    tiny_study_config,
    write_config,
)

from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.paths import realism_sets, scene_targets, study_targets


def test_dry_run_schedules_exactly_each_scenes_own_targets(tiny_study_dry_run):
    config, output = tiny_study_dry_run
    jobs = dry_run_jobs(output)
    scenes = {wc["scene"] for rule, wc in jobs if "scene" in wc}
    assert scenes == set(config["scenes"])
    assert ("all", {}) in jobs


def test_two_configs_schedule_only_their_scenes(tmp_path):
    one = {"scenes": {"only_a": {"sensor": "digit", "printer": "ender3"}}}
    two = {"scenes": {"only_b": {"sensor": "gelsight_mini", "printer": "ender3"}}}
    jobs_one = scheduled_jobs(tmp_path, write_config(tmp_path, one, "one.yaml"))
    jobs_two = scheduled_jobs(tmp_path, write_config(tmp_path, two, "two.yaml"))
    assert {wc.get("scene") for _, wc in jobs_one} - {None} == {"only_a"}
    assert {wc.get("scene") for _, wc in jobs_two} - {None} == {"only_b"}


def test_study_targets_follow_scene_config():
    config = validate_config(targets_config())
    targets = study_targets(config)
    for name, scene in config["scenes"].items():
        assert set(scene_targets(name, scene)) <= set(targets)
        assert all(t.startswith(f"results/{name}/") for t in scene_targets(name, scene))


def test_config_cli_override_keeps_default_scenes(repo, tmp_path):
    # `--config seed=3` modifies the default study; only `--configfile` replaces it.
    result = snakemake(repo, repo / "config.yaml", "--dry-run", "--config", "seed=3")
    assert "digit_sim" in result.stdout


def test_bad_config_fails_at_parse_time_naming_the_key(tmp_path):
    bad = {"scenes": {"s": {"sensor": "digit", "printer": "ender3", "model": {"preset": "big"}}}}
    result = snakemake(tmp_path, write_config(tmp_path, bad), "--dry-run", check=False)
    assert result.returncode != 0
    output = result.stdout + result.stderr
    assert (
        "scenes.s.model.preset: 'big' is not allowed (allowed: touchnet, compact, compact_tiny, context, context_half, multiscale, lookup)"
        in output
    )
    assert not (tmp_path / "results").exists()


def test_an_unreadable_test_object_stl_fails_at_parse_time_naming_the_key(tmp_path):
    """Repro: an STL that exists but is no closed surface passed the Snakefile's validation; the
    study collected and trained before the pressing stage read it."""
    sheet = tmp_path / "sheet.stl"
    sheet.write_text(
        "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
        "endloop\nendfacet\nendsolid s\n"
    )
    bad = {"scenes": {"s": {"sensor": "digit", "printer": "ender3", "objects": [str(sheet)]}}}
    result = snakemake(tmp_path, write_config(tmp_path, bad), "--dry-run", check=False)
    assert result.returncode != 0
    assert (
        f"scenes.s.objects[0]: {sheet}: the mesh is not a closed" in result.stdout + result.stderr
    )
    assert not (tmp_path / "results").exists()


def test_config_without_scenes_is_refused(tmp_path):
    result = snakemake(tmp_path, write_config(tmp_path, {"seed": 1}), "--dry-run", check=False)
    assert result.returncode != 0
    assert "'scenes' is a required property" in result.stdout + result.stderr


def cluster_check():
    return load_file_module("workflow/cluster/check.py", "cluster_check")


def split_tiny_study(tmp_path) -> tuple[dict, dict]:
    """tests/config/test.yaml as two studies: the collected scenes (the run `make test` makes), and
    the imported scene with the realism check, whose cross-validation, sim-to-real and presets
    stages are most of the tiny study's job-time (the long test runs them). `make cluster-test`
    runs the whole file."""
    config = tiny_study_config(tmp_path)
    imported = {name for name, scene in config["scenes"].items() if "import" in scene}
    assert imported, "tests/config/test.yaml has no imported scene"
    collected = dict(
        config, scenes={k: v for k, v in config["scenes"].items() if k not in imported}
    )
    collected.pop("realism", None)
    rest = {k: v for k, v in config.items() if k not in ("scenes", "integration_study")}
    rest["scenes"] = {name: config["scenes"][name] for name in imported}
    return collected, rest


@pytest.mark.long
@pytest.mark.slow
def test_end_to_end_run_of_an_imported_scene_and_the_realism_check(tmp_path):
    _, config = split_tiny_study(tmp_path)
    snakemake(tmp_path, write_config(tmp_path, config))
    for name, scene in config["scenes"].items():
        record = json.loads((tmp_path / f"results/{name}/scene.json").read_text())
        assert record["scene"] == name and record["software"]["threedcal"]
        assert (tmp_path / f"results/{name}/models/P80/r0/model.pt").stat().st_size > 0
        assert (tmp_path / f"results/{name}/models/P80/r0/losses.png").is_file()
        ball = json.loads((tmp_path / f"results/{name}/ball_eval.json").read_text())
        # cross-validated: every real image tested once, by a model that never saw it
        assert ball["n_test_images"] == ball["lookup"]["n_test_images"] == 42
        assert ball["gradient_rmse"] > 0 and ball["lookup"]["cap_depth_mae_um"] > 0
        assert len(ball["folds"]) == scene["cv"]["folds"]
        assert (tmp_path / f"results/{name}/cv/errors.png").is_file()
        assert (tmp_path / f"results/{name}/presets.csv").is_file()
        errors = pd.read_csv(tmp_path / f"results/{name}/sim2real/errors.csv")
        pooled = errors[errors["fold"].astype(str) == "all"]
        assert set(pooled["condition"]) == {"sim+real", "real-only", "scene model"}
        assert (pooled["cap_depth_mae_um"] > 0).all()
        assert (tmp_path / f"results/{name}/sim2real/error_vs_k.png").is_file()
    for leaf in ("summary.md", "environment.json", "realism/table.txt"):
        assert (tmp_path / f"results/{leaf}").is_file(), leaf
    assert cluster_check().uncovered_timing_tables(tmp_path / "results") == []
    assert scheduled_jobs(tmp_path, write_config(tmp_path, config)) == []


@pytest.mark.slow
def test_end_to_end_run_then_reruns_only_what_a_change_touches(tmp_path):
    config, _ = split_tiny_study(tmp_path)
    path = write_config(tmp_path, config)
    snakemake(tmp_path, path)
    for name in config["scenes"]:
        record = json.loads((tmp_path / f"results/{name}/scene.json").read_text())
        assert record["scene"] == name and record["software"]["threedcal"]
    for name, scene in config["scenes"].items():
        if scene["sensor"] == "reskin":
            reskin = json.loads((tmp_path / f"results/{name}/reskin_eval.json").read_text())
            assert reskin["n_test_readings"] > 0 and reskin["median_error_mm"] >= 0
            assert reskin["p90_error_mm"] >= reskin["median_error_mm"]
            assert (tmp_path / f"results/{name}/reskin_eval.png").is_file()
            assert not (tmp_path / f"results/{name}/dataset").exists()
    collected = next(name for name, scene in config["scenes"].items() if scene.get("ablation"))
    for leaf in (
        "raw.zarr",
        "dataset/registration.json",
        "models/P20/r1/model.pt",
        "stats/tests.csv",
        "stats/tests.png",
        "stats/power.csv",
        "stats/recommendation.txt",
        "stats/learning_curve.csv",
        "stats/learning_curve.png",
        "objects/errors.csv",
        "objects/figures/pill_by_P.png",
        "models/inference.json",
    ):
        assert (tmp_path / f"results/{collected}/{leaf}").exists(), leaf
    # errors.csv: per object, P and protocol, the mean over the object's reporting presses (two
    # pill presses here; the tuning press is in presses.csv and tuning.csv only) and over the
    # replicates' models (two here: every one scores every press)
    objects = tmp_path / f"results/{collected}/objects"
    presses = pd.read_csv(objects / "presses.csv")
    reporting = presses[presses["set"] == "reporting"]
    assert sorted(reporting["press"].unique()) == [0, 1]
    assert reporting["registered_x_px"].nunique() == 2
    assert set(presses["set"]) == {"tuning", "reporting"}
    errors = pd.read_csv(objects / "errors.csv")
    assert list(errors["protocol"].unique()) == ["printer", "paper"]
    metrics = ["overall_um", "type1_um", "type2_um"]
    means = reporting.groupby(["object", "P", "protocol"])[metrics].mean()
    pd.testing.assert_frame_equal(
        errors.set_index(["object", "P", "protocol"])[metrics].sort_index(), means.sort_index()
    )
    assert (errors["presses"] == 2).all() and (errors["type2_um_lo"] <= errors["type2_um"]).all()
    assert (errors["replicates"] == 2).all() and set(reporting["replicate"]) == {0, 1}
    tuning = pd.read_csv(objects / "tuning.csv")
    assert (tuning["presses"] == 1).all()
    for leaf in ("summary.md", "environment.json", "integration/reading.md"):
        assert (tmp_path / f"results/{leaf}").is_file(), leaf
    summary = (tmp_path / "results/summary.md").read_text()
    assert collected in summary
    # the stage-time table: the training of the collected scene is among the summed stages, one
    # job per fraction
    assert f"| train_ablation | {collected} | 2 |" in summary
    # Snakemake limits every job's BLAS/OpenMP pools to the job's threads (1 for this rule)
    environment = json.loads((tmp_path / "results/environment.json").read_text())
    assert environment["thread_environment"] == dict.fromkeys(
        ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"), "1"
    )
    # Two replicates per fraction, each scored on the same validation coordinates; tests.csv holds
    # the paper's, the paired and the equivalence family; the recommendation rests on the last
    stats_dir = tmp_path / f"results/{collected}/stats"
    validation = pd.read_csv(stats_dir / "validation_mse.csv")
    assert sorted(validation.groupby(["P", "replicate"]).groups) == [
        (20, 0),
        (20, 1),
        (80, 0),
        (80, 1),
    ]
    assert validation.groupby(["P", "replicate"])["point"].apply(frozenset).nunique() == 1
    tests = pd.read_csv(stats_dir / "tests.csv")
    assert set(tests["family"]) == {"paper", "paired", "equivalence", "placebo"}
    recommendation = (stats_dir / "recommendation.txt").read_text().splitlines()
    assert "margin of mean validation MSE" in recommendation[0]
    # two fractions: no curve of three parameters, and the line says so
    assert recommendation[1].startswith("learning curve not fitted: a curve of three parameters")
    curve = pd.read_csv(stats_dir / "learning_curve.csv").set_index("quantity")
    assert curve.loc["points_within_margin", "note"].startswith("not fitted")
    assert (stats_dir / "learning_curve.png").stat().st_size > 0
    # every model trained the same steps, and on to twice them: the ablation read again there,
    # and every fraction's error at every cycle end (2, 4, 8 and 16 steps)
    steps = config["scenes"][collected]["ablation"]["steps"]
    for p, r in ((20, 0), (20, 1), (80, 0), (80, 1)):
        folder = tmp_path / f"results/{collected}/models/P{p}/r{r}"
        assert pd.read_csv(folder / "losses.csv")["step"].iloc[-1] == steps
        assert pd.read_csv(folder / "twice/losses.csv")["step"].iloc[-1] == 2 * steps
    twice = pd.read_csv(stats_dir / "twice/validation_mse.csv")
    assert sorted(twice.groupby(["P", "replicate"]).groups) == sorted(
        validation.groupby(["P", "replicate"]).groups
    )
    assert "margin of mean validation MSE" in (stats_dir / "twice/recommendation.txt").read_text()
    assert (stats_dir / "twice/learning_curve.csv").is_file()
    curve = pd.read_csv(stats_dir / "error_vs_time.csv")
    assert sorted(curve["steps"].unique()) == [steps // 4, steps // 2, steps, 2 * steps]
    assert len(curve) == 4 * 4 and curve["mse"].gt(0).all()
    convergence = pd.read_csv(stats_dir / "convergence.csv")
    assert convergence["P"].tolist() == [20, 80] and convergence["replicates"].eq(2).all()
    # `make cluster-test` compares this study's outputs with a Slurm run's byte for byte, timing
    # columns excepted: every table that times something must be named there.
    assert cluster_check().uncovered_timing_tables(tmp_path / "results") == []
    # Nothing changed: nothing to do.
    assert scheduled_jobs(tmp_path, path) == []
    # A model setting of one scene: its trainings and what reads them rerun, not its collection
    # nor the test-object presses (the frames are kept; only their scores are redone).
    config["scenes"][collected]["model"]["epochs_base"] = 2
    path = write_config(tmp_path, config)
    jobs = scheduled_jobs(tmp_path, path)
    rules = {rule for rule, _ in jobs}
    assert {"train_ablation", "stats", "objects"} <= rules
    assert not rules & {
        "collect",
        "object_presses",
        "dataset_collected",
        "dataset_import",
        "integration_study",
        "realism",
    }
    assert {wc["scene"] for _, wc in jobs if "scene" in wc} == {collected}
    # A probing setting reruns the collection and everything downstream of it, for that scene only.
    config["scenes"][collected]["plan"]["frames"] = 2
    jobs = scheduled_jobs(tmp_path, write_config(tmp_path, config))
    assert ("collect", {"scene": collected}) in jobs
    assert {wc["scene"] for _, wc in jobs if "scene" in wc} == {collected}


def test_one_training_job_per_fraction_and_a_ball_eval_for_imported_scenes(tmp_path):
    config = {
        "scenes": {
            "balls": {
                "sensor": "gelsight_mini",
                "import": {"format": "ball_folder", "path": str(tmp_path / "data")},
                "ablation": [20, 80],
            }
        }
    }
    jobs = scheduled_jobs(tmp_path, write_config(tmp_path, config))
    trains = sorted(wc["p"] for rule, wc in jobs if rule == "train_ablation")
    assert trains == ["20", "80"]  # one job per fraction (the plain list form: one replicate)
    assert ("ball_eval", {"scene": "balls"}) in jobs
    # one job per fold trains the fold's model of every method
    folds = sorted(int(wc["fold"]) for rule, wc in jobs if rule == "cv_train")
    assert folds == list(range(6))
    # sim_to_real off (the default): no sim-to-real job
    assert not [rule for rule, _ in jobs if rule.startswith("sim2real")]
    # Asking for one P schedules that training alone (plus the dataset it reads).
    one = scheduled_jobs(
        tmp_path, write_config(tmp_path, config), "results/balls/models/P20/r0/model.pt"
    )
    assert sorted(rule for rule, _ in one) == ["dataset_import", "train_ablation"]


def test_sim_to_real_schedules_one_job_per_condition_and_chosen_fold(tmp_path):
    balls = {
        "sensor": "gelsight_mini",
        "import": {"format": "ball_folder", "path": str(tmp_path / "data")},
        # shipped: one more training per k and fold, from the package's weights
        "sim_to_real": {"enabled": True, "k": [4, "all"], "folds": [1, 3], "shipped": True},
    }
    jobs = scheduled_jobs(tmp_path, write_config(tmp_path, {"scenes": {"balls": balls}}))
    # every k of a (condition, fold) in one job
    trains = sorted((wc["condition"], wc["fold"]) for rule, wc in jobs if rule == "sim2real_train")
    assert trains == [(c, f) for c in ("real_only", "shipped_real", "sim_real") for f in ("1", "3")]
    # One simulated set and one pretraining for both folds: the optics fitted to the images of the
    # folds not evaluated, on which each of them trains.
    for rule in ("sim2real_simulate", "sim2real_pretrain"):
        assert [wc["folds"] for r, wc in jobs if r == rule] == ["1-3"]
    assert ("sim2real_eval", {"scene": "balls"}) in jobs
    # Off (the default): no sim-to-real job (the same imported scene without sim_to_real is
    # test_one_training_job_per_fraction_and_a_ball_eval_for_imported_scenes's dry run).


def test_one_training_job_per_fraction_for_its_replicates_and_replicate_0_for_single_model_stages(
    tmp_path,
):
    config = {
        "scenes": {
            "sim": {
                "sensor": "digit",
                "printer": "ender3",
                "ablation": {"fractions": [20, 80], "replicates": 3},
                "objects": ["pill"],
            },
            "balls": {
                "sensor": "gelsight_mini",
                "import": {"format": "ball_folder", "path": str(tmp_path / "data")},
                "ablation": {"fractions": [20, 80], "replicates": 2},
            },
        }
    }
    result = snakemake(tmp_path, write_config(tmp_path, config), "--dry-run")
    blocks = {}  # (rule, scene, p, r) -> the job's dry-run text
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", result.stdout + result.stderr):
        rule = re.match(r"(?:local)?rule (\w+):", block.strip())
        wildcards = re.search(r"^\s+wildcards: (.*)$", block, re.MULTILINE)
        if rule and wildcards:
            values = dict(kv.split("=", 1) for kv in wildcards.group(1).split(", "))
            key = (rule.group(1), values["scene"], values.get("p"), values.get("r"))
            blocks[key] = block
    trains = sorted((scene, p) for rule, scene, p, _ in blocks if rule.startswith("train"))
    assert trains == [("balls", "20"), ("balls", "80"), ("sim", "20"), ("sim", "80")]
    # each job trains every replicate of its fraction (two rules: two replicate counts)
    sim_job = blocks[
        next(
            key for key in blocks if key[:3] == (key[0], "sim", "80") and key[0].startswith("train")
        )
    ]
    assert all(f"models/P80/r{r}/model.pt" in sim_job for r in range(3))
    # objects reads every replicate of every P; inference_speed replicate 0 of the largest P;
    # ball_eval scores the cross-validation's fold models, never an ablation replicate
    objects = blocks[("objects", "sim", None, None)]
    assert all(f"models/P{p}/r{r}/model.pt" in objects for p in (20, 80) for r in range(3))
    speed = blocks[("inference_speed", "sim", None, None)]
    assert "models/P80/r0/model.pt" in speed and "/r1/" not in speed
    ball_eval = blocks[("ball_eval", "balls", None, None)]
    assert "cv/model/fold0/model.pt" in ball_eval and "/models/P" not in ball_eval
    stats_block = blocks[("stats", "sim", None, None)]
    assert all(f"models/P{p}/r{r}/model.pt" in stats_block for p in (20, 80) for r in range(3))


def targets_config():
    return yaml.safe_load(
        """
scenes:
  sim: {sensor: digit, printer: ender3, ablation: [5, 80]}
  imported: {sensor: gelsight_mini, import: {format: ball_folder, path: x}}
"""
    )


def test_realism_sets_carry_each_pairs_gel_mechanics():
    config = validate_config(
        {
            "realism": {
                "real": "data/gelsight_ball_fots",
                "gel_mechanics": "elastic",
                "also": [{"real": "data/digit_frames_fots", "sensor": "digit"}],
            },
            "scenes": {"s": {"sensor": "digit", "printer": "ender3"}},
        }
    )
    assert realism_sets(config) == [
        ["data/gelsight_ball_fots", "gelsight_mini", "elastic"],
        ["data/digit_frames_fots", "digit", None],
    ]
    bad = {"real": "data/gelsight_ball_fots", "gel_mechanics": "soft"}
    with pytest.raises(ConfigError, match="gel_mechanics"):
        validate_config({"realism": bad, "scenes": {"s": {"sensor": "digit", "printer": "ender3"}}})


def test_only_a_real_printer_is_held_one_job_at_a_time(tmp_path):
    """`resources: printer` serialises the jobs that drive a real printer; every simulated scene
    has its own bench, so its collection runs beside another's."""
    config = {
        "scenes": {
            "real": {"sensor": "digit", "printer": "ender3", "port": "/dev/ttyUSB0", "camera": 0},
            "sim": {"sensor": "digit", "printer": "ender3"},
        }
    }
    result = snakemake(tmp_path, write_config(tmp_path, config), "--dry-run")
    held = {}
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", result.stdout + result.stderr):
        if re.match(r"(?:local)?rule collect:", block.strip()):
            scene = re.search(r"wildcards: scene=(\w+)", block).group(1)
            held[scene] = re.search(r"resources: .*printer=(\d)", block).group(1)
    assert held == {"real": "1", "sim": "0"}
