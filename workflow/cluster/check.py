"""The cluster check behind `make cluster-test` (docs/how-to/slurm.md): the tiny study on Slurm against a local run.

Needs a Slurm controller that answers (`scontrol ping`) with accounting (`sacct`), partitions and
resources as workflow/profiles/slurm asks, and the executor plugin (`pip install -e ".[cluster]"`).
workflow/cluster/slurm.sh starts such a cluster on one machine. In WORKDIR it

1. runs tests/config/test.yaml (with registration presses added to `tiny_digit`: its collection then
   lasts long enough to be killed between two writes) locally with a bare `snakemake --cores 2`
   (no profile): simulated scenes collect side by side (each has its own bench; only a real
   printer's jobs hold the `printer` resource);
2. at the same time runs it through `--profile workflow/profiles/slurm` with two failures made on
   purpose: an image of the imported ball scene is unreadable (a cluster job fails: its log must say
   why, where the docs say), and the collection of `tiny_digit` is killed mid-way (its partial
   store must stay);
3. repairs the image and reruns: only what failed and what follows it runs; the collection resumes;
4. asks sacct which jobs ran where: `collect` and `object_presses` never went to Slurm, training got
   the GPU partition;
5. compares every output of the two runs: equal bytes, or equal but for the named timing fields.

Prints the Slurm job ids, the run times and the equality table; exits non-zero on any failed check.
"""

from __future__ import annotations

import argparse
import fnmatch
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import yaml

REPO = Path(__file__).resolve().parents[2]
SNAKEMAKE = Path(sys.executable).with_name("snakemake")
PROFILE = REPO / "workflow/profiles/slurm"
# A small run is dominated by the plugin's wait before its first status check (default 40 s per
# job) and Snakemake's 10 s between checks; on a one-node test cluster a few seconds are enough.
FAST_STATUS = [
    "--slurm-init-seconds-before-status-checks",
    "3",
    "--seconds-between-status-checks",
    "3",
]
KILLED_SCENE = "tiny_digit"  # its collection is killed after KILL_AFTER points, then resumed
KILL_AFTER = 10
FAILING_SCENE = "tiny_ball"  # one of its images is made unreadable for the first cluster run
FAILING_RULE = "dataset_import"

# What may differ between the two runs, and why. Everything else must be equal byte for byte.
TIMES = "progress bars with rates and timestamps"
# Files that measure time on the machine that ran them.
EXCLUDED = {
    "*/logs/*.log": TIMES,
    "logs/*.log": TIMES,
    "integration/logs/*.log": TIMES,
    "*/benchmarks/*.tsv": "run time and memory of this run",
    "benchmarks/*.tsv": "run time and memory of this run",
    "*/models/inference.json": "inference speed measured while the job ran",
    "integration/reading.md": "names the fastest integrator, read from the timings",
    "integration/error_vs_time.png": "plots the timings",
    "*/presets.png": "plots inference and training times",
    "*/stats/error_vs_cost.png": "plots training time and the probing estimate",
    "*/stats/error_vs_time.png": "plots training time",
    "summary.md": "quotes collection and inference speed (its other figures are compared at the source)",
    # The collection of KILLED_SCENE was killed and resumed on purpose: its frames and labels must
    # equal the uninterrupted run's, but the per-point clock counts from the start of each run.
    f"{KILLED_SCENE}/raw.zarr/t_s/*": "capture clock restarts with the resumed run",
    f"{KILLED_SCENE}/raw.zarr/hardware_s/*": "printer-time clock restarts with the resumed run",
}
# Tables compared without their timing columns: pattern -> (columns, why).
TIMING_COLUMNS = {
    "*/models/P*/losses.csv": (["seconds"], "training time per epoch"),
    "*/cv/*/fold*/losses.csv": (["seconds"], "training time per epoch"),
    "*/sim2real/*losses.csv": (["seconds"], "training time per epoch"),
    "*/stats/error_vs_time.csv": (["seconds"], "training time of each snapshot"),
    # Estimated probing time comes from the collection runs that finished, so after a killed run
    # it leaves out the killed run's share (a gap of the collection summary, docs/how-to/slurm.md).
    f"{KILLED_SCENE}/stats/error_vs_cost.csv": (
        ["training_min", "probing_h"],
        "training time; probing estimate without the killed run's share",
    ),
    "*/stats/error_vs_cost.csv": (["training_min"], "training time"),
    "*/presets.csv": (["ms_per_frame", "train_s"], "inference and training times"),
    "integration/error_vs_time.csv": (["ms_per_frame"], "integrator timings"),
    "*/quick/rounds.csv": (["train_s"], "each round's labelling, scoring and training time"),
    "*/quick/rounds/r*/losses.csv": (["seconds"], "training time per check"),
}
# JSON compared without these keys, at any depth: durations; for the killed and resumed collection
# also its per-run record (the one finished run covers the points after the kill) and the hardware
# estimate summed from it.
DURATIONS = ["duration_s", "frames_per_s"]
RESUMED_RUN = [*DURATIONS, "estimated_hardware_s", "runs"]
TIMING_KEYS = {
    f"{KILLED_SCENE}/collect/summary.json": (RESUMED_RUN, "durations; the resumed run's record"),
    f"{KILLED_SCENE}/raw.zarr/zarr.json": (RESUMED_RUN, "durations; the resumed run's record"),
    f"{KILLED_SCENE}/raw.zarr/captured/zarr.json": (RESUMED_RUN, "the resumed run's record"),
    "*/collect/summary.json": (DURATIONS, "collection durations"),
    "*/raw.zarr/captured/zarr.json": (DURATIONS, "collection durations"),
    "*/raw.zarr/zarr.json": (DURATIONS, "collection durations"),
    "*/objects/pressing/summary.json": (["seconds", "seconds_per_press"], "pressing wall time"),
    "*/quick/stop.json": (["wall_s"], "the quick stage's wall time"),
}
# Rules that drive the printer: local rules, run by Snakemake on this machine, never through sbatch.
PRINTER_RULES = ("collect", "object_presses")


class CheckFailed(Exception):
    pass


def check(condition: bool, message: str) -> None:
    if not condition:
        raise CheckFailed(message)
    print(f"  ok  {message}", flush=True)


def matches(relative: str, patterns) -> str | None:
    return next((p for p in patterns if fnmatch.fnmatch(relative, p)), None)


# ---------------------------------------------------------------------------------------------
# Runs


def write_config(work: Path, *workdirs: Path) -> Path:
    """tests/config/test.yaml with the real-data path made absolute. An imported scene reads
    `data/<scene>` relative to each run's work directory: a copy per run, so the cluster's copy can
    be damaged while the local run reads its own, and both runs see the same configuration."""
    config = yaml.safe_load((REPO / "tests/config/test.yaml").read_text())
    if "realism" in config:
        config["realism"]["real"] = str((REPO / config["realism"]["real"]).resolve())
    for name, scene in config["scenes"].items():
        if "import" in scene:
            source = (REPO / scene["import"]["path"]).resolve()
            for workdir in workdirs:
                shutil.rmtree(workdir / "data" / name, ignore_errors=True)
                shutil.copytree(source, workdir / "data" / name)
            scene["import"]["path"] = f"data/{name}"
    # The collection writes captured points in batches, one a second (threedcal.collect.run):
    # registration presses (not trained on) make KILLED_SCENE's collection last several seconds,
    # so that the kill after KILL_AFTER points falls between two batches.
    config["scenes"][KILLED_SCENE]["plan"]["registration"] = {"spacing_mm": 0.6, "depth_mm": 0.4}
    path = work / "test.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def snakemake_command(workdir: Path, config: Path, *args: str) -> list[str]:
    """This repository's workflow on `config`, in `workdir` (the launch directory does not matter)."""
    workflow = ["-s", str(REPO / "Snakefile"), "-d", str(workdir)]
    return [str(SNAKEMAKE), *workflow, "--configfile", str(config), *args]


def start_logged(command: list[str], log: Path) -> subprocess.Popen:
    with log.open("w") as out:
        return subprocess.Popen(
            command, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )


def finish(process: subprocess.Popen, timeout: float, what: str) -> int:
    try:
        return process.wait(timeout)
    except subprocess.TimeoutExpired:
        raise CheckFailed(f"{what} did not end within {timeout:.0f} s") from None
    finally:
        stop(process)


def stop(process: subprocess.Popen) -> None:
    """End a Snakemake we started, if still running: Ctrl-C first (it cancels its Slurm jobs)."""
    if process.poll() is not None:
        return
    os.killpg(process.pid, signal.SIGINT)
    try:
        process.wait(60)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def captured_points(store: Path) -> tuple[int, int]:
    import zarr

    try:
        captured = zarr.open_group(str(store), mode="r")["captured"][:]
    except Exception:  # not made yet, or caught mid-write
        return 0, 0
    return int(captured.sum()), int(captured.size)


def descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def collection_processes(snakemake_pid: int, scene: str) -> list[int]:
    """The `collect` job's script processes of `scene` under this Snakemake (rule scripts run as
    `python .snakemake/scripts/tmpXXXX.collect.py`, their log open under results/{scene}/)."""
    return [
        p
        for p in descendants(snakemake_pid)
        if cmdline(p).rstrip().endswith(".collect.py") and writes_under(p, f"results/{scene}/")
    ]


def writes_under(pid: int, folder: str) -> bool:
    """Whether the process holds a file open under `folder` (its job's log)."""
    try:
        return any(folder in os.readlink(fd) for fd in Path(f"/proc/{pid}/fd").iterdir())
    except OSError:
        return False


def run_cluster_with_failures(work: Path, config: Path, workdir: Path, timeout: float) -> float:
    """First cluster run: an unreadable image, and the collection of KILLED_SCENE killed mid-way."""
    command = snakemake_command(
        workdir, config, "--profile", str(PROFILE), *FAST_STATUS, "--keep-going"
    )
    log = work / "slurm-run1.log"
    partial = workdir / f"results/{KILLED_SCENE}/.partial/raw.zarr"
    start = time.monotonic()
    killed = 0
    with log.open("w") as out:
        process = subprocess.Popen(
            command, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
        try:
            while process.poll() is None and time.monotonic() - start < timeout:
                if not killed and captured_points(partial)[0] >= KILL_AFTER:
                    for pid in collection_processes(process.pid, KILLED_SCENE):
                        os.kill(pid, signal.SIGKILL)
                        killed = pid
                time.sleep(0.1)
            if process.poll() is None:
                raise CheckFailed(f"the first cluster run did not end within {timeout:.0f} s")
        finally:
            stop(process)
    seconds = time.monotonic() - start
    print(f"cluster run 1 (two failures on purpose): {seconds:.0f} s, exit {process.returncode}")
    check(killed != 0, f"killed the collection of {KILLED_SCENE} (pid {killed}) mid-way")
    check(process.returncode != 0, "the run reports the failures (non-zero exit)")
    return seconds


# ---------------------------------------------------------------------------------------------
# Slurm accounting


def sacct_jobs(since: str) -> pd.DataFrame:
    fields = "JobID,JobName,Partition,State,Elapsed,ReqMem,MaxRSS,AllocTRES,Comment"
    text = subprocess.run(
        ["sacct", "-P", "-n", "-S", since, f"--format={fields}"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    table = pd.read_csv(
        io.StringIO(text), sep="|", names=fields.split(","), dtype=str, keep_default_na=False
    )
    steps = table[table["JobID"].str.contains(r"\.")]
    jobs = table[~table["JobID"].str.contains(r"\.")].copy()
    rss = steps.assign(base=steps["JobID"].str.split(".").str[0]).groupby("base")["MaxRSS"]
    jobs["MaxRSS"] = jobs["JobID"].map(rss.agg(lambda v: max(v, key=_kib)))
    jobs["rule"] = jobs["Comment"].str.extract(r"^rule_(\w+?)(?:_wildcards_|$)")[0]
    jobs["wildcards"] = jobs["Comment"].str.extract(r"_wildcards_(.*)$")[0].fillna("")
    return jobs.reset_index(drop=True)


def _kib(value: str) -> float:
    units = {"K": 1, "M": 1024, "G": 1024**2}
    if not value:
        return 0.0
    return float(value[:-1]) * units[value[-1]] if value[-1] in units else float(value) / 1024


# ---------------------------------------------------------------------------------------------
# Equality


def compare_results(local: Path, cluster: Path) -> list[tuple[str, str, str]]:
    """(file, verdict, note) for every output; raises CheckFailed listing the differences."""
    files = sorted(
        {p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file()}
        | {p.relative_to(cluster).as_posix() for p in cluster.rglob("*") if p.is_file()}
    )
    rows, problems = [], []
    for relative in files:
        one, two = local / relative, cluster / relative
        if not one.exists() or not two.exists():
            problems.append(f"{relative}: only in the {'cluster' if two.exists() else 'local'} run")
            continue
        if one.read_bytes() == two.read_bytes():
            rows.append((relative, "equal bytes", ""))
            continue
        if pattern := matches(relative, EXCLUDED):
            rows.append((relative, "not compared", EXCLUDED[pattern]))
            continue
        if pattern := matches(relative, TIMING_COLUMNS):
            columns, why = TIMING_COLUMNS[pattern]
            a = pd.read_csv(one).drop(columns=columns)
            b = pd.read_csv(two).drop(columns=columns)
            if a.equals(b):
                rows.append((relative, "equal but", f"{', '.join(columns)}: {why}"))
                continue
        elif pattern := matches(relative, TIMING_KEYS):
            keys, why = TIMING_KEYS[pattern]
            if _drop(json.loads(one.read_text()), keys) == _drop(json.loads(two.read_text()), keys):
                rows.append((relative, "equal but", f"{', '.join(keys)}: {why}"))
                continue
        problems.append(f"{relative}: differs")
    if problems:
        raise CheckFailed("local and cluster outputs differ:\n    " + "\n    ".join(problems))
    return rows


# Column names that hold a duration measured on the machine that ran the job.
TIMED_COLUMNS = {
    "seconds",
    "ms_per_frame",
    "train_s",
    "training_min",
    "study_seconds",
    "twice_seconds",
}


def uncovered_timing_tables(results: Path) -> list[str]:
    """Tables under `results` with a timing column that no rule above exempts: the cluster run
    would differ from the local one there, so a new such output needs its line in TIMING_COLUMNS."""
    missing = []
    for path in sorted(results.rglob("*.csv")):
        relative = path.relative_to(results).as_posix()
        if matches(relative, TIMING_COLUMNS) or matches(relative, EXCLUDED):
            continue
        header = path.open().readline().strip().split(",")
        if TIMED_COLUMNS & set(header):
            missing.append(relative)
    return missing


def _drop(value, keys):
    if isinstance(value, dict):
        return {k: _drop(v, keys) for k, v in value.items() if k not in keys}
    if isinstance(value, list):
        return [_drop(v, keys) for v in value]
    return value


# ---------------------------------------------------------------------------------------------


def cluster_runs(
    work: Path, config: Path, cluster: Path, damaged: Path, original: bytes, timeout: float
) -> tuple[float, float]:
    """The first cluster run (a damaged image, a killed collection), its checks, the repair and the
    rerun. Returns both runs' seconds."""
    try:
        run1_s = run_cluster_with_failures(work, config, cluster, timeout)
    finally:
        damaged.write_bytes(original)
    stage_log = cluster / f"results/{FAILING_SCENE}/logs/dataset.log"
    check(
        stage_log.is_file()
        and "not a readable image" in stage_log.read_text()
        and damaged.name in stage_log.read_text(),
        f"the failed job's log {stage_log.relative_to(cluster)} names the unreadable image",
    )
    slurm_logs = list((cluster / f".snakemake/slurm_logs/rule_{FAILING_RULE}").rglob("*.log"))
    check(
        any("not a readable image" in p.read_text() for p in slurm_logs),
        "Slurm's log of the failed job is kept ("
        + ", ".join(str(p.relative_to(cluster)) for p in slurm_logs)
        + ")",
    )
    run1_log = (work / "slurm-run1.log").read_text()
    check(
        str(stage_log.relative_to(cluster)) in run1_log,
        "Snakemake's report of the failure points at that log",
    )
    partial = cluster / f"results/{KILLED_SCENE}/.partial/raw.zarr"
    done, total = captured_points(partial)
    check(
        0 < done < total and not (cluster / f"results/{KILLED_SCENE}/raw.zarr").exists(),
        f"the killed collection kept its partial store ({done} of {total} points in "
        f"{partial.relative_to(cluster)})",
    )
    for leaf in ("tiny_reskin/reskin_eval.json", "integration/error_vs_time.csv"):
        check((cluster / "results" / leaf).is_file(), f"independent work finished anyway ({leaf})")

    # 3. Repair (done above) and rerun: only what failed, and what follows it.
    dry = subprocess.run(
        snakemake_command(cluster, config, "--profile", str(PROFILE), "--dry-run"),
        capture_output=True,
        text=True,
        check=True,
    )
    planned = parse_jobs(dry.stdout + dry.stderr)
    rules = {rule for rule, _ in planned}
    check(
        ("collect", f"scene={KILLED_SCENE}") in planned
        and (FAILING_RULE, f"scene={FAILING_SCENE}") in planned
        and not rules & {"integration_study", "realism", "environment", "scene", "reskin_train"}
        and ("collect", "scene=tiny_reskin") not in planned,
        f"the rerun plans only the failed work and what follows it ({len(planned)} jobs: "
        f"{', '.join(sorted(rules))})",
    )
    run2_start = time.monotonic()
    rc = finish(
        start_logged(
            snakemake_command(cluster, config, "--profile", str(PROFILE), *FAST_STATUS),
            work / "slurm-run2.log",
        ),
        timeout,
        "the cluster rerun",
    )
    run2_s = time.monotonic() - run2_start
    print(f"cluster run 2 (rerun after the repair): {run2_s:.0f} s, exit {rc}")
    check(rc == 0, f"the rerun succeeded (log: {work / 'slurm-run2.log'})")
    store_attrs = json.loads((cluster / f"results/{KILLED_SCENE}/raw.zarr/zarr.json").read_text())
    runs = store_attrs["attributes"]["runs"]
    check(
        runs[-1]["resumed_at"] >= KILL_AFTER,
        f"the collection resumed at point {runs[-1]['resumed_at']}, not from the start",
    )
    return run1_s, run2_s


def parse_jobs(text: str) -> list[tuple[str, str]]:
    """(rule, wildcards) of each job a dry run lists."""
    jobs = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", text):
        match = re.match(r"(?:local)?rule (\w+):", block.strip())
        if match:
            wildcards = re.search(r"^\s+wildcards: (.*)$", block, re.MULTILINE)
            jobs.append((match.group(1), wildcards.group(1) if wildcards else ""))
    return jobs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workdir", type=Path, help="an empty directory for both runs")
    parser.add_argument("--timeout", type=float, default=900, help="seconds per Snakemake run")
    parser.add_argument(
        "--reuse-local",
        action="store_true",
        help="keep WORKDIR's local run from an earlier check (redo only the cluster part)",
    )
    args = parser.parse_args(argv)
    work = args.workdir.resolve()
    work.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    since = time.strftime("%Y-%m-%dT%H:%M:%S")
    print(f"cluster check in {work} (Slurm config: {os.environ.get('SLURM_CONF', 'default')})")
    _check_controller()
    local, cluster = work / "local", work / "slurm"
    shutil.rmtree(cluster, ignore_errors=True)
    if not args.reuse_local:
        shutil.rmtree(local, ignore_errors=True)
    config = write_config(work, local, cluster)

    # 1. Local reference, bare `snakemake --cores 2`, beside the cluster runs, filling the cores
    # while they wait on Slurm.
    local_start = time.monotonic()
    local_run = start_logged(snakemake_command(local, config, "--cores", "2"), work / "local.log")

    # 2-3. The cluster runs (two failures on purpose, then the rerun) beside the local run.
    damaged = sorted((cluster / "data" / FAILING_SCENE).glob("*.png"))[0]
    original = damaged.read_bytes()
    damaged.write_bytes(b"not a PNG: made unreadable by workflow/cluster/check.py")
    try:
        run1_s, run2_s = cluster_runs(work, config, cluster, damaged, original, args.timeout)
    finally:
        rc = finish(local_run, args.timeout, "the local run")
    local_s = time.monotonic() - local_start
    print(f"local run (snakemake --cores 2, no profile, beside the cluster runs): {local_s:.0f} s")
    check(rc == 0, f"the local run succeeded (log: {work / 'local.log'})")
    _check_where_jobs_ran(sacct_jobs(since), work, cluster)  # 4.
    _check_equal_results(local / "results", cluster / "results")  # 5.
    total_s = time.monotonic() - started
    print(
        f"\ncluster check passed in {total_s:.0f} s (local {local_s:.0f} s, "
        f"cluster {run1_s:.0f} + {run2_s:.0f} s)"
    )
    return 0


def _check_controller() -> None:
    try:
        ping = subprocess.run(["scontrol", "ping"], capture_output=True, text=True, timeout=30)
    except FileNotFoundError:
        raise CheckFailed("scontrol not found: no Slurm client on this machine") from None
    check(
        ping.returncode == 0 and "UP" in ping.stdout,
        f"a Slurm controller answers ({ping.stdout.strip()})",
    )


def _check_where_jobs_ran(jobs: pd.DataFrame, work: Path, cluster: Path) -> None:
    """The printer's rules ran locally, training on the GPU partition, every job completed but
    the failure made on purpose."""
    check(len(jobs) > 0, f"sacct lists {len(jobs)} Slurm jobs of these runs")
    runs_log = (work / "slurm-run1.log").read_text() + (work / "slurm-run2.log").read_text()
    for rule in PRINTER_RULES:
        check(rule not in set(jobs["rule"]), f"no {rule} job went to Slurm (a local rule)")
        check(
            f"localrule {rule}:" in runs_log,
            f"Snakemake ran {rule} itself (`localrule {rule}` in its log)",
        )
    train = jobs[jobs["rule"] == "train"]
    check(
        len(train) > 0
        and (train["Partition"] == "gpu").all()
        and train["AllocTRES"].str.contains("gres/gpu=1").all(),
        f"{len(train)} training jobs ran in partition gpu with one GPU allocated",
    )
    devices = {
        log.name: re.search(r"training P=\d+(?: r\d+)? on (\S+)", log.read_text())
        for log in sorted((cluster / "results").glob("*/logs/train_P*.log"))
    }
    named = {name: m.group(1) if m else "?" for name, m in devices.items()}
    fell_back = set(named.values()) == {"cpu"}
    check(
        bool(named) and "?" not in named.values(),
        "the training jobs log their device: "
        + ", ".join(f"{name} {device}" for name, device in named.items())
        + (" (no CUDA device behind the allocated GPU: training fell back to the CPU)" * fell_back),
    )
    failed = jobs[jobs["State"] != "COMPLETED"]
    check(
        set(failed["rule"]) == {FAILING_RULE},
        f"every Slurm job completed but the failure made on purpose ({FAILING_RULE})",
    )
    print("\nSlurm jobs (sacct):")
    shown = jobs[
        ["JobID", "rule", "wildcards", "Partition", "State", "Elapsed", "ReqMem", "MaxRSS"]
    ]
    print(shown.to_string(index=False))


def _check_equal_results(local: Path, cluster: Path) -> None:
    """The cluster's results are the local run's, byte for byte where they can be."""
    rows = compare_results(local, cluster)
    table = pd.DataFrame(rows, columns=["file", "verdict", "note"])
    equal = table[table["verdict"] == "equal bytes"]["file"]
    headline = sorted(
        f
        for f in equal
        if fnmatch.fnmatch(f, "*/models/P*/model.pt")
        or f.endswith(
            ("objects/errors.csv", "stats/tests.csv", "ball_eval.json", "reskin_eval.json")
        )
    )
    print(f"\nlocal against cluster outputs ({len(table)} files):")
    print(f"  equal bytes: {len(equal)} files, among them")
    for name in headline:
        print(f"      {name}")
    for _, row in table[table["verdict"] == "equal but"].iterrows():
        columns, why = row["note"].split(": ", 1)
        print(f"  equal but for {columns} ({why}): {row['file']}")
    skipped = table[table["verdict"] == "not compared"].groupby("note")["file"].agg(list)
    for note, names in skipped.items():
        shown = ", ".join(names[:3]) + (f", ... ({len(names)} files)" if len(names) > 3 else "")
        print(f"  not compared ({note}): {shown}")
    for scene, leaf in [
        (KILLED_SCENE, "models/P80/r0/model.pt"),
        (KILLED_SCENE, "objects/errors.csv"),
        (KILLED_SCENE, "stats/tests.csv"),
        (FAILING_SCENE, "models/P80/r0/model.pt"),
    ]:
        check(f"{scene}/{leaf}" in set(equal), f"{scene}/{leaf}: equal bytes")


if __name__ == "__main__":
    try:
        sys.exit(main())
    except CheckFailed as failure:
        print(f"  FAILED  {failure}", file=sys.stderr)
        sys.exit(1)
