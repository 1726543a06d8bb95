"""Where the time goes: the stages' summed `benchmark:` files (threedcal.report.stage_times), for
the page and for the summary."""

from __future__ import annotations

from pathlib import Path

from threedcal.report.stage_times import stage_time_lines, stage_times, study_span

# The page's stage-time table's longest stages; the rest share one row.
TOP_STAGES = 8


def time_section(results: Path) -> list[str]:
    span = study_span(results)
    table = stage_times(results)
    duration = (
        f"{(span[1] - span[0]) / 60:.1f} min from the first job's start to the last one's end; "
        if span
        else ""
    )
    work = (
        f"{table['wall_s'].sum() / 60:.1f} job-minutes (jobs run side by side). "
        if not table.empty
        else ""
    )
    return [
        "## Where the time goes",
        "",
        f"{duration}{work}Per stage from the `benchmark:` files (CPU time and memory: "
        "`threedcal report stage-times`).",
        "",
        *stage_time_lines(table, limit=TOP_STAGES, brief=True),
        "",
    ]


def time_lines(results: Path) -> list[str]:
    """The summary's stage-time table: every stage's jobs, wall and CPU time, memory."""
    return [
        "## Where the time goes",
        "",
        "Each stage's jobs summed from their `benchmark:` files (the jobs that had run when this "
        "page was written; jobs run side by side, so the summed wall time is work, not duration):",
        "",
        *stage_time_lines(stage_times(results)),
        "",
    ]
