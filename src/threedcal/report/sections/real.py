"""Real frames: imported scenes' cross-validated accuracy (ball_eval.json) and the shipped weights
on real folders (real_check/table.csv), for the page and for each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    bounds_suffix,
    cross_validated,
    figure,
    markdown_table,
    missing_file,
    read_json,
)
from threedcal.report.sections.records import recorded_config, simulated_cell
from threedcal.report.sections.sim2real import sim2real_section
from threedcal.study.config import is_imported
from threedcal.study.paths import has_sim2real


def real_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Imported scenes: the cross-validated figures, then sim-to-real."""
    chosen = {name: r for name, r in scenes.items() if is_imported(recorded_config(r))}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "ball_eval.json"
        sim = simulated_cell(record)
        ball = read_json(path)
        if ball is None:
            rows.append([f"`{name}`", sim, MISSING, MISSING, missing_file(path, results), MISSING])
            rows[-1].append(MISSING)
            continue
        folds = (ball.get("protocol") or {}).get("folds")
        protocol = f"{folds}-fold grouped cross-validation" if folds else "held-out images"
        for method, figures in (
            (f"model ({ball.get('preset', 'model')})", ball.get("model", ball)),
            ("colour lookup", ball.get("lookup")),
        ):
            if not figures:
                continue
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    protocol,
                    method,
                    cross_validated(figures, "gradient_rmse", 3),
                    cross_validated(figures, "cap_depth_mae_um", 0),
                    str(figures.get("n_test_images", ball.get("n_test_images", MISSING))),
                ]
            )
    lines = [
        "## Real frames: cross-validated accuracy",
        "",
        "Protocol: each press's images in one fold, each image tested by the model trained "
        "without its fold; error inside each contact's evaluation circle, bootstrap over press "
        "groups ([real data](explanation/real-data.md)).",
        "",
        *markdown_table(
            [
                "scene",
                SIM_COLUMN,
                "protocol",
                "method",
                "gradient RMSE",
                "cap depth MAE µm",
                "test images",
            ],
            rows,
        ),
        "",
    ]
    lines += sim2real_section(
        {n: r for n, r in chosen.items() if has_sim2real(recorded_config(r))}, results
    )
    return lines


def real_check_section(results: Path) -> list[str]:
    """The shipped weights on real frames (results/real_check/table.csv), when the study ran it."""
    path = results / "real_check" / "table.csv"
    if not path.is_file():
        return []
    table = pd.read_csv(path)
    rows = [
        [
            f"`{Path(str(r['set'])).name}`",
            "pretraining only (real test frames)",
            str(r["weights"]),
            str(r["frames_read"]),
            str(int(r["frames"])),
            f"{100 * r['within_bound']:.0f} %",
            f"{r['area_ratio_median']:.2f} ({r['area_ratio_p90']:.2f})",
            f"{r['centroid_error_mm_median']:.2f} ({100 * r['centroid_within_0p2mm']:.0f} %)",
            f"{r['peak_mm_median']:.2f} / {r['allowed_mm_median']:.2f}",
        ]
        for _, r in table.iterrows()
    ]
    header = [
        "set",
        SIM_COLUMN,
        "weights",
        "frames read",
        "frames",
        "contact within the ball",
        "contact / ball's disc, median (p90)",
        "centroid error mm, median (within 0.2 mm)",
        "peak / allowed depth mm",
    ]
    return [
        "### The shipped weights on real frames: depth only where the ball is?",
        "",
        "Protocol: each real folder read with its own blank at the weights' frame size; contact = "
        "depth above 0.05 mm, against the ball's disc πR²; centroid against the located contact; "
        "peak against the located contact's cap depth. Fine-tuned: on the folder's fitting half "
        "(the realism split), read on the other ([real data](explanation/real-data.md)).",
        "",
        *markdown_table(header, rows),
        "",
    ]


def ball_facts(root: Path) -> list[tuple[str, str]]:
    """The summary's row of a scene's real images (ball_eval.json): learned model and lookup."""
    ball = read_json(root / "ball_eval.json")
    if not ball:
        return []
    learned, lookup = ball.get("model", ball), ball.get("lookup", {})
    folds = ball.get("protocol", {}).get("folds")
    return [
        (
            "real images, cross-validated" if folds else "ball eval (held-out images)",
            f"gradient RMSE {figure(learned.get('gradient_rmse'), 3)}"
            f"{bounds_suffix(learned, 'gradient_rmse', 3)} "
            f"(lookup {figure(lookup.get('gradient_rmse'), 3)}), "
            f"cap depth MAE {figure(learned.get('cap_depth_mae_um'), 0)}"
            f"{bounds_suffix(learned, 'cap_depth_mae_um', 0)} µm "
            f"(lookup {figure(lookup.get('cap_depth_mae_um'), 0)} µm), "
            f"{ball.get('n_test_images')} images" + (f", {folds} grouped folds" if folds else ""),
        )
    ]
