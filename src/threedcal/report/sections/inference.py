"""Inference speed: a scene's model turning frames into depth maps on the host's CPU
(models/inference.json), for the page and for each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    markdown_table,
    missing_file,
    read_json,
)
from threedcal.report.sections.records import recorded_config, recorded_sensor, simulated_cell
from threedcal.rig import is_magnetic
from threedcal.study.config import is_quick


def inference_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    # a quick scene's model is timed by no stage (its rounds are its figures)
    chosen = {
        name: r
        for name, r in scenes.items()
        if not is_magnetic(recorded_sensor(r)) and not is_quick(recorded_config(r))
    }
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "models" / "inference.json"
        fps = read_json(path)
        sim = simulated_cell(record)
        if fps is None:
            rows.append([f"`{name}`", sim, missing_file(path, results)] + [MISSING] * 4)
            continue
        shape = fps.get("image_shape") or []
        rows.append(
            [
                f"`{name}`",
                sim,
                str(fps.get("preset", MISSING)),
                f"{fps['frames_per_s']:.1f}",
                f"{fps['ms_per_frame']:.1f}",
                "×".join(str(s) for s in shape) if shape else MISSING,
                str(fps.get("torch_threads", MISSING)),
            ]
        )
    return [
        "## Inference speed",
        "",
        "Protocol: replicate 0 of the largest P turns its scene's frames into depth maps on "
        "this host's CPU, one at a time after a warm-up (`models/inference.json`).",
        "",
        *markdown_table(
            [
                "scene",
                SIM_COLUMN,
                "model preset",
                "frames/s",
                "ms per frame",
                "image H×W px",
                "torch threads",
            ],
            rows,
        ),
        "",
    ]


def inference_facts(root: Path) -> list[tuple[str, str]]:
    """The summary's row of a scene's depth frames/s (models/inference.json)."""
    fps = read_json(root / "models" / "inference.json")
    if not fps:
        return []
    return [("depth inference (P=80 model, CPU)", f"{fps['frames_per_s']:.1f} frames/s")]
