"""`threedcal report results-page`: the results page from a finished study's results/ folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from threedcal.report.results_page import write_results_page


def run_report_results_page(args: argparse.Namespace) -> int:
    out = Path(args.out)
    write_results_page(args.results, out)
    print(f"{out}: written from {args.results}")
    return 0
