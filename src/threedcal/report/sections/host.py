"""Which threedcal, host and date made a study's figures, from its environment.json and benchmark
files: the page's provenance line and the summary's run environment table."""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from pathlib import Path

from threedcal.report.sections.markdown import fact_table, read_json
from threedcal.report.stage_times import study_span


def _widest(flags) -> list[str]:
    """The vector extensions that decide torch's kernels (AVX2, AVX-512, native bfloat16), of a
    CPU's flags: the page names the host, not every flag."""
    flags = flags.split() if isinstance(flags, str) else list(flags)
    return [f for f in ("avx2", "avx512f", "avx512_bf16") if f in flags] or ["no AVX2"]


def provenance_lines(results: Path) -> list[str]:
    """Which threedcal, host and date produced the figures, from what the study recorded."""
    environment = read_json(results / "environment.json") or {}
    software = environment.get("software", {})

    def words(value) -> str:
        if isinstance(value, Mapping):
            return ", ".join(f"{k}={v}" for k, v in value.items())
        return " ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)

    limits = environment.get("isa_limits")
    host = ", ".join(
        str(part)
        for part in (
            environment.get("platform"),
            environment.get("processor"),
            environment.get("cpu"),
            f"{environment['cpu_count']} CPUs" if environment.get("cpu_count") else None,
            f"with {words(_widest(environment['cpu_flags']))}"
            if environment.get("cpu_flags")
            else None,
            f"capped by {words(limits)}" if limits and limits != "none" else None,
            f"torch dispatches {environment['torch_cpu_capability']}"
            if environment.get("torch_cpu_capability")
            else None,
        )
        if part
    )
    span = study_span(results)
    when = (
        datetime.datetime.fromtimestamp(span[1], tz=datetime.timezone.utc).strftime(
            "%Y-%m-%d %H:%M UTC"
        )
        if span
        else None
    )
    facts = [
        f"threedcal {software['threedcal']}" if "threedcal" in software else None,
        f"torch {software['torch']}" if "torch" in software else None,
        f"host {host}" if host else "host not recorded",
        f"last job ended {when}" if when else None,
    ]
    return [
        "Written by `make results-page` from one finished study's `results/` (regenerate, do "
        f"not edit): {'; '.join(f for f in facts if f)} (every version: `environment.json`). "
        "Other hosts give other digits.",
        "",
    ]


def environment_lines(results: Path) -> list[str]:
    """The summary's run environment: every recorded figure and software version, one a row."""
    environment = read_json(results / "environment.json")
    if not environment:
        return []
    rows = [(k, v) for k, v in environment.items() if not isinstance(v, dict)]
    rows += list(environment.get("software", {}).items())
    return ["## Run environment", "", *fact_table(rows), ""]
