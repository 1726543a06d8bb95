"""`threedcal report stage-times`: where a study's time went (apart from the results page, whose
tables and statistics this needs none of)."""

from __future__ import annotations

import argparse

import threedcal.report.stage_times as times


def run_report_stage_times(args: argparse.Namespace) -> int:
    print("\n".join(times.stage_time_lines(times.stage_times(args.results))))
    return 0
