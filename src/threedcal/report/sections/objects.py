"""Test objects: Type 2 MAE per object (objects/errors.csv), for the page and for each scene of the
summary."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    estimate,
    markdown_table,
    missing_file,
)
from threedcal.report.sections.records import recorded_config, simulated_cell
from threedcal.study.config import training_fractions
from threedcal.study.paths import has_objects

# The fraction whose test-object figures lead the page (the paper's Table II reports P = 20 %).
REPORTED_P = 20


def _objects_of(scenes: Mapping[str, dict]) -> list[str]:
    names: dict[str, None] = {}
    for record in scenes.values():
        if has_objects(recorded_config(record)):
            names.update(dict.fromkeys(str(o) for o in recorded_config(record)["objects"]))
    return list(names)


def objects_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Type 2 MAE per object at P = 20 %, both protocols; then the printer protocol over every P."""
    chosen = {name: r for name, r in scenes.items() if has_objects(recorded_config(r))}
    if not chosen:
        return []
    objects = _objects_of(chosen)
    fractions = sorted({p for r in chosen.values() for p in training_fractions(recorded_config(r))})
    reported = REPORTED_P if REPORTED_P in fractions else max(fractions)
    head_rows, by_p_rows, designs = [], [], {}
    for name, record in chosen.items():
        path = results / name / "objects" / "errors.csv"
        sim = simulated_cell(record)
        if not path.is_file():
            head_rows.append(
                [f"`{name}`", sim, MISSING, missing_file(path, results)]
                + [MISSING] * (len(objects) - 1)
            )
            continue
        table = pd.read_csv(path)
        replicates = int(table["replicates"].min()) if "replicates" in table else 1
        design = (
            f"{int(table['presses'].min())} presses per object and {replicates} "
            f"model{'s' if replicates != 1 else ''} per P"
        )
        designs.setdefault(design, []).append(f"`{name}`")
        for protocol in dict.fromkeys(table["protocol"]):
            rows = table[table["protocol"] == protocol]
            at = {r.object: r for r in rows[rows["P"] == reported].itertuples()}
            head_rows.append(
                [f"`{name}`", sim, f"**{protocol}**" if protocol == "printer" else protocol]
                + [
                    estimate(at[o].type2_um, at[o].type2_um_lo, at[o].type2_um_hi)
                    if o in at
                    else MISSING
                    for o in objects
                ]
            )
            if protocol != "printer":
                continue
            for obj in objects:
                part = rows[rows["object"] == obj].set_index("P")["type2_um"]
                ends = (
                    [f"{part[p]:.0f} ({p})" for p in (part.idxmin(), part.idxmax())]
                    if len(part)
                    else [MISSING, MISSING]
                )
                by_p_rows.append([f"`{name}`", sim, protocol, obj, *ends])
    design = "; ".join(f"{d} ({', '.join(names)})" for d, names in designs.items())
    return [
        f"## Test objects: Type 2 MAE (µm), P = {reported} %",
        "",
        f"Protocol: objects pressed by the printer; the P = {reported} % models' depth against "
        "the CAD truth where it touches ([objects](explanation/objects.md)); `printer`: truth "
        "placed where the printer put it, `paper`: aligned by cross-correlation, depth fitted. "
        "Mean over presses and models, both random" + (f": {design}" if design else "") + ".",
        "",
        *markdown_table(["scene", SIM_COLUMN, "protocol", *objects], head_rows),
        "",
        f"Over P = {', '.join(map(str, fractions))} %, the lowest and highest mean (all: "
        "`objects/errors.csv`):",
        "",
        *markdown_table(
            ["scene", SIM_COLUMN, "protocol", "object", "lowest (P %)", "highest (P %)"], by_p_rows
        ),
        "",
    ]


def _ci(row, metric: str) -> str:
    lo, hi = getattr(row, f"{metric}_lo"), getattr(row, f"{metric}_hi")
    if pd.isna(lo) or pd.isna(hi):
        return f"{getattr(row, metric):.0f}"
    return f"{getattr(row, metric):.0f} [{lo:.0f}, {hi:.0f}]"


def object_lines(table: pd.DataFrame) -> list[str]:
    """A scene's objects/errors.csv as markdown: the printer protocol first, then the paper's."""
    full = int(table["P"].max())
    presses = int(table["presses"].min())
    replicates = int(table["replicates"].min()) if "replicates" in table else 1
    spread = (
        f"mean over the presses and the {replicates} replicate models of each P [95 % interval, "
        "presses and models both random]"
        if replicates > 1
        else "mean [95 % t interval over presses]"
    )
    lines = [
        f"Test objects, reporting presses ({presses} or more per object): MAE in µm, {spread}. "
        "`printer`: the ground truth where the printer put the "
        "object (registration, commanded Z), nothing fitted; `paper`: the paper's protocol "
        "(aligned by cross-correlation, depth fitted to the prediction).",
        "",
        f"| protocol | object | overall, P = {full} % | Type 1, P = {full} % "
        f"| Type 2, P = {full} % | Type 2, P = 20 % | depth / true, P = {full} % |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for protocol in dict.fromkeys(table["protocol"]):
        rows = table[table["protocol"] == protocol]
        at20 = {r.object: r for r in rows[rows["P"] == 20].itertuples()}
        for r in rows[rows["P"] == full].itertuples():
            p20 = _ci(at20[r.object], "type2_um") if r.object in at20 else "—"
            lines.append(
                f"| {protocol} | {r.object} | {_ci(r, 'overall_um')} | {_ci(r, 'type1_um')} "
                f"| {_ci(r, 'type2_um')} | {p20} | {r.depth_ratio:.3f} |"
            )
    return lines + [""]
