"""Sim-to-real: error against k real training images with and without simulated pretraining
(sim2real/errors.csv), for the page and for each scene of the summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.report.sections.markdown import MISSING, SIM_COLUMN, markdown_table, missing_file

# Sim-to-real conditions, in the table's column order, with whether the simulator made their
# training and test frames.
SIM2REAL_CONDITIONS = {
    "sim+real": "pretraining",
    "real-only": "no",
    "scene model": "no",
}
# Shown only where a scene ran it (sim_to_real.shipped).
SHIPPED_CONDITION = "shipped+real"


def sim2real_rows(pooled: pd.DataFrame) -> list[tuple[str, str, str, str]]:
    """(k, condition, gradient RMSE [95 %], cap depth MAE µm [95 %]) of errors.csv's pooled rows."""
    rows = []
    for row in pooled.itertuples(index=False):
        k = row.k if row.k != "all" else f"all ({row.n_train:.0f})"
        rows.append(
            (
                k,
                row.condition,
                f"{row.gradient_rmse:.3f} [{row.gradient_rmse_lo:.3f}, {row.gradient_rmse_hi:.3f}]",
                f"{row.cap_depth_mae_um:.0f} [{row.cap_depth_mae_um_lo:.0f}, "
                f"{row.cap_depth_mae_um_hi:.0f}]",
            )
        )
    return rows


def sim2real_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """One row per scene and k, one column per condition: gradient RMSE; cap depth MAE."""
    if not scenes:
        return []
    conditions = dict(SIM2REAL_CONDITIONS)
    rows = []
    for name in scenes:
        path = results / name / "sim2real" / "errors.csv"
        if not path.is_file():
            rows.append({"scene": f"`{name}`", "protocol": MISSING, "k": MISSING})
            rows[-1][next(iter(conditions))] = missing_file(path, results)
            continue
        errors = pd.read_csv(path, dtype={"k": str, "fold": str})
        folds = sorted(set(errors["fold"]) - {"all"}, key=int)
        protocol = f"held-out folds {', '.join(folds)}"
        by_k: dict[str, dict] = {}
        for k, condition, rmse, mae in sim2real_rows(errors[errors["fold"] == "all"]):
            conditions.setdefault(
                condition, "pretraining" if condition == SHIPPED_CONDITION else MISSING
            )
            row = by_k.setdefault(k, {"scene": f"`{name}`", "protocol": protocol, "k": k})
            row[condition] = f"{rmse}; {mae}"
        rows += by_k.values()
    # the simulator made no test frame here: only some conditions' pretraining frames
    simulated = "only to pretrain " + ", ".join(
        f"`{c}`" for c in conditions if conditions[c] == "pretraining"
    )
    unknown = [f"`{c}`" for c in conditions if conditions[c] == MISSING]
    simulated += f"; {MISSING} for {', '.join(unknown)}" if unknown else ""
    header = ["scene", "protocol", "k", *conditions]
    return [
        "### Sim-to-real: k real images, with and without simulated pretraining",
        "",
        "Protocol: `sim+real`: simulated presses, then k real; `real-only`: k alone; "
        + (
            f"`{SHIPPED_CONDITION}`: shipped weights, then k at their frame size; "
            if SHIPPED_CONDITION in conditions
            else ""
        )
        + "`scene model`: cross-validated"
        + f". *{SIM_COLUMN}*: {simulated}. Cells: gradient RMSE; cap depth MAE µm.",
        "",
        *markdown_table(header, [[row.get(column, MISSING) for column in header] for row in rows]),
        "",
    ]


def sim2real_lines(errors: pd.DataFrame) -> list[str]:
    """One scene's error against k real training images: sim-pretrained, real-only, the scene's
    own model."""
    pooled = errors[errors["fold"] == "all"]
    folds = sorted(set(errors["fold"]) - {"all"}, key=int)
    lines = [
        f"Sim-to-real (held-out real images of folds {', '.join(folds)}; 95 % intervals over "
        "press groups; sim2real/error_vs_k.png):",
        "",
        "| k real images | condition | gradient RMSE | cap depth MAE µm |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {k} | {condition} | {rmse} | {mae} |"
        for k, condition, rmse, mae in sim2real_rows(pooled)
    ]
    return lines + [""]
