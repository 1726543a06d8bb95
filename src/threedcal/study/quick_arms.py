"""A quick calibration measured against its unit's full one: its arms, one yardstick.

A quick scene with `quick.compare_with: S` was calibrated on the same unit (sensor, bench unit,
seating, seed) as the collected scene S. Its arms of models are scored alike:

quick    the quick flow's model after each round, results/{scene}/quick/rounds/r{k}/model.pt
         (r0: the starting weights, `model.init`'s, before any press);
stopped  the model where its stop rule stopped;
scratch  for each round k ≥ 1, a model trained from fresh weights (the scene's preset, no init) on
         the same presses as round k, with the quick model's cumulative step budget by then (the
         steps its rounds' checkpoints record), in one cosine cycle at the scene's rate and seed;
full     S's P = 80 models, every replicate: the calibration at the paper's scale.

Every model is scored on (i) S's validation coordinates with the stats stage's per-coordinate
gradient MSE (threedcal.evaluate.validation.coordinate_mse), and (ii) S's test-object reporting
presses under the printer protocol, Type 2 MAE per object (threedcal.evaluate.object_scores).
Intervals are 95 %. (i) pairs the arms on S's spatial blocks (threedcal.evaluate.ablation:
blocks one scoring disc across; the two-way replicate + block model, Satterthwaite's degrees of
freedom): an arm's mean MSE over blocks, and its relative change against `full` with Fieller's
interval. (ii) pairs them on the presses: an arm's mean Type 2 MAE, and its difference from
`full`'s, each with the crossed (replicate x press) interval of object_errors.crossed_mean_interval.
The quick run and `full`'s replicates are independent trainings, paired only on blocks or presses
(threedcal.evaluate.ablation.independent_contrast); the quick run's own training randomness is in
no interval (make quick-study measures over units: threedcal.study.quick_study).

The issue's targets are judged on the `stopped` model: its validation MSE within 10 % of `full`'s, its Type 2 MAE within 10 µm of `full`'s on every
object (both one-sided: better is within), at most 50 presses, at most 5 printer minutes (the
motion model's estimate, registration and first-touch search included). A target judged on an
interval is `met` when the whole interval lies within it, `not met` when the whole interval lies
past it, else `undecided`.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.special import stdtrit

from threedcal.dataset.build import collected_so_far
from threedcal.dataset.splits import subset_size
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import (
    contrast,
    independent_contrast,
    ratio_interval,
    spatial_blocks,
)
from threedcal.evaluate.object_errors import crossed_mean_interval
from threedcal.evaluate.object_scores import evaluate_objects
from threedcal.evaluate.validation import coordinate_mse, scoring_disc_mm
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import train
from threedcal.plotting import pyplot
from threedcal.study.pressing import objects_setup
from threedcal.study.quick_loop import QuickLoop
from threedcal.study.session import prepare

LEVEL = 0.95
# The quick flow's targets against the same unit's full calibration.
MSE_WITHIN = 0.10  # relative change of the mean validation MSE
TYPE2_WITHIN_UM = 10.0  # Type 2 MAE, every object, printer protocol
MAX_PRESSES = 50
MAX_PRINTER_MINUTES = 5.0

ARMS = ("quick", "stopped", "scratch", "full")
COLUMNS = (
    "arm",
    "round",
    "presses",
    "printer_min",
    "steps",
    "replicates",
    "metric",
    "object",
    "value",
    "value_lo",
    "value_hi",
    "change",
    "change_lo",
    "change_hi",
)


@dataclass(frozen=True)
class ArmModel:
    """One point of an arm: its models (one, or one per replicate) and what they cost."""

    arm: str
    round: int | None  # None for `full`
    presses: int
    printer_min: float
    steps: int
    paths: tuple[str, ...]

    @property
    def key(self) -> tuple[str, int]:
        return (self.arm, -1 if self.round is None else self.round)


# ---- the models of each arm -----------------------------------------------------------------


def _checkpoint_steps(path: str | Path) -> int:
    return int(read_checkpoint(path)["training"].get("steps") or 0)


def run_arm(rounds: pd.DataFrame, rounds_dir: str | Path, start_min: float) -> list[ArmModel]:
    """One run's models r0..rK (rounds.csv's rounds), with the presses, printer minutes and
    cumulative training steps each had. `start_min`: the printer's minutes before the first round
    (registration and first-touch search), the cost of r0."""
    rounds_dir = Path(rounds_dir)
    out = [ArmModel("quick", 0, 0, start_min, 0, (str(rounds_dir / "r0" / "model.pt"),))]
    steps = 0
    for row in rounds.itertuples(index=False):
        path = rounds_dir / f"r{int(row.round)}" / "model.pt"
        if not path.is_file():
            raise ConfigError(f"{path}: round {int(row.round)} of rounds.csv has no model")
        steps += _checkpoint_steps(path)
        out.append(
            ArmModel(
                "quick", int(row.round), int(row.presses), row.printer_s / 60, steps, (str(path),)
            )
        )
    return out


def stopped_arm(points: Sequence[ArmModel]) -> ArmModel:
    """The run's model where its stop rule stopped (what a user keeps): the point the targets
    are judged on."""
    return replace(points[-1], arm="stopped", round=None)


def scratch_arm(
    loop,
    quick: Sequence[ArmModel],
    out_dir: str | Path,
    progress: bool = False,
) -> list[ArmModel]:
    """For every quick round k ≥ 1: fresh weights trained on round k's presses with its cumulative
    step budget, into out_dir/r{k}/. `loop`: a threedcal.study.quick_loop.QuickLoop over the quick
    scene's finished store (its rounds' plan rows and training settings)."""
    out_dir = Path(out_dir)
    base = loop.train_settings
    models, registered = [], None
    for point in quick:
        if point.round == 0:
            continue
        rows = loop.ends[point.round - 1]
        trainset, _, registered = collected_so_far(
            loop.dataset_settings, loop.store_path, rows, prior=registered
        )
        budget = max(1, point.steps)
        settings = replace(
            base,
            init=None,
            stopping={**base.stopping, "first_cycle": budget, "max_steps": budget},
        )
        target = out_dir / f"r{point.round}"
        train(trainset, target, 80, settings, progress=progress)
        models.append(replace(point, arm="scratch", paths=(str(target / "model.pt"),)))
        logging.getLogger("threedcal").info(
            "scratch r%d: %d presses, %d steps", point.round, point.presses, budget
        )
    return models


def full_arm(paths: Sequence[str | Path], n_points: int, hardware_s: float | None) -> ArmModel:
    """The compared scene's P = 80 models: the presses they trained on (80 % of its probe
    coordinates) and the printer's time for those presses (the stats stage's cost convention)."""
    points = subset_size(n_points, 80)
    minutes = math.nan if hardware_s is None else hardware_s * points / n_points / 60
    steps = int(np.mean([_checkpoint_steps(p) for p in paths]))
    return ArmModel("full", None, points, minutes, steps, tuple(str(p) for p in paths))


# ---- scores ---------------------------------------------------------------------------------


def validation_scores(models: Sequence[ArmModel], trainset, splits: pd.DataFrame) -> pd.DataFrame:
    """arm, round, replicate, point, x_mm, y_mm, mse: every model on the validation coordinates.

    Each model compares the frames with the validation set's blank, not the one it carries: the
    frames were rectified with the compared scene's lens, and a blank rectified with another fit
    (the quick flow's own) leaves a shifted shading in every difference, an error no rig makes
    (there, frames and blank pass through one lens; the object presses are scored likewise)."""
    coords = splits.set_index("point")[["x_mm", "y_mm"]]
    tables, scored = [], {}  # a run's stopped model is also its round's: scored once
    for model in models:
        for replicate, path in enumerate(model.paths):
            if path in scored:
                tables.append(
                    scored[path].assign(arm=model.arm, round=model.key[1], replicate=replicate)
                )
                continue
            checkpoint = read_checkpoint(path)
            shape = tuple(checkpoint.get("image_shape") or np.shape(checkpoint["blank"])[:2])
            if shape != tuple(trainset.image_shape):
                raise ConfigError(
                    f"{path}: works on {shape} px frames, the compared scene's validation frames "
                    f"are {tuple(trainset.image_shape)} (dataset.downscale must agree)"
                )
            estimator = DepthEstimator(checkpoint, device="cpu", blank=trainset.blank)
            scored[path] = coordinate_mse(estimator, trainset).join(coords, on="point")
            tables.append(
                scored[path].assign(arm=model.arm, round=model.key[1], replicate=replicate)
            )
    return pd.concat(tables, ignore_index=True)


def block_matrix(scores: pd.DataFrame, blocks: pd.Series) -> np.ndarray:
    """(replicates, blocks): each replicate's mean MSE over the coordinates of each block."""
    wide = scores.pivot(index="replicate", columns="point", values="mse").sort_index(axis=1)
    if not np.isfinite(wide.to_numpy()).all():
        raise ConfigError("non-finite validation errors cannot be paired")
    return wide.T.groupby(blocks[wide.columns].to_numpy()).mean().T.to_numpy(float)


def mean_interval_blocks(matrix: np.ndarray, level: float = LEVEL) -> tuple[float, float, float]:
    """Mean of a (replicates, blocks) table and its `level` t interval, replicates and blocks
    random (threedcal.evaluate.ablation.contrast; one replicate: the blocks alone)."""

    mean, se, df = (float(v) for v in contrast(matrix, np.zeros_like(matrix), 0.0))
    half = float(stdtrit(df, 0.5 + level / 2)) * se
    return mean, mean - half, mean + half


def relative_change(
    sample: np.ndarray, reference: np.ndarray, level: float = LEVEL
) -> tuple[float, float, float]:
    """mean(sample) / mean(reference) − 1 and its Fieller interval, paired on blocks; the arms'
    runs are independent of each other (a quick run is no replicate of a full model)."""
    ratio = float(np.mean(sample) / np.mean(reference))
    low, high = ratio_interval(sample, reference, (1 - level) / 2, independent=True)
    return ratio - 1, low - 1, high - 1


def validation_rows(
    models: Sequence[ArmModel], scores: pd.DataFrame, blocks: pd.Series
) -> list[dict]:
    """One validation_mse row per model point: the arm's mean MSE over blocks, and its relative
    change against `full` (which is its own reference: no change)."""
    matrices = {key: block_matrix(part, blocks) for key, part in scores.groupby(["arm", "round"])}
    reference = matrices[("full", -1)]
    rows = []
    for model in models:
        matrix = matrices[model.key]
        value = mean_interval_blocks(matrix)
        change = (math.nan,) * 3 if model.arm == "full" else relative_change(matrix, reference)
        rows.append(_row(model, "validation_mse", "", value, change))
    return rows


def object_presses(
    models: Sequence[ArmModel],
    objects_scene: Mapping,
    pressing_dir: str | Path,
    registration: str | Path,
    progress: bool = False,
) -> pd.DataFrame:
    """Per reporting press, model and replicate: the printer protocol's errors (presses.csv's
    rows of the objects stage, `P` standing for the model point's position in `models`)."""
    unique = list(dict.fromkeys(path for model in models for path in model.paths))
    with tempfile.TemporaryDirectory() as scratch:
        evaluate_objects(
            objects_setup(objects_scene),
            {j: [path] for j, path in enumerate(unique)},  # each file pressed once
            pressing_dir,
            registration,
            scratch,
            plots=False,
            progress=progress,
        )
        presses = pd.read_csv(Path(scratch) / "presses.csv")
    keep = (presses["set"] == "reporting") & (presses["protocol"] == "printer")
    presses = presses[keep]
    index = {path: j for j, path in enumerate(unique)}
    parts = [
        presses[presses["P"] == index[path]].assign(P=i, replicate=replicate)
        for i, model in enumerate(models)
        for replicate, path in enumerate(model.paths)
    ]
    return pd.concat(parts, ignore_index=True)


def object_rows(models: Sequence[ArmModel], presses: pd.DataFrame) -> list[dict]:
    """One type2_um row per model point and object: the mean Type 2 MAE over presses (and
    replicates) and its difference from `full`'s, paired on the presses."""
    full = next(i for i, m in enumerate(models) if m.arm == "full")
    rows = []
    for name, group in presses.groupby("object", sort=False):
        cells = {
            i: part.pivot(index="replicate", columns="press", values="type2_um").sort_index(axis=1)
            for i, part in group.groupby("P")
        }
        reference = cells[full].to_numpy(float)
        for i, model in enumerate(models):
            own = cells[i].to_numpy(float)
            value = crossed_mean_interval(own, LEVEL)
            if model.arm == "full":
                change = (math.nan,) * 3
            else:  # its runs against every replicate of the full calibration, press by press
                change = difference_interval(own, reference)
            rows.append(_row(model, "type2_um", str(name), value, change))
    return rows


def difference_interval(own: np.ndarray, reference: np.ndarray, level: float = LEVEL):
    """mean(own) − mean(reference) of two (runs, presses) tables paired on the presses, the runs
    of each independent (threedcal.evaluate.ablation.independent_contrast), and its t interval.
    Presses with a NaN in either (no Type 2 pixel) are left out."""

    keep = np.isfinite(own).all(axis=0) & np.isfinite(reference).all(axis=0)
    if keep.sum() < 2:
        return own[:, keep].mean() - reference[:, keep].mean(), math.nan, math.nan
    mean, se, df = independent_contrast(own[:, keep], reference[:, keep])
    half = float(stdtrit(df, 0.5 + level / 2)) * se
    return mean, mean - half, mean + half


def _row(model: ArmModel, metric: str, name: str, value, change) -> dict:
    return {
        "arm": model.arm,
        "round": model.round,
        "presses": model.presses,
        "printer_min": round(model.printer_min, 3),
        "steps": model.steps,
        "replicates": len(model.paths),
        "metric": metric,
        "object": name,
        "value": value[0],
        "value_lo": value[1],
        "value_hi": value[2],
        "change": change[0],
        "change_lo": change[1],
        "change_hi": change[2],
    }


def arms_table(rows: list[dict]) -> pd.DataFrame:
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    table["round"] = table["round"].astype("Int64")
    return table


# ---- the targets ----------------------------------------------------------------------------


def judged(low: float, high: float, limit: float) -> str:
    """A one-sided target `≤ limit` judged on an interval: met, not met, or undecided."""
    if high <= limit:
        return "met"
    if low > limit:
        return "not met"
    return "undecided"


def verdicts(
    table: pd.DataFrame,
    scene: str,
    full_scene: str,
    setup_presses: int = 0,
    stop: Mapping | None = None,
) -> dict:
    """arms.json: each target's verdict on the stopped model (arms.csv's `stopped` rows), with
    the scratch model of its round beside it; `stop`: where the run stopped and why. The presses'
    target counts every press of the unit: the rounds' and the `setup_presses` (touch search and
    any registration lattice) before them."""
    final = table[table["arm"] == "stopped"]
    if final.empty:
        raise ValueError(f"{scene}: arms.csv has no `stopped` rows to judge")
    mse = final[final["metric"] == "validation_mse"].iloc[0]
    objects = final[final["metric"] == "type2_um"]
    presses, minutes = int(mse["presses"]), float(mse["printer_min"])
    mse_verdict = judged(mse["change_lo"], mse["change_hi"], MSE_WITHIN)
    targets = {
        "validation_mse": {
            "verdict": mse_verdict,
            "change": mse["change"],
            "interval95": [mse["change_lo"], mse["change_hi"]],
            "line": (
                f"mean validation MSE within {MSE_WITHIN:.0%} of {full_scene}'s P = 80: "
                f"{mse_verdict} ({mse['change']:+.1%}, 95 % interval "
                f"{mse['change_lo']:+.1%} to {mse['change_hi']:+.1%})"
            ),
        },
        "objects": _objects_target(objects, scene, full_scene),
        "presses": {
            "verdict": "met" if presses + setup_presses <= MAX_PRESSES else "not met",
            "value": presses + setup_presses,
            "line": f"at most {MAX_PRESSES} presses: "
            f"{'met' if presses + setup_presses <= MAX_PRESSES else 'not met'} "
            f"({presses + setup_presses} in all: {presses} in rounds, {setup_presses} touch search "
            "and any registration lattice)",
        },
        "printer_minutes": {
            "verdict": "met" if minutes <= MAX_PRINTER_MINUTES else "not met",
            "value": round(minutes, 2),
            "line": f"at most {MAX_PRINTER_MINUTES:g} printer minutes (motion model): "
            f"{'met' if minutes <= MAX_PRINTER_MINUTES else 'not met'} ({minutes:.2f})",
        },
    }
    scratch = table[(table["arm"] == "scratch") & (table["metric"] == "validation_mse")]
    scratch = scratch[scratch["round"] == scratch["round"].max()]  # the stopped round
    return {
        "scene": scene,
        "compare_with": full_scene,
        "stop": None if stop is None else dict(stop),
        "presses": presses,
        "presses_in_all": presses + setup_presses,
        "printer_minutes": round(minutes, 2),
        "targets": targets,
        "scratch_same_round": None
        if scratch.empty
        else {
            "change": float(scratch["change"].iloc[0]),
            "interval95": [
                float(scratch["change_lo"].iloc[0]),
                float(scratch["change_hi"].iloc[0]),
            ],
        },
    }


def _objects_target(objects: pd.DataFrame, scene: str, full_scene: str) -> dict:
    """The Type 2 target: each object's difference from `full_scene`, its verdict, and theirs."""
    per_object = {
        row.object: {
            "difference_um": row.change,
            "interval95_um": [row.change_lo, row.change_hi],
            "verdict": judged(row.change_lo, row.change_hi, TYPE2_WITHIN_UM),
        }
        for row in objects.itertuples(index=False)
    }
    states = [o["verdict"] for o in per_object.values()]
    object_verdict = (
        "not met" if "not met" in states else "undecided" if "undecided" in states else "met"
    )
    if not per_object:
        raise ValueError(
            f"{scene}: no object presses of {full_scene} to score (objects/presses.csv)"
        )
    worst = max(per_object.items(), key=lambda item: item[1]["interval95_um"][1])
    return {
        "verdict": object_verdict,
        "per_object": per_object,
        "line": f"Type 2 MAE within {TYPE2_WITHIN_UM:.0f} µm of {full_scene}'s on every object "
        f"(printer protocol): {object_verdict} (highest bound: {worst[0]} "
        f"{worst[1]['difference_um']:+.1f} µm, 95 % interval "
        f"{worst[1]['interval95_um'][0]:+.1f} to {worst[1]['interval95_um'][1]:+.1f})",
    }


# ---- the figure -----------------------------------------------------------------------------


def arms_figure(table: pd.DataFrame, path: str | Path, title: str) -> None:
    """Error against presses (left) and against printer minutes (right): the quick and scratch
    arms round by round with their 95 % intervals, the full calibration as a band (its presses
    and minutes in the legend); one row for validation MSE, one per test object."""
    plt = pyplot()
    panels = [("validation_mse", "")] + [
        ("type2_um", name)
        for name in dict.fromkeys(table.loc[table["metric"] == "type2_um", "object"])
    ]
    fig, axes = plt.subplots(
        len(panels), 2, figsize=(8, 2.3 * len(panels)), dpi=110, squeeze=False, sharex="col"
    )
    colours = {"quick": "tab:blue", "scratch": "tab:orange", "full": "tab:green"}
    for (metric, name), row_axes in zip(panels, axes, strict=True):
        part = table[(table["metric"] == metric) & (table["object"].fillna("") == name)]
        full = part[part["arm"] == "full"].iloc[0]
        for ax, column in zip(row_axes, ("presses", "printer_min"), strict=True):
            for arm in ("quick", "scratch"):
                points = part[part["arm"] == arm].sort_values(column)
                if points.empty:
                    continue
                ax.errorbar(
                    points[column],
                    points["value"],
                    yerr=[
                        points["value"] - points["value_lo"],
                        points["value_hi"] - points["value"],
                    ],
                    fmt="o-",
                    ms=3,
                    capsize=2,
                    c=colours[arm],
                    label=arm,
                )
            stopped = part[part["arm"] == "stopped"]
            for point in stopped.itertuples(index=False):
                ax.errorbar(
                    [getattr(point, column)],
                    [point.value],
                    yerr=[[point.value - point.value_lo], [point.value_hi - point.value]],
                    fmt="D",
                    ms=5,
                    capsize=3,
                    c="black",
                    label=f"stopped ({point.replicates} run{'s' * (point.replicates > 1)})",
                )
            ax.axhline(full["value"], c=colours["full"], lw=1)
            ax.axhspan(full["value_lo"], full["value_hi"], color=colours["full"], alpha=0.2, lw=0)
            ax.plot(
                [],
                [],
                c=colours["full"],
                label=f"full: {int(full['presses'])} presses, {full['printer_min']:.0f} min",
            )
            if metric == "validation_mse":  # fresh weights start an order of magnitude off
                ax.set(yscale="log")
            ylabel = "validation MSE" if metric == "validation_mse" else f"{name} Type 2 (µm)"
            ax.set_ylabel(ylabel, fontsize=8)
            ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=6)
    axes[-1][0].set_xlabel("presses")
    axes[-1][1].set_xlabel("printer minutes (motion model)")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# ---- the stage ------------------------------------------------------------------------------


def arms_stage(
    name: str,
    scene: Mapping,
    *,
    store: str | Path,
    rounds: str | Path,
    rounds_dir: str | Path,
    full_name: str,
    full_models: Sequence[str | Path],
    trainset: str | Path,
    splits: str | Path,
    collect_summary: str | Path | None,
    objects_scene: Mapping,
    pressing_dir: str | Path,
    registration: str | Path,
    out: Mapping[str, str | Path],
    progress: bool = True,
) -> dict:
    """The `quick_arms` rule: scratch/r{k}/, arms.csv, arms.png and arms.json."""
    prepared = prepare(scene, source=f"scenes.{name}")
    loop = QuickLoop(scene, prepared.plan, store, out["scratch"], prepared.sensor, prepared.printer)
    start_min = loop.printer_s(loop.first_row) / 60
    table = pd.read_csv(rounds)
    quick = run_arm(table, rounds_dir, start_min)
    scratch = scratch_arm(loop, quick, out["scratch"], progress)
    hardware_s = None
    if collect_summary is not None and Path(collect_summary).is_file():
        hardware_s = json.loads(Path(collect_summary).read_text()).get("estimated_hardware_s")
    split_table = pd.read_csv(splits)
    full = full_arm(full_models, len(split_table), hardware_s)
    models = [*quick, stopped_arm(quick), *scratch, full]
    validation = TrainingSet.load(trainset)
    scores = validation_scores(models, validation, split_table)
    blocks = spatial_blocks(scores, scoring_disc_mm(validation))
    rows = validation_rows(models, scores, blocks)
    presses = object_presses(models, objects_scene, pressing_dir, registration, progress)
    rows += object_rows(models, presses)
    arms = arms_table(rows)
    arms.to_csv(out["table"], index=False, float_format="%.6g")
    arms_figure(arms, out["figure"], f"{name}: quick, scratch and {full_name}'s P = 80")
    stop = {
        "scene": name,
        "round": int(table["round"].iloc[-1]),
        "presses": int(table["presses"].iloc[-1]),
        "printer_minutes": round(float(table["printer_s"].iloc[-1]) / 60, 2),
        "decision": str(table["decision"].iloc[-1]),
    }
    record = verdicts(arms, name, full_name, setup_presses=loop.first_row, stop=stop)
    Path(out["verdicts"]).write_text(json.dumps(record, indent=2) + "\n")
    for target in record["targets"].values():
        logging.getLogger("threedcal").info("%s", target["line"])
    return record
