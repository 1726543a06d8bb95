"""Where jobs run: printer jobs one at a time and on the submitting machine; the study on Slurm.

One test runs workflow/cluster/check.py (the tiny study on Slurm against a local run) when a Slurm
controller answers and THREEDCAL_SLURM_CHECK=1 asks for it (it takes minutes); `make cluster-test`
starts a controller, runs that check and stops it again.
"""

import base64
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO, load_file_module, snakemake, tiny_study_config, write_config

PROFILE = REPO / "workflow/profiles/slurm"


def two_printer_scenes() -> dict:
    # Two small simulated collections, both ready at once: only the printer keeps them apart.
    # (one touch-search place and one frame a point: the printer's turn-taking, not the search)
    plan = {"spacing_mm": 4.0, "depth_mm": 1.0, "frames": 1, "touch_search": {"points": 1}}
    scene = {"sensor": "digit", "printer": "ender3", "plan": plan}
    return {"seed": 1, "torch_threads": 1, "scenes": {"one": scene, "two": dict(scene)}}


COLLECTIONS = [f"results/{name}/collect/summary.json" for name in ("one", "two")]


def job_span(workdir, output: str) -> tuple[float, float]:
    """When the job that made `output` started and ended, as Snakemake recorded it."""
    record = workdir / ".snakemake/metadata" / base64.b64encode(output.encode()).decode()
    data = json.loads(record.read_text())
    return data["starttime"], data["endtime"]


def job_blocks(text: str) -> dict[str, list[str]]:
    """Rule name -> the text of each of its jobs in Snakemake's output."""
    blocks: dict[str, list[str]] = {}
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", text):
        match = re.match(r"(?:local)?rule (\w+):", block.strip())
        if match:
            blocks.setdefault(match.group(1), []).append(block.split("\n\n")[0])
    return blocks


def test_a_real_printers_jobs_take_turns_and_simulated_ones_run_side_by_side(tmp_path):
    # A real printer is one device: its jobs hold `printer` (one unit, with or without a profile:
    # the Snakefile's default), so two never run at once. Each simulated scene has its own bench.
    # (Side by side on the bench, run for real: tests/test_workflow.py.)
    config = two_printer_scenes()
    config["scenes"]["one"] = {**config["scenes"]["one"], "port": "/dev/ttyUSB0", "camera": 0}
    dry = snakemake(tmp_path, write_config(tmp_path, config), "--dry-run", *COLLECTIONS)
    jobs = {
        re.search(r"results/(\w+)/", job).group(1): job for job in job_blocks(dry.stdout)["collect"]
    }
    assert "printer=1" in jobs["one"] and "printer=0" in jobs["two"], jobs


@pytest.mark.long
def test_every_rule_writes_a_benchmark_file_beside_its_logs(tmp_path, tiny_study_dry_run):
    tiny, dry_run = tiny_study_dry_run
    config = write_config(tmp_path, tiny)
    listed = snakemake(tmp_path, config, "--list-rules").stdout.split()
    blocks = job_blocks(dry_run)
    # the tiny study runs every rule but the pretraining (`snakemake pretrained`, not in `all`)
    pretraining = job_blocks(snakemake(tmp_path, config, "pretrained", "--dry-run").stdout)
    assert set(pretraining) == {"pretrain", "pretrained"}
    blocks.update(pretraining)
    # and the quick flow's arms, which need a full calibration to compare with (the default study's)
    if not (tmp_path / "data").exists():
        (tmp_path / "data").symlink_to(REPO / "data")  # the default study's real folders
    arms = snakemake(tmp_path, REPO / "config.yaml", "results/digit_quick/quick/arms.json", "-n")
    blocks["quick_arms"] = job_blocks(arms.stdout)["quick_arms"]
    # and `make quick-study`'s summary over units (its own config)
    study = snakemake(tmp_path, REPO / "config/quick_study.yaml", "quick_study", "-n")
    blocks["quick_study"] = job_blocks(study.stdout)["quick_study"]
    # and the shipped weights on real frames (the default study's real_check section)
    real = snakemake(tmp_path, REPO / "config.yaml", "results/real_check/table.csv", "-n")
    blocks["real_check"] = job_blocks(real.stdout)["real_check"]
    assert set(blocks) == set(listed)
    for rule, jobs in blocks.items():
        if rule in ("all", "pretrained"):  # targets that only gather other rules' outputs
            continue
        for job in jobs:
            bench = re.search(r"^\s+benchmark: (\S+)$", job, re.MULTILINE)
            log = re.search(r"^\s+log: (\S+)$", job, re.MULTILINE)
            assert bench, f"rule {rule} has no benchmark file"
            # results/{scene}/benchmarks/ beside results/{scene}/logs/; study-wide: results/benchmarks/
            scope = log.group(1).split("/")[1]
            study_wide = scope in ("logs", "integration")
            folder = "results/benchmarks/" if study_wide else f"results/{scope}/benchmarks/"
            assert bench.group(1).startswith(folder) and bench.group(1).endswith(".tsv"), (
                rule,
                bench.group(1),
            )


def test_slurm_profile_asks_a_gpu_for_training_and_the_printer_for_collection(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_slurm", reason='pip install -e ".[cluster]"')
    config = write_config(tmp_path, tiny_study_config(tmp_path))
    dry = snakemake(tmp_path, config, "--profile", str(PROFILE), "--dry-run")
    blocks = job_blocks(dry.stdout + dry.stderr)
    for job in blocks["train"]:
        assert "slurm_partition=gpu" in job and "gres=gpu:1" in job
    for job in blocks["collect"] + blocks["object_presses"]:
        assert "printer=0" in job  # the simulated bench: no printer to share
    for job in blocks["stats"] + blocks["objects"]:
        assert "slurm_partition=cpu" in job and "gres=" not in job


@pytest.mark.long
@pytest.mark.slow
def test_slurm_profile_runs_printer_jobs_on_this_machine_without_sbatch(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_slurm", reason='pip install -e ".[cluster]"')
    config = two_printer_scenes()
    config["scenes"] = {"one": config["scenes"]["one"]}
    config["scenes"]["one"].update(  # the tiny study's plan: enough contacts to register
        plan={"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1, "touch_search": {"points": 1}},
        objects=["pill"],
        pressing={"presses": 1, "tuning_presses": 1},
    )
    config = write_config(tmp_path, config)
    # No Slurm to submit to: every Slurm command on PATH is a stand-in that writes down its call
    # and fails at once, so a printer job through the profile succeeds only because it is a local
    # rule, run here and never given to sbatch. (A real client with no controller would fail too,
    # after tens of seconds of DNS lookups per call.)
    fake_bin = tmp_path / "fake-slurm"
    fake_bin.mkdir()
    calls = tmp_path / "slurm-calls.txt"
    for command in (
        "sbatch",
        "scontrol",
        "sacct",
        "sacctmgr",
        "squeue",
        "sinfo",
        "scancel",
        "srun",
    ):
        stand_in = fake_bin / command
        stand_in.write_text(f'#!/bin/sh\necho "{command} $*" >> "{calls}"\nexit 1\n')
        stand_in.chmod(0o755)
    no_slurm = dict(
        os.environ,
        PATH=f"{fake_bin}{os.pathsep}{os.environ.get('PATH', '')}",
        SLURM_CONF=str(tmp_path / "no-slurm.conf"),
    )

    def through_profile(target: str) -> str:
        # The plugin's status loop sleeps this long between checks (40 s by default) and the run
        # ends only when it wakes: 1 s, so the test does not spend its time asleep.
        result = snakemake(
            tmp_path,
            config,
            "--profile",
            str(PROFILE),
            "--slurm-init-seconds-before-status-checks",
            "1",
            target,
            check=False,
            env=no_slurm,
        )
        text = result.stdout + result.stderr
        assert result.returncode == 0, text
        assert "submitted with SLURM jobid" not in text
        submitted = (
            [c for c in calls.read_text().splitlines() if c.startswith("sbatch")]
            if calls.exists()
            else []
        )
        assert submitted == [], submitted
        return text

    assert "localrule collect:" in through_profile("results/one/collect/summary.json")
    assert (tmp_path / "results/one/raw.zarr/zarr.json").is_file()
    snakemake(tmp_path, config, "results/one/dataset/registration.json")  # a Slurm job's work
    pressing = "results/one/objects/pressing/summary.json"
    assert "localrule object_presses:" in through_profile(pressing)
    assert (tmp_path / pressing).is_file()
    assert (tmp_path / "results/one/benchmarks/object_presses.tsv").is_file()


def slurm_controller_missing() -> str | None:
    """Why no Slurm controller can be used here, or None when one answers `scontrol ping`."""
    if shutil.which("scontrol") is None:
        return "no Slurm client (scontrol) on this machine"
    try:
        ping = subprocess.run(["scontrol", "ping"], capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        return "`scontrol ping` timed out"
    if ping.returncode != 0 or "UP" not in ping.stdout:
        return f"no Slurm controller answers `scontrol ping` ({(ping.stdout + ping.stderr).strip()[:160]})"
    return None


@pytest.mark.slow
def test_study_on_slurm_gives_the_local_results(tmp_path):
    reason = slurm_controller_missing()
    if reason:
        pytest.skip(f"{reason}; `make cluster-test` starts one and runs this check")
    if os.environ.get("THREEDCAL_SLURM_CHECK") != "1":
        # Minutes of Slurm jobs: not inside `make test` (under 5 minutes) unless asked for.
        pytest.skip("a Slurm controller answers; THREEDCAL_SLURM_CHECK=1 runs this check on it")
    pytest.importorskip("snakemake_executor_plugin_slurm", reason='pip install -e ".[cluster]"')
    result = subprocess.run(
        [sys.executable, str(REPO / "workflow/cluster/check.py"), str(tmp_path / "work")],
        capture_output=True,
        text=True,
    )
    print(result.stdout)
    assert result.returncode == 0, result.stdout + result.stderr


def _load_resources():
    return load_file_module("workflow/cluster/resources.py", "cluster_resources")


def test_resources_suggests_memory_and_time_per_rule_from_benchmark_files(tmp_path):
    resources = _load_resources()
    header = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
    jobs = {  # (wall s, max_rss MB, cpu s)
        "a/benchmarks/train_P20_r0.tsv": (2000.0, 563.3, 190.2),
        "b/benchmarks/train_P80_r2.tsv": (945.1, 380.6, 400.0),
        "benchmarks/environment.tsv": (19.4, 257.3, 2.8),
    }
    for name, (wall, rss, cpu) in jobs.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(header + f"{wall}\t0:00:00\t{rss}\t0\t0\t0\t0\t0\t1\t{cpu}\n")
    table = resources.suggest(resources.measured(tmp_path))
    assert list(table.index) == ["train", "environment"]  # P, r are wildcards: one rule, two jobs
    train = table.loc["train"]
    assert train["jobs"] == 2 and train["max_rss_mb"] == 563 and train["max_cpu_s"] == 400
    assert train["mem_mb"] == 1500  # 563.3 x 1.5 + 500 = 1345 -> next 500 MB
    assert train["runtime"] == 20  # 3 x 400 s = 20 min
    assert table.loc["environment", "mem_mb"] == 1000  # 886 -> 1000
    assert table.loc["environment", "runtime"] == 10  # at least 10 min
    by_wall = resources.suggest(resources.measured(tmp_path), time="s")
    assert by_wall.loc["train", "runtime"] == 100  # 3 x 2000 s = 100 min
    with pytest.raises(SystemExit, match="no benchmarks"):
        resources.measured(tmp_path / "a/benchmarks")


def test_resources_names_every_wildcard_job_by_its_rule():
    """Every `benchmark:` file of rules/*.smk, its wildcards filled as the default study fills
    them, maps back to the rule that declares it."""
    resources = _load_resources()
    values = {  # each wildcard's values in the default study (both sim-to-real conditions)
        "scene": ["digit_sim"],
        "p": ["1", "20"],
        "r": ["0", "2"],
        "method": ["model", "lookup"],
        "fold": ["0", "5"],
        "folds": ["0", "0-1-2"],
        "k": ["8", "all"],
        "condition": ["sim_real", "real_only"],
        "sensor": ["digit_fots", "gelsight_mini"],
    }
    checked = {}
    for smk in (REPO / "rules").glob("*.smk"):
        # `rule x:`, or a rule defined in a loop (`rule:` then `name:`, its first name the base)
        text = re.sub(
            r"^(\s*)rule:\s*\n\s*name:\s*\n?\s*\"(\w+)\".*$",
            r"rule \2:",
            smk.read_text(),
            flags=re.MULTILINE,
        )
        blocks = re.split(r"^\s*(?:local)?rule (\w+):", text, flags=re.MULTILINE)
        for rule, body in zip(blocks[1::2], blocks[2::2], strict=True):
            found = re.search(r"benchmark:\s*\n\s*\"([^\"]+)\"", body)
            if not found:
                continue
            for pick in (0, -1):  # the first and the last value of every wildcard
                name = re.sub(
                    r"\{(\w+)\}", lambda m, pick=pick: values[m.group(1)][pick], found.group(1)
                )
                checked[Path(name).stem] = (resources.rule_of(Path(name)), rule)
    assert {"train_P1_r0", "cv_train_fold5", "sim2real_real_only_fold5"} <= set(checked)
    assert {"sim2real_pretrain_folds0-1-2", "sim2real_simulate_folds0"} <= set(checked)
    assert {"train_ablation_P20", "pretrain_digit_fots"} <= set(checked)
    assert all(got == rule for got, rule in checked.values()), checked
