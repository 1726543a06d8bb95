"""Where a study's time went: every job's `benchmark:` file (results/**/benchmarks/*.tsv) summed per
stage, for the summary's stage-time table and `threedcal report stage-times`.

A job's file is named after its rule and wildcards (train_P20_r0.tsv, train_ablation_P20.tsv,
cv_train_fold3.tsv, sim2real_real_only_fold1.tsv, sim2real_pretrain_folds0-1-2.tsv); the stage is
the name without the replicate, fraction, k and fold parts, so the jobs of one stage add up.
Snakemake runs `--cores` jobs at once: the summed wall time
is the work, not the run's duration (the Makefile prints that).
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

# The wildcard tails that tell jobs of one stage apart.
_JOB_PARTS = re.compile(r"(_P\d+(_r\d+)?|_k[^_]+_fold\d+|_fold\d+|_folds\d+(-\d+)*)$")


def stage_of(benchmark: Path) -> str:
    return _JOB_PARTS.sub("", benchmark.stem)


def stage_times(results: str | Path) -> pd.DataFrame:
    """One row per (stage, scene): jobs, summed wall and CPU seconds, the longest job, peak memory.

    Sorted by wall time, longest first; `scene` is empty for study-wide stages."""
    results = Path(results)
    rows = []
    for path in sorted(results.glob("**/benchmarks/*.tsv")):
        table = pd.read_csv(path, sep="\t")
        if table.empty:
            continue
        last = table.iloc[-1]  # a rerun appends its own line
        scope = path.parent.parent
        rows.append(
            {
                "stage": stage_of(path),
                "scene": "" if scope == results else scope.relative_to(results).as_posix(),
                "wall_s": float(last["s"]),
                "cpu_s": float(last["cpu_time"]),
                "max_rss_mb": float(last["max_rss"]),
            }
        )
    columns = ["stage", "scene", "jobs", "wall_s", "cpu_s", "longest_job_s", "max_rss_mb"]
    if not rows:
        return pd.DataFrame(columns=columns)
    jobs = pd.DataFrame(rows)
    grouped = jobs.groupby(["stage", "scene"], sort=False)
    table = grouped.agg(
        jobs=("wall_s", "size"),
        wall_s=("wall_s", "sum"),
        cpu_s=("cpu_s", "sum"),
        longest_job_s=("wall_s", "max"),
        max_rss_mb=("max_rss_mb", "max"),
    ).reset_index()
    return table.sort_values("wall_s", ascending=False, kind="stable").reset_index(drop=True)[
        columns
    ]


def study_span(results: str | Path) -> tuple[float, float] | None:
    """(first job's start, last job's end) in seconds since the epoch, from the benchmark files:
    each is written when its job ends (its modification time), `s` seconds after the job began.
    None without benchmark files. A study resumed over several sessions spans them all, and a
    copied results folder carries the copy's times unless the copy kept them."""
    starts, ends = [], []
    for path in Path(results).glob("**/benchmarks/*.tsv"):
        table = pd.read_csv(path, sep="\t")
        if table.empty:
            continue
        end = path.stat().st_mtime
        starts.append(end - float(table.iloc[-1]["s"]))
        ends.append(end)
    return (min(starts), max(ends)) if ends else None


def stage_time_lines(table: pd.DataFrame, limit: int = 15, brief: bool = False) -> list[str]:
    """Markdown: the `limit` longest stages, then the rest in one line (its scene column "—"),
    then the total. `brief`: the stage (its scene in brackets), jobs, wall time and share only (no
    CPU time, longest job or memory)."""
    if table.empty:
        return ["No benchmark files yet."]
    total_wall, total_cpu = table["wall_s"].sum(), table["cpu_s"].sum()
    header = ["stage", "scene", "jobs", "wall min", "share", "CPU min", "longest job min"]
    header.append("peak RSS MB")
    if brief:
        header = ["stage (scene)", "jobs", "wall min", "share"]

    def line(cells: list[str]) -> str:
        return "|" + "|".join(f" {cell} " if cell else " " for cell in cells[: len(header)]) + "|"

    def row(stage, scene, jobs, wall, cpu, longest, rss) -> str:
        share = 100 * wall / total_wall if total_wall > 0 else 0.0
        if brief:
            where = [f"{stage} ({scene})" if scene and scene != "—" else str(stage)]
        else:
            where = [str(stage), scene or "(study)"]
        return line(
            [
                *where,
                str(jobs),
                f"{wall / 60:.1f}",
                f"{share:.0f} %",
                f"{cpu / 60:.1f}",
                f"{longest / 60:.1f}",
                f"{rss:.0f}",
            ]
        )

    lines = [line(header), "|" + "|".join(["---"] * len(header)) + "|"]
    for item in table.head(limit).itertuples(index=False):
        lines.append(row(*item))
    rest = table.iloc[limit:]
    if len(rest):
        lines.append(
            row(
                f"{len(rest)} other stages",
                "—",
                int(rest["jobs"].sum()),
                rest["wall_s"].sum(),
                rest["cpu_s"].sum(),
                rest["longest_job_s"].max(),
                rest["max_rss_mb"].max(),
            )
        )
    total = ["**all**", *([] if brief else [""]), str(int(table["jobs"].sum()))]
    total += [f"{total_wall / 60:.1f}", "100 %"]
    lines.append(line([*total, f"{total_cpu / 60:.1f}", "", ""]))
    return lines
