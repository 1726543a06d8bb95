"""What a registration error costs a calibration, measured under control.

A finished `make quick-study` scores both calibrations against the bench's truth, and each unit's
change follows which of the two registered better. This measures the dose: per unit, the full
calibration's presses labelled through the bench's true registration and touch height (as the
quick study's truth scores them), then the same labels moved by a known shift, as a registration
off by that much would place them; a P = 80 model (the scene's own settings) trained on each and
all scored on the true labels of the validation presses. A registration error e (camera px) costs

    MSE(e) = MSE(0) (1 + c e^2)

and `cost_per_px2` fits c per unit; `unit_costs` gives each sensor's mean over units with its
Student's t interval (one training a shift: replicates' spread is not in it). The registration that costs a claim of +-X % alone is
e = sqrt(X / c) in one calibration, the other exact. Where the quick study's units.csv is there,
each unit's quick and full models are also set against the unshifted model (`against_ideal`).

    .venv/bin/python -m diagnostics.registration_cost [--results DIR] [--units digit_u11 ...]
        [--shifts 0.25 0.5] [--replicate N]

A shift moves every label's centre by the same amount (model px = camera px / dataset.downscale),
in x and then in y: what a registration off by a translation does; scale, rotation and lens errors
are not drawn. About 1.5 minutes a training on one core here (5 a unit at the default shifts);
`--smoke`: one simulated unit's 12 presses, tiny trainings.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import pandas as pd
import torch

from diagnostics.quick_presses import over_units, smoke_unit
from threedcal.dataset.trainset import TrainingSet
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings
from threedcal.study.config import compared_with, load_config, scene_config
from threedcal.study.quick_arms import ArmModel, validation_scores
from threedcal.study.quick_study import truth_labelled
from threedcal.study.scene import dataset_settings
from threedcal.study.training import train_settings

SHIFTS_PX = (0.25, 0.5)  # camera px: the quick study's registrations err by 0.09-0.72


def shifted(trainset: TrainingSet, dx_px: float, dy_px: float) -> TrainingSet:
    """The set with every label's centre moved by (dx, dy) model px; frames untouched."""
    samples = trainset.samples.assign(
        center_x_px=trainset.samples["center_x_px"] + float(dx_px),
        center_y_px=trainset.samples["center_y_px"] + float(dy_px),
    )
    return replace(trainset, samples=samples)


def downscale_of(trainset: TrainingSet) -> float:
    """Camera px per model px (the dataset stage's downscale; 1 where the set does not say)."""
    return float((trainset.meta or {}).get("downscale") or 1)


def shift_rows(
    truth: TrainingSet,
    splits: pd.DataFrame,
    settings: TrainSettings,
    shifts_px: Sequence[float],
    work: Path,
    replicate: int = 0,
) -> list[dict]:
    """Per shift (camera px; 0 first, then each along x and along y): the validation MSE, on
    `truth`'s own labels, of a P = 80 model trained on `truth` with its labels shifted."""
    scale = downscale_of(truth)
    moves = [(0.0, 0.0)] + [m for s in shifts_px for m in ((float(s), 0.0), (0.0, float(s)))]
    rows = []
    for dx, dy in moves:
        out = work / f"shift_{dx}_{dy}"
        train(shifted(truth, dx / scale, dy / scale), out, 80, settings, False, replicate)
        models = [ArmModel("shifted", None, 0, math.nan, 0, (str(out / "model.pt"),))]
        mse = float(validation_scores(models, truth, splits)["mse"].mean())
        rows.append({"dx_px": dx, "dy_px": dy, "error_px": math.hypot(dx, dy), "mse": mse})
    base = rows[0]["mse"]
    return [{**row, "change": row["mse"] / base - 1} for row in rows]


def cost_per_px2(rows: pd.DataFrame) -> float:
    """c of MSE(e) = MSE(0) (1 + c e^2), least squares through the origin over the shifted rows
    (change against e^2)."""
    moved = rows[rows["error_px"] > 0]
    e2 = moved["error_px"].to_numpy(float) ** 2
    if e2.size == 0:
        raise ValueError("no shifted rows to fit the cost to")
    return float(e2 @ moved["change"].to_numpy(float) / (e2 @ e2))


def error_for(change: float, cost: float) -> float:
    """The registration error (px) that alone costs `change` (0.1: 10 %) at `cost` per px^2."""
    return math.sqrt(change / cost) if cost > 0 else math.inf


def truth_set(results: Path, scene: dict, full: str) -> tuple[TrainingSet, pd.DataFrame]:
    """The full calibration's presses labelled through the bench's truth, and its splits."""
    splits = pd.read_csv(results / full / "dataset" / "splits.csv")
    truth_path = results / full / "collect" / "bench_truth.json"
    labelled = truth_labelled(
        truth_path, dataset_settings(scene), results / full / "raw.zarr", splits
    )
    if labelled is None:
        raise SystemExit(
            f"{truth_path}: no bench truth with a registration (not a simulated unit?)"
        )
    return labelled, splits


def smoke(work: Path, shifts_px: Sequence[float]) -> list[dict]:
    """The whole path on one simulated unit's 12 presses (6 validate), tiny trainings."""
    truth, splits, settings = smoke_unit()
    return shift_rows(truth, splits, settings, shifts_px, work)


def unit_costs(table: pd.DataFrame) -> pd.DataFrame:
    """Per sensor: each unit's c, their mean and its Student's t interval over units (NaN with
    one unit), and the registration error that alone costs 10 % at the mean."""
    rows = []
    for sensor, part in table.groupby("sensor", sort=False):
        costs = [cost_per_px2(unit) for _, unit in part.groupby("unit", sort=False)]
        mean, low, high = over_units(costs)
        rows.append(
            {
                "sensor": sensor,
                "units": len(costs),
                "unit_costs": costs,
                "cost": mean,
                "cost_lo": low,
                "cost_hi": high,
                "error_for_10pct_px": error_for(0.1, mean),
            }
        )
    return pd.DataFrame(rows)


def summary(table: pd.DataFrame) -> list[str]:
    """Per sensor: c over units with its interval, and the error that alone costs 10 %."""
    return [
        f"{r.sensor}: MSE(e) = MSE(0) (1 + c e^2), e in camera px; c = {r.cost:.2f} "
        f"[{r.cost_lo:.2f}, {r.cost_hi:.2f}] over {r.units} unit(s) (each: "
        f"{', '.join(f'{c:.2f}' for c in r.unit_costs)}); a registration off by "
        f"{r.error_for_10pct_px:.3f} px alone costs 10 %"
        for r in unit_costs(table).itertuples()
    ]


def against_ideal(table: pd.DataFrame, units: pd.DataFrame) -> pd.DataFrame:
    """Per unit of the quick study's units.csv that `table` measured: its quick and full models'
    MSE against the truth over the truth-registered (unshifted) model's, the calibration a perfect
    registration would give."""
    ideal = table[table["error_px"] == 0].set_index("unit")["mse"].rename("ideal_mse")
    rows = units.join(ideal, on="full_scene", how="inner")
    return rows.assign(
        quick_vs_ideal=rows["truth_quick_mse"] / rows["ideal_mse"] - 1,
        full_vs_ideal=rows["truth_full_mse"] / rows["ideal_mse"] - 1,
    )[["full_scene", "ideal_mse", "quick_vs_ideal", "full_vs_ideal"]]


def main(argv: list[str] | None = None) -> pd.DataFrame:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", default="results", type=Path)
    parser.add_argument("--config", default="config/quick_study.yaml")
    parser.add_argument("--units", nargs="*", help="full scenes (default: every compared one)")
    parser.add_argument("--shifts", nargs="*", type=float, default=list(SHIFTS_PX))
    parser.add_argument("--replicate", type=int, default=0)
    parser.add_argument("--smoke", action="store_true", help="one simulated unit, tiny trainings")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as work:
        if args.smoke:
            for row in smoke(Path(work), args.shifts[:1]):
                rows.append({"sensor": "digit_fots", "unit": "smoke", **row})
        else:
            config = load_config(args.config)
            fulls = [compared_with(scene) for scene in config["scenes"].values()]
            fulls = [f for f in fulls if f and (not args.units or f in args.units)]
            for full in fulls:
                scene = scene_config(config, full)
                truth, splits = truth_set(args.results, scene, full)
                unit_work = Path(work) / full
                settings = train_settings(scene)
                for row in shift_rows(
                    truth, splits, settings, args.shifts, unit_work, args.replicate
                ):
                    rows.append({"sensor": scene["sensor"], "unit": full, **row})
                    print(json.dumps(rows[-1]), flush=True)
    table = pd.DataFrame(rows)
    for line in summary(table):
        print(line)
    units_csv = args.results / "quick_study" / "units.csv"
    if not args.smoke and units_csv.is_file():
        print(against_ideal(table, pd.read_csv(units_csv)).to_string(index=False))
    return table


if __name__ == "__main__":
    main()
