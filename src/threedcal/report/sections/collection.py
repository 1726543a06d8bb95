"""The summary's rows of a collected scene: how long probing took (collect/summary.json) and how
well the frames were registered to the printer (dataset/registration.json)."""

from __future__ import annotations

from pathlib import Path

from threedcal.report.sections.markdown import figure, read_json


def collection_facts(root: Path) -> list[tuple[str, str]]:
    facts = []
    summary = read_json(root / "collect" / "summary.json")
    if summary:
        hours = summary["estimated_hardware_s"] / 3600
        facts += [
            ("probe points / frames", f"{summary['points']} / {summary['frames']}"),
            (
                "estimated probing time on the real printer",
                f"{hours:.2f} h ({summary['estimated_hardware_s']:.0f} s)",
            ),
            (
                "collection here (simulated)",
                f"{summary['duration_s']:.1f} s, {figure(summary['frames_per_s'], 1)} frames/s",
            ),
        ]
    registration = read_json(root / "dataset" / "registration.json")
    if registration:
        error = registration.get("error_px")
        facts.append(
            (
                "registration residual / error vs hidden truth",
                f"{registration['residual_px']:.3f} px / {figure(error, 3)} px",
            )
        )
        facts.append(
            ("first-touch offset (estimated)", f"{registration['touch_offset_mm']:+.3f} mm")
        )
    return facts
