"""Depth integrators: the study's reading of its analytic-surface comparison
(integration/reading.md), for the page and for the summary."""

from __future__ import annotations

from pathlib import Path


def integrators_section(results: Path) -> list[str]:
    reading = results / "integration" / "reading.md"
    if not reading.is_file():
        return []
    body = [line for line in reading.read_text().splitlines() if not line.startswith("# ")]
    body = "\n".join(body).strip().splitlines()
    # the study's reading up to its advice, which explanation/depth.md gives
    advice = [i for i, line in enumerate(body) if line.startswith("Which method when")]
    body = "\n".join(body[: advice[0]] if advice else body).strip().splitlines()
    return [
        "## Depth integrators",
        "",
        "Protocol: gradient fields of analytic surfaces (exact, or with the scenario's noise, "
        "outliers or border contact), no simulator and no model, integrated and compared with "
        "the surface (`integration/`; which method when: [depth](explanation/depth.md)).",
        "",
        *[f"#{line}" if line.startswith("## ") else line for line in body],
        "",
    ]


def integrator_lines(results: Path) -> list[str]:
    """The summary's section: the study's reading as it is."""
    reading = results / "integration" / "reading.md"
    if not reading.is_file():
        return []
    return ["## Depth integrators", "", reading.read_text().strip(), ""]
