"""results/summary.md: every scene's headline numbers on one page, read from the stage outputs."""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from threedcal.evaluate.ablation_reading import curve_summary
from threedcal.report.stage_times import stage_time_lines, stage_times
from threedcal.study.config import is_imported
from threedcal.study.paths import has_sim2real


def read_json(path: Path) -> dict | None:
    """A results JSON file, or None where the study has not written it."""
    return json.loads(path.read_text()) if path.is_file() else None


def _fmt(value, digits: int = 2) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _interval(figures: Mapping, key: str, digits: int) -> str:
    """' [lo, hi]' of a cross-validated figure's 95 % interval, or nothing."""
    bounds = figures.get("interval95", {}).get(key)
    return f" [{bounds[0]:.{digits}f}, {bounds[1]:.{digits}f}]" if bounds else ""


def scene_section(name: str, scene: Mapping, results: Path) -> list[str]:
    root = results / name
    lines = [f"## {name}", "", f"{scene.get('description', '')}".strip(), ""]
    facts: list[tuple[str, str]] = [("sensor", str(scene["sensor"]))]
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
                f"{summary['duration_s']:.1f} s, {_fmt(summary['frames_per_s'], 1)} frames/s",
            ),
        ]
    registration = read_json(root / "dataset" / "registration.json")
    if registration:
        error = registration.get("error_px")
        facts.append(
            (
                "registration residual / error vs hidden truth",
                f"{registration['residual_px']:.3f} px / {_fmt(error, 3)} px",
            )
        )
        facts.append(
            ("first-touch offset (estimated)", f"{registration['touch_offset_mm']:+.3f} mm")
        )
    quick = read_json(root / "quick" / "stop.json")
    if quick:
        facts.append(
            (
                "quick calibration",
                f"stopped ({quick['stopped']}) after {quick['presses']} presses in "
                f"{quick['round']} rounds ({quick.get('presses_in_all', quick['presses'])} with the "
                f"touch search and registration), {quick['printer_minutes']:.1f} printer minutes",
            )
        )
    arms = read_json(root / "quick" / "arms.json")
    if arms:
        facts.append(
            (
                f"quick against {arms['compare_with']}'s P = 80 (quick/arms.json)",
                "; ".join(target["line"] for target in arms["targets"].values()),
            )
        )
    facts += recommendation_facts(root / "stats")
    fps = read_json(root / "models" / "inference.json")
    if fps:
        facts.append(("depth inference (P=80 model, CPU)", f"{fps['frames_per_s']:.1f} frames/s"))
    ball = read_json(root / "ball_eval.json")
    if ball:
        learned, lookup = ball.get("model", ball), ball.get("lookup", {})
        folds = ball.get("protocol", {}).get("folds")
        facts.append(
            (
                "real images, cross-validated" if folds else "ball eval (held-out images)",
                f"gradient RMSE {_fmt(learned.get('gradient_rmse'), 3)}{_interval(learned, 'gradient_rmse', 3)} "
                f"(lookup {_fmt(lookup.get('gradient_rmse'), 3)}), "
                f"cap depth MAE {_fmt(learned.get('cap_depth_mae_um'), 0)}{_interval(learned, 'cap_depth_mae_um', 0)} µm "
                f"(lookup {_fmt(lookup.get('cap_depth_mae_um'), 0)} µm), "
                f"{ball.get('n_test_images')} images"
                + (f", {folds} grouped folds" if folds else ""),
            )
        )
    reskin = read_json(root / "reskin_eval.json")
    if reskin:
        facts.append(
            (
                "ReSkin localisation (held-out)",
                f"median {reskin['median_error_mm']:.2f} mm, p90 {reskin['p90_error_mm']:.2f} mm, "
                f"depth MAE {reskin['depth_mae_mm']:.3f} mm",
            )
        )
    lines += ["| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in facts] + [""]
    sim2real = root / "sim2real" / "errors.csv"
    if has_sim2real(scene) and sim2real.is_file():
        lines += sim2real_section(pd.read_csv(sim2real, dtype={"k": str, "fold": str}))
    lines += ablation_section(root / "stats")
    errors = root / "objects" / "errors.csv"
    if errors.is_file():
        lines += object_table(pd.read_csv(errors))
    return lines


def recommendation_facts(stats_dir: Path) -> list[tuple[str, str]]:
    """The recommendation's rows: the TOST's answer, the learning curve's (with its interval) and
    where the two differ, why (stats/recommendation.txt, one reading a line)."""
    path = stats_dir / "recommendation.txt"
    if not path.is_file():
        return []
    lines = path.read_text().strip().splitlines()
    facts = [("recommendation (equivalence test)", lines[0])]
    curve = stats_dir / "learning_curve.csv"
    if curve.is_file():
        facts.append(
            ("learning curve (stats/learning_curve.csv)", curve_summary(pd.read_csv(curve)))
        )
    compared = [line for line in lines[1:] if "readings" in line.split(":", 1)[0]]
    facts += [("equivalence test against the curve", line) for line in compared]
    return facts


def sim2real_section(errors: pd.DataFrame) -> list[str]:
    """Error against k real training images: sim-pretrained, real-only, the scene's own model."""
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


def ablation_section(stats_dir: Path) -> list[str]:
    """The ablation's three test families side by side, disagreements spelled out, and the design
    the power simulation says each P needs (docs/explanation/statistics.md)."""
    tests_path = stats_dir / "tests.csv"
    if not tests_path.is_file():
        return []
    from threedcal.evaluate.ablation_reading import family_comparison, placebo_summary
    from threedcal.evaluate.power import needed_design

    tests = pd.read_csv(tests_path)
    if not {"paper", "paired", "equivalence"} <= set(tests["family"]):
        return []
    comparison = family_comparison(tests)
    power = pd.read_csv(stats_dir / "power.csv") if (stats_dir / "power.csv").is_file() else None
    lines = [
        "Each P against P = 80 % (tests.csv): the paper's tests (replicates significant, t / U), "
        "the paired spatial-block test and the equivalence test (TOST):",
        "",
        "| P | change of mean MSE | paper t / U | paired | equivalence | families | "
        "80 % power to show equivalence |",
        "|---:|---:|---|---|---|---|---|",
    ]
    for row in comparison.itertuples():
        design = needed_design(power, row.P) if power is not None else "—"
        lines.append(
            f"| {row.P} | {row.change} | {row.paper_t} / {row.paper_u} | {row.paired} | "
            f"{row.equivalence} | {row.agreement} | {design} |"
        )
    placebo = placebo_summary(tests)
    if placebo:
        lines += ["", f"Placebo (`family = placebo`): {placebo}."]
    lines += convergence_lines(stats_dir / "convergence.csv")
    return lines + [""]


def convergence_lines(path: Path) -> list[str]:
    """The convergence check in one sentence per P (stats/convergence.csv), and the ablation read
    again at twice the budget (stats/twice/recommendation.txt)."""
    if not path.is_file():
        return []
    table = pd.read_csv(path)
    parts = [
        f"P = {row.P} % {row.budget_mse:.5f} after {row.steps} steps, {row.twice_mse:.5f} after "
        f"{row.twice_steps} ({row.change:+.1%}, {row.ci_low:+.1%} to {row.ci_high:+.1%})"
        for row in table.itertuples()
    ]
    lines = [
        "",
        "Convergence (every model trained on to twice the budget, mean validation MSE; "
        f"stats/convergence.csv): {'; '.join(parts)}.",
    ]
    twice = reading_line(path.parent / "twice")
    if twice:
        lines += ["", f"At twice the budget: {twice}"]
    return lines


def reading_line(folder: Path) -> str | None:
    """A reading's recommendation.txt in one line: the equivalence test's answer, then the
    learning curve's (learning_curve.csv beside it) and whether the two differ; None without it."""
    path = folder / "recommendation.txt"
    if not path.is_file():
        return None
    lines = path.read_text().strip().splitlines()
    text = lines[0]
    curve = folder / "learning_curve.csv"
    if curve.is_file():
        text += f"; learning curve: {curve_summary(pd.read_csv(curve))}"
        if any(line.startswith("the readings differ") for line in lines[1:]):
            text += " (the two differ: why in recommendation.txt)"
    return text


def _ci(row, metric: str) -> str:
    lo, hi = getattr(row, f"{metric}_lo"), getattr(row, f"{metric}_hi")
    if pd.isna(lo) or pd.isna(hi):
        return f"{getattr(row, metric):.0f}"
    return f"{getattr(row, metric):.0f} [{lo:.0f}, {hi:.0f}]"


def object_table(table: pd.DataFrame) -> list[str]:
    """objects/errors.csv as markdown: the printer protocol first, then the paper's."""
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


def write_summary(config: Mapping, results: str | Path, out: str | Path) -> str:
    results = Path(results)
    lines = ["# threedcal study summary", ""]
    scenes = config["scenes"]
    # Real frames first: what a user's sensor will meet outranks what the simulator trains and tests.
    real = [name for name, scene in scenes.items() if is_imported(scene)]
    if real:
        lines += [
            f"Scenes on real sensor frames first ({', '.join(real)}); every other scene is "
            "trained and tested in the simulator.",
            "",
        ]
    for name in real + [name for name in scenes if name not in real]:
        lines += scene_section(name, scenes[name], results)
    reading = results / "integration" / "reading.md"
    if reading.is_file():
        lines += ["## Depth integrators", "", reading.read_text().strip(), ""]
    lines += [
        "## Where the time goes",
        "",
        "Each stage's jobs summed from their `benchmark:` files (the jobs that had run when this "
        "page was written; jobs run side by side, so the summed wall time is work, not duration):",
        "",
        *stage_time_lines(stage_times(results)),
        "",
    ]
    environment = read_json(results / "environment.json")
    if environment:
        lines += ["## Run environment", "", "| | |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in environment.items() if not isinstance(v, dict)]
        lines += [f"| {k} | {v} |" for k, v in environment.get("software", {}).items()]
        lines.append("")
    text = "\n".join(lines)
    Path(out).write_text(text)
    return text


def environment(config: Mapping) -> dict[str, Any]:
    """Versions, threads, seeds and hardware of this run (for the report and summary)."""
    import torch

    from threedcal.model.machine import cpu_capability, cpu_flags, isa_limits, native_bfloat16
    from threedcal.study.paths import package_versions

    cpu, flags = cpu_flags()
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu": cpu,
        "cpu_flags": " ".join(flags),
        "isa_limits": ", ".join(f"{k}={v}" for k, v in isa_limits().items()) or "none",
        "torch_cpu_capability": cpu_capability(),
        "native_bfloat16": native_bfloat16(),
        "cpu_count": os.cpu_count(),
        "cuda": torch.cuda.is_available(),
        "seed": config.get("seed"),
        "torch_threads": config.get("torch_threads"),
        # what this job's BLAS/OpenMP pools were given: Snakemake sets them to the job's threads
        "thread_environment": {
            name: os.environ.get(name)
            for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
        },
        "scene_seeds": {name: s["seed"] for name, s in config["scenes"].items()},
        "software": package_versions(),
    }


def measure_inference(
    model_path: str | Path, trainset_dir: str | Path, out: str | Path, frames: int = 30
) -> dict:
    """Depth frames/s of a checkpoint on real frames of its dataset (the figure the summary quotes)."""
    import time

    import numpy as np

    from threedcal.dataset.trainset import TrainingSet
    from threedcal.model.inference import DepthEstimator

    estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
    trainset = TrainingSet.load(trainset_dir)
    picks = np.linspace(0, len(trainset.frames) - 1, frames).round().astype(int)
    batch = np.asarray(trainset.frames[picks])
    estimator.depth(batch[0])  # warm-up
    start = time.perf_counter()
    for frame in batch:
        estimator.depth(frame)
    seconds = (time.perf_counter() - start) / len(batch)
    import torch

    record = {
        "preset": estimator.preset,
        "frames_per_s": round(1.0 / seconds, 2),
        "ms_per_frame": round(seconds * 1000, 2),
        "image_shape": list(estimator.image_shape),
        "torch_threads": torch.get_num_threads(),
    }
    Path(out).write_text(json.dumps(record, indent=2) + "\n")
    return record
