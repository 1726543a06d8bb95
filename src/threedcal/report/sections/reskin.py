"""ReSkin: where the probe touched, from magnetic readings (reskin_eval.json), for the page and for
each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.report.sections.markdown import (
    MISSING,
    SIM_READINGS,
    markdown_table,
    missing_file,
    read_json,
)
from threedcal.report.sections.records import recorded_sensor, simulated_cell
from threedcal.rig import is_magnetic


def reskin_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if is_magnetic(recorded_sensor(r))}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "reskin_eval.json"
        sim = simulated_cell(record).replace("frames", "readings")
        figures = read_json(path)
        if figures is None:
            rows.append([f"`{name}`", sim, missing_file(path, results)] + [MISSING] * 4)
            continue
        protocol = (
            f"{figures.get('n_test_coordinates', '?')} held-out probe coordinates "
            f"({figures.get('n_test_readings', '?')} readings)"
        )
        per_depth = figures.get("per_depth") or {}
        for depth, part in [
            *sorted(per_depth.items(), key=lambda kv: float(kv[0])),
            ("all", figures),
        ]:
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    protocol,
                    depth,
                    f"{part['median_error_mm']:.2f}",
                    f"{part['p90_error_mm']:.2f}",
                    f"{part['depth_mae_mm']:.3f}",
                ]
            )
    return [
        "## ReSkin: where the probe touched",
        "",
        "Protocol: magnetic readings of probe presses on the authors' cross plan; an MLP "
        "predicts contact position and depth at probe coordinates it never trained on (x, y "
        "error; [ReSkin](explanation/reskin.md)).",
        "",
        *markdown_table(
            [
                "scene",
                SIM_READINGS,
                "protocol",
                "press depth mm",
                "median error mm",
                "p90 error mm",
                "depth MAE mm",
            ],
            rows,
        ),
        "",
    ]


def reskin_facts(root: Path) -> list[tuple[str, str]]:
    """The summary's row of a ReSkin scene: localisation error at held-out coordinates."""
    reskin = read_json(root / "reskin_eval.json")
    if not reskin:
        return []
    return [
        (
            "ReSkin localisation (held-out)",
            f"median {reskin['median_error_mm']:.2f} mm, p90 {reskin['p90_error_mm']:.2f} mm, "
            f"depth MAE {reskin['depth_mae_mm']:.3f} mm",
        )
    ]
