"""Per-rule memory and time from a run's benchmark files, and the profile figures they suggest.

Every rule writes `results/{scene}/benchmarks/{rule}.tsv` (study-wide: `results/benchmarks/`), one
row with Snakemake's measurements of the job's script: `s` (wall seconds), `cpu_time` (CPU seconds)
and `max_rss` (MB). This takes the largest of each rule over its jobs and suggests the Slurm
profile's `mem_mb` and `runtime` with a margin:

    mem_mb  = max_rss x 1.5 + 500 MB for the Snakemake processes around the script on a node
              (sacct MaxRSS - max_rss was 125-290 MB in `make cluster-test`), rounded up to 500 MB
    runtime = time x 3 in minutes, rounded up to 5, at least 10

The time is `cpu_time` by default: the job's own work, which a node with the job's CPUs to itself
gives back as wall time or less; `s` on a shared machine counts the other users too (on ours,
under load, `presets` took 3813 s of wall time for 385 s of CPU). `--time s` uses wall time.

    .venv/bin/python workflow/cluster/resources.py results            # after a run of your study
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import pandas as pd

MEMORY_FACTOR, MEMORY_EXTRA_MB, MEMORY_STEP_MB = 1.5, 500, 500
TIME_FACTOR, TIME_STEP_MIN, TIME_MIN_MIN = 3, 5, 10


# A job's benchmark file is its rule's name with the job's wildcards (rules/*.smk, `benchmark:`);
# these name the rule back, so that the jobs of one rule share one suggestion.
_RULE_OF_JOB = (
    (
        re.compile(r"^train_P\d+(_r\d+)?$"),
        "train",
    ),  # train_P{p}_r{r} (train_P{p} before replicates)
    (re.compile(r"^train_ablation_P\d+$"), "train_ablation"),  # a fraction's replicates together
    (re.compile(r"^pretrain_\w+$"), "pretrain"),  # pretrain_{sensor}
    (re.compile(r"^cv_train_fold\d+$"), "cv_train"),  # cv_train_fold{fold}
    (re.compile(r"^sim2real_(simulate|pretrain)_folds\d+(-\d+)*$"), r"sim2real_\1"),
    (re.compile(r"^sim2real_[a-z_]+_fold\d+$"), "sim2real_train"),  # _{condition}_fold{fold}
)


def rule_of(path: Path) -> str:
    """results/x/benchmarks/train_P20_r1.tsv -> train: the Snakemake rule whose job wrote it."""
    for pattern, rule in _RULE_OF_JOB:
        if pattern.match(path.stem):
            return pattern.sub(rule, path.stem)
    return path.stem


def measured(results: Path) -> pd.DataFrame:
    rows = []
    for path in sorted(results.glob("**/benchmarks/*.tsv")):
        table = pd.read_csv(path, sep="\t")
        for _, row in table.iterrows():
            rows.append({"rule": rule_of(path), "job": str(path.relative_to(results)), **row})
    if not rows:
        raise SystemExit(f"{results}: no benchmarks/*.tsv below it (run the study first)")
    frame = pd.DataFrame(rows)
    for column in ("max_rss", "cpu_time"):
        frame[column] = pd.to_numeric(frame[column], errors="coerce")
    return frame


def suggest(frame: pd.DataFrame, time: str = "cpu_time") -> pd.DataFrame:
    by_rule = frame.groupby("rule").agg(
        jobs=("job", "size"),
        max_rss_mb=("max_rss", "max"),
        max_s=("s", "max"),
        max_cpu_s=("cpu_time", "max"),
    )
    basis = by_rule["max_cpu_s" if time == "cpu_time" else "max_s"]
    by_rule["mem_mb"] = [
        math.ceil((rss * MEMORY_FACTOR + MEMORY_EXTRA_MB) / MEMORY_STEP_MB) * MEMORY_STEP_MB
        for rss in by_rule["max_rss_mb"].fillna(0)
    ]
    by_rule["runtime"] = [
        max(TIME_MIN_MIN, math.ceil(s * TIME_FACTOR / 60 / TIME_STEP_MIN) * TIME_STEP_MIN)
        for s in basis
    ]
    return by_rule.round({"max_rss_mb": 0, "max_s": 1, "max_cpu_s": 1}).sort_values(
        "max_cpu_s", ascending=False
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="a run's results/ folder")
    parser.add_argument(
        "--time", choices=["cpu_time", "s"], default="cpu_time", help="the runtime's basis"
    )
    args = parser.parse_args(argv)
    print(suggest(measured(args.results), args.time).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
