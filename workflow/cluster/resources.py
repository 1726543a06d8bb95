"""Per-rule memory and time from a run's benchmark files, and the profile figures they suggest.

Every rule writes `results/{scene}/benchmarks/{rule}.tsv` (study-wide: `results/benchmarks/`), one
row with Snakemake's measurements of the job's script: `s` (wall seconds) and `max_rss` (MB). This
takes the largest of each rule over its jobs and suggests the Slurm profile's `mem_mb` and `runtime`
with a margin:

    mem_mb  = max_rss x 1.5 + 500 MB for the Snakemake processes around the script on a node,
              rounded up to 500 MB
    runtime = s x 3 in minutes, rounded up to 5, at least 10

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


def rule_of(path: Path) -> str:
    """results/x/benchmarks/train_P20.tsv -> train (one file per job; P is a wildcard)."""
    return re.sub(r"_P\d+$", "", path.stem)


def measured(results: Path) -> pd.DataFrame:
    rows = []
    for path in sorted(results.glob("**/benchmarks/*.tsv")):
        table = pd.read_csv(path, sep="\t")
        for _, row in table.iterrows():
            rows.append({"rule": rule_of(path), "job": str(path.relative_to(results)), **row})
    if not rows:
        raise SystemExit(f"{results}: no benchmarks/*.tsv below it (run the study first)")
    frame = pd.DataFrame(rows)
    frame["max_rss"] = pd.to_numeric(frame["max_rss"], errors="coerce")
    return frame


def suggest(frame: pd.DataFrame) -> pd.DataFrame:
    by_rule = frame.groupby("rule").agg(
        jobs=("job", "size"), max_rss_mb=("max_rss", "max"), max_s=("s", "max")
    )
    by_rule["mem_mb"] = [
        math.ceil((rss * MEMORY_FACTOR + MEMORY_EXTRA_MB) / MEMORY_STEP_MB) * MEMORY_STEP_MB
        for rss in by_rule["max_rss_mb"].fillna(0)
    ]
    by_rule["runtime"] = [
        max(TIME_MIN_MIN, math.ceil(s * TIME_FACTOR / 60 / TIME_STEP_MIN) * TIME_STEP_MIN)
        for s in by_rule["max_s"]
    ]
    by_rule["max_rss_mb"] = by_rule["max_rss_mb"].round(0)
    by_rule["max_s"] = by_rule["max_s"].round(1)
    return by_rule.sort_values("max_s", ascending=False)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="a run's results/ folder")
    args = parser.parse_args(argv)
    print(suggest(measured(args.results)).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
