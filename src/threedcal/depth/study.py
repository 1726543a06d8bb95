"""Error against run time: every integrator x grid size x scenario x dtype, timed and scored.

Each cell solves the scenario's gradients `repeats` times (fewer when one solve exceeds the time
budget; always at least once), keeps the median wall time per frame, and scores the last depth map
against the analytic truth in mm: rmse and peak (max absolute) error over all pixels.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.depth import METHODS, integrate
from threedcal.depth.scenarios import SCENARIOS, make_scene
from threedcal.errors import ConfigError
from threedcal.plotting import pyplot

COLUMNS = ["method", "scenario", "H", "W", "dtype", "ms_per_frame", "rmse", "peak_error", "repeats"]


def run_study(
    sizes: Sequence[Sequence[int]],
    scenarios: Sequence[str],
    methods: Sequence[str],
    dtypes: Sequence[str] = ("float32", "float64"),
    repeats: int = 5,
    time_budget_s: float = 2.0,
    seed: int = 0,
    workers: int | None = None,
    method_max_pixels: Mapping[str, int] | None = None,
) -> pd.DataFrame:
    """Time and score every cell; a method in `method_max_pixels` skips grids larger than its limit
    (the sparse solver costs seconds per frame at 960 × 1280 and adds nothing to the reading there)."""
    limits = dict(method_max_pixels or {})
    for name in methods:
        if name not in METHODS:
            raise ConfigError(
                f"integration study: method {name!r} is not allowed (allowed: {', '.join(METHODS)})"
            )
    for name in scenarios:
        if name not in SCENARIOS:
            raise ConfigError(
                f"integration study: scenario {name!r} is not allowed (allowed: {', '.join(SCENARIOS)})"
            )
    cells = [
        (hw, s, d, m)
        for hw in sizes
        for s in scenarios
        for d in dtypes
        for m in methods
        if hw[0] * hw[1] <= limits.get(m, float("inf"))
    ]
    rows = []
    scene_cache: dict = {}
    for (h, w), scenario, dtype, method in tqdm(cells, desc="integration study", unit="cell"):
        key = (h, w, scenario)
        if key not in scene_cache:
            scene_cache.clear()
            scene_cache[key] = make_scene(scenario, h, w, seed)
        scene = scene_cache[key]
        gx = scene.gx.astype(dtype)
        gy = scene.gy.astype(dtype)
        times = []
        spent = 0.0
        while len(times) < max(1, repeats) and (not times or spent + times[-1] <= time_budget_s):
            start = time.perf_counter()
            depth = integrate(gx, gy, method, px_per_mm=scene.px_per_mm, workers=workers)
            times.append(time.perf_counter() - start)
            spent += times[-1]
        err = depth.astype(np.float64) - scene.depth_mm
        rows.append(
            {
                "method": method,
                "scenario": scenario,
                "H": h,
                "W": w,
                "dtype": dtype,
                "ms_per_frame": 1e3 * float(np.median(times)),
                "rmse": float(np.sqrt(np.mean(err**2))),
                "peak_error": float(np.max(np.abs(err))),
                "repeats": len(times),
            }
        )
    return pd.DataFrame(rows, columns=COLUMNS)


def pareto_front(points: pd.DataFrame, x: str = "ms_per_frame", y: str = "rmse") -> pd.DataFrame:
    """Rows no other row beats on both time and error (ties kept)."""
    ordered = points.sort_values([x, y])
    keep, best = [], np.inf
    for index, row in ordered.iterrows():
        if row[y] < best:
            keep.append(index)
            best = row[y]
    return ordered.loc[keep]


def plot_pareto(table: pd.DataFrame, path: str | Path) -> None:
    """One log-log panel per scenario: median ms per frame against rmse, front drawn."""
    plt = pyplot()

    scenarios = list(dict.fromkeys(table["scenario"]))
    methods = list(dict.fromkeys(table["method"]))
    colours = dict(zip(methods, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    ncols = min(4, len(scenarios))
    nrows = -(-len(scenarios) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4 * ncols, 3.4 * nrows), squeeze=False)
    sizes = sorted(
        {(h, w) for h, w in zip(table["H"], table["W"], strict=True)}, key=lambda s: s[0] * s[1]
    )
    marker_size = {hw: 20 + 40 * i for i, hw in enumerate(sizes)}
    for ax, scenario in zip(axes.flat, scenarios, strict=False):
        part = table[table["scenario"] == scenario]
        for _, row in part.iterrows():
            filled = row["dtype"] == "float32"
            ax.scatter(
                row["ms_per_frame"],
                max(row["rmse"], 1e-16),
                s=marker_size[(row["H"], row["W"])],
                facecolors=colours[row["method"]] if filled else "none",
                edgecolors=colours[row["method"]],
            )
        front = pareto_front(part)
        ax.plot(front["ms_per_frame"], front["rmse"].clip(lower=1e-16), "k--", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scenario, fontsize=9)
        ax.set_xlabel("median ms per frame")
        ax.set_ylabel("rmse (mm)")
    for ax in list(axes.flat)[len(scenarios) :]:
        ax.axis("off")
    handles = [plt.Line2D([], [], marker="o", ls="", color=colours[m], label=m) for m in methods]
    size_note = ", ".join(f"{h}x{w}" for h, w in sizes)
    fig.legend(
        handles=handles,
        loc="lower center",
        ncol=len(methods),
        fontsize=8,
        title=f"filled float32, open float64; larger marker = larger grid ({size_note})",
    )
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def reading(table: pd.DataFrame) -> str:
    """A short data-driven reading: per scenario the most accurate method, and the fastest one
    within 2x of the best error (float32 at the largest grid when present)."""
    largest = table.loc[(table["H"] * table["W"]).idxmax(), ["H", "W"]]
    lines = [
        "# Depth integration: error against run time",
        "",
        f"Grid {int(largest['H'])}x{int(largest['W'])}; rmse and peak error in mm against the analytic truth.",
        "",
        "| scenario | most accurate (rmse mm) | fastest within 2x of it (ms/frame) |",
        "|---|---|---|",
    ]
    sub = table[(table["H"] == largest["H"]) & (table["W"] == largest["W"])]
    if "float32" in set(sub["dtype"]):
        sub = sub[sub["dtype"] == "float32"]
    votes: dict[str, int] = {}
    for scenario, part in sub.groupby("scenario", sort=False):
        best = part.loc[part["rmse"].idxmin()]
        good = part[part["rmse"] <= 2 * best["rmse"] + 1e-12]
        fast = good.loc[good["ms_per_frame"].idxmin()]
        votes[fast["method"]] = votes.get(fast["method"], 0) + 1
        lines.append(
            f"| {scenario} | {best['method']} ({best['rmse']:.3g}) | {fast['method']} ({fast['ms_per_frame']:.3g} ms, rmse {fast['rmse']:.3g}) |"
        )
    lines += [
        "",
        "Which method when (read from the table above):",
        "- "
        + "; ".join(
            f"{m}: the pick in {n} scenario(s)"
            for m, n in sorted(votes.items(), key=lambda kv: -kv[1])
        )
        + ".",
        "- Median ms per frame by method: "
        + ", ".join(
            f"{m} {v:.3g}"
            for m, v in sub.groupby("method")["ms_per_frame"].median().sort_values().items()
        )
        + ".",
        "- Contact inside the frame: poisson_dst and poisson_dct share the edge model and agree in error; take the faster.",
        "- Contact reaching the border: use poisson_dct (no assumption at the border) or lstsq_sparse.",
        "- Invalid pixels or per-pixel confidence: lstsq_sparse (masked, weighted), at a much higher cost.",
        "- py3dcal (the authors' solver) is listed to show its error, not for use.",
        "",
    ]
    return "\n".join(lines)


def write_study(table: pd.DataFrame, csv_path, png_path, reading_path) -> None:
    Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(csv_path, index=False, float_format="%.6g")
    plot_pareto(table, png_path)
    Path(reading_path).write_text(reading(table))
