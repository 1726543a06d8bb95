"""The quick calibration over units: is its model within 10 % of each unit's full calibration?

One unit cannot say: its full calibration's validation coordinates fall in a few spatial blocks,
and a quick run and a P = 80 training each carry their own training randomness. So the claim is
made over units (`make quick-study`, config/quick_study.yaml): several simulated units that the
shipped weights never saw, each calibrated quickly (its stopped model) and fully (its dense grid
and P = 80 models), both scored on the full calibration's validation presses with the stats
stage's per-coordinate gradient MSE (threedcal.evaluate.validation.coordinate_mse).

Against what labels. The full calibration's validation labels carry its own registration's error
(up to 0.6 px and 0.035 mm of touch height on these units), which its models learnt and the quick
model did not: scored there, every quick model pays for the full calibration's mistakes as well as
its own. On the simulated bench the same validation frames are therefore also labelled through the
bench's true registration and touch height (threedcal.dataset.build.labelled_through) and both
models scored there, each paying for its own registration alone. That score decides the claim;
the one against the full calibration's labels is reported beside it. The truth only scores: no
calibration sees it.

Per unit u the statistic is the relative change c_u = mean MSE(quick) / mean MSE(full) − 1, the
full side averaged over its replicates; the claim's interval is Student's t over the units' c_u
(n − 1 degrees of freedom). Each c_u already holds everything that varies within a unit (the
coordinates, both trainings, the presses), so the units are the independent replicates and the
interval is honest without modelling those parts. The per-unit interval beside it (Fieller's,
paired on the unit's spatial blocks as quick/arms.csv is) is for reading a unit, not the claim.
The claim holds when the whole interval lies inside ±MSE_WITHIN.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from threedcal.dataset.build import labelled_through
from threedcal.dataset.camera_fit import AffineFit
from threedcal.dataset.settings import DatasetSettings
from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation import spatial_blocks
from threedcal.evaluate.validation import scoring_disc_mm
from threedcal.lens import RadialLens
from threedcal.plotting import pyplot
from threedcal.profiles import load_profile
from threedcal.sim.bench import BenchTruth
from threedcal.study.quick_arms import (
    LEVEL,
    MAX_PRESSES,
    MAX_PRINTER_MINUTES,
    MSE_WITHIN,
    ArmModel,
    block_matrix,
    relative_change,
    validation_scores,
)

COLUMNS = (
    "sensor",
    "unit",
    "quick_scene",
    "full_scene",
    "presses_in_all",
    "touch_presses",
    "printer_min",
    "round",
    "stopped",
    "quick_mse",
    "full_mse",
    "full_replicates",
    "change",
    "change_lo",
    "change_hi",
    "touch_error_mm",
    "registration_error_px",
    "truth_quick_mse",
    "truth_full_mse",
    "truth_change",
    "truth_change_lo",
    "truth_change_hi",
)

# which change decides the claim: against the bench's truth where every unit has one
AGAINST = {"truth_change": "the bench's truth", "change": "the full calibration's labels"}


@dataclass(frozen=True)
class UnitPair:
    """One unit's quick and full calibrations and the files they left."""

    quick_scene: str
    full_scene: str
    sensor: str
    unit: int | None
    quick_model: str | Path
    stop: str | Path  # the quick stage's stop.json
    full_models: Sequence[str | Path]  # the full calibration's P = 80 models, every replicate
    trainset: str | Path  # the full calibration's validation set
    splits: str | Path
    truth: str | Path | None = None  # the simulated bench's hidden truth (scores, never fits)
    store: str | Path | None = None  # the full calibration's raw.zarr (relabelled)
    dataset: DatasetSettings | None = None  # the full scene's dataset settings


def unit_row(pair: UnitPair) -> dict:
    """One unit's line of units.csv: what the quick run cost and its MSE against the full one."""
    stop = json.loads(Path(pair.stop).read_text())
    models = [
        ArmModel("stopped", None, 0, math.nan, 0, (str(pair.quick_model),)),
        ArmModel("full", None, 0, math.nan, 0, tuple(str(p) for p in pair.full_models)),
    ]
    validation = TrainingSet.load(pair.trainset)
    split_table = pd.read_csv(pair.splits)
    quick_mse, full_mse, low, high = _compared(models, validation, split_table)
    truth = _truth_set(pair, split_table)
    truth_scores = (
        dict(zip(TRUTH_FIGURES, _compared(models, truth, split_table), strict=True))
        if truth is not None
        else dict.fromkeys(TRUTH_FIGURES, math.nan)
    )
    registration = stop.get("registration") or {}
    touch_error, registration_error = _bench_errors(registration, pair.truth, pair, split_table)
    return {
        "sensor": pair.sensor,
        "unit": pair.unit,
        "quick_scene": pair.quick_scene,
        "full_scene": pair.full_scene,
        "presses_in_all": int(stop["presses_in_all"]),
        "touch_presses": int(stop.get("touch_presses", 0)),
        "printer_min": float(stop["printer_minutes"]),
        "round": int(stop["round"]),
        "stopped": str(stop["stopped"]),
        "quick_mse": quick_mse,
        "full_mse": full_mse,
        "full_replicates": len(pair.full_models),
        "change": quick_mse / full_mse - 1,
        "change_lo": low,
        "change_hi": high,
        "touch_error_mm": touch_error,
        "registration_error_px": registration_error,
        "truth_quick_mse": truth_scores["quick"],
        "truth_full_mse": truth_scores["full"],
        "truth_change": truth_scores["quick"] / truth_scores["full"] - 1,
        "truth_change_lo": truth_scores["low"],
        "truth_change_hi": truth_scores["high"],
    }


TRUTH_FIGURES = ("quick", "full", "low", "high")


def _compared(models, validation: TrainingSet, split_table: pd.DataFrame) -> tuple:
    """(quick mean MSE, full mean MSE, the change's interval low, high) on `validation`'s presses,
    paired on its spatial blocks."""
    scores = validation_scores(models, validation, split_table)
    quick = scores[scores["arm"] == "stopped"]
    full = scores[scores["arm"] == "full"]
    blocks = spatial_blocks(scores, scoring_disc_mm(validation))
    _, low, high = relative_change(block_matrix(quick, blocks), block_matrix(full, blocks))
    return float(quick["mse"].mean()), float(full["mse"].mean()), low, high


def _truth_set(pair: UnitPair, split_table: pd.DataFrame) -> TrainingSet | None:
    """The full calibration's presses labelled through the bench's truth; None off the bench."""
    if pair.store is None or pair.dataset is None:
        return None
    return truth_labelled(pair.truth, pair.dataset, pair.store, split_table)


def truth_labelled(
    truth_path, settings: DatasetSettings, store: str | Path, split_table: pd.DataFrame
) -> TrainingSet | None:
    """A store's presses labelled through the bench's true registration and touch height
    (module docstring), paired point for point with `split_table`; None off the bench."""
    truth = _bench_truth(truth_path)
    if truth is None:
        return None
    fit = AffineFit(
        np.asarray(truth.affine_px_per_mm, float),
        0.0,
        np.zeros(0, bool),
        RadialLens.from_record(truth.lens),
    )
    return labelled_through(settings, store, fit, float(truth.touch_offset_mm), split_table)


def _bench_truth(path) -> BenchTruth | None:
    """The bench's hidden truth with its registration; None off the bench or in an older record."""
    if path is None or not Path(path).is_file():
        return None
    if "affine_px_per_mm" not in json.loads(Path(path).read_text()):
        return None
    return BenchTruth.read(path)


def _bench_errors(registration: Mapping, truth_path, pair, splits) -> tuple[float, float]:
    """The quick run's touch height and registration against the bench's hidden truth: the touch
    offset's error (mm) and the RMS distance (camera px) between where its fit and the truth image
    the full calibration's validation coordinates. NaN without a truth or a fit."""
    truth = _bench_truth(truth_path)
    if truth is None:
        return math.nan, math.nan
    touch = registration.get("touch_offset_mm")
    touch_error = math.nan if touch is None else float(touch) - float(truth.touch_offset_mm)
    matrix = registration.get("affine_px_per_mm")
    if matrix is None:
        return touch_error, math.nan
    fit = AffineFit(
        np.asarray(matrix, float),
        math.nan,
        np.zeros(0, bool),
        RadialLens.from_record(registration.get("lens")),
    )
    mount = load_profile("sensor", pair.sensor)["mount"]
    xy = splits[["x_mm", "y_mm"]].to_numpy(float) + [mount["x_offset_mm"], mount["y_offset_mm"]]
    error = np.linalg.norm(fit.apply(xy) - truth.camera_px(xy), axis=1)
    return touch_error, float(np.sqrt(np.mean(error**2)))


def over_units(table: pd.DataFrame, level: float = LEVEL, column: str = "change") -> dict:
    """The claim per sensor and over every unit: the mean relative change (`column`) and its t
    interval over units, the presses and printer minutes at their most; `met` when the whole
    interval lies inside ±MSE_WITHIN, `not met` when it lies wholly outside, else `undecided`."""
    groups = {str(s): part for s, part in table.groupby("sensor", sort=False)}
    if len(groups) > 1:
        groups["all"] = table
    out = {}
    for name, part in groups.items():
        changes = part[column].to_numpy(float)
        mean = float(changes.mean())
        if len(changes) > 1:
            half = (
                float(stats.t.ppf(0.5 + level / 2, len(changes) - 1))
                * float(changes.std(ddof=1))
                / math.sqrt(len(changes))
            )
        else:
            half = math.nan
        low, high = mean - half, mean + half
        inside = -MSE_WITHIN <= low and high <= MSE_WITHIN
        outside = low > MSE_WITHIN or high < -MSE_WITHIN
        verdict = "met" if inside else "not met" if outside else "undecided"
        out[name] = {
            "units": len(changes),
            "change": mean,
            "interval": [low, high],
            "verdict": verdict,
            "most_presses": int(part["presses_in_all"].max()),
            "most_printer_min": float(part["printer_min"].max()),
            "presses_verdict": "met" if part["presses_in_all"].max() <= MAX_PRESSES else "not met",
            "minutes_verdict": "met"
            if part["printer_min"].max() <= MAX_PRINTER_MINUTES
            else "not met",
            "scored_against": AGAINST[column],
            "line": (
                f"{name}: quick within {MSE_WITHIN:.0%} of the full calibration's mean validation "
                f"MSE over {len(changes)} units, scored against {AGAINST[column]}: {verdict} "
                f"({mean:+.1%}, {level:.0%} interval "
                f"{low:+.1%} to {high:+.1%}); at most {int(part['presses_in_all'].max())} "
                f"presses, {part['printer_min'].max():.2f} printer minutes"
            ),
        }
    return out


def study_figure(table: pd.DataFrame, summary: Mapping, path: str | Path) -> None:
    """Each unit's relative change with its within-unit interval (scored against the bench's truth
    where there is one, and against the full calibration's labels beside it, hollow), each
    sensor's interval over units and every unit's together, against the ±10 % band."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(1.0 + 0.8 * (len(table) + 3), 3.6), dpi=110)
    column = summary["column"]
    claims = summary["claims"]

    def point(x, value, low, high, marker, size, colour, hollow=False):
        ax.errorbar(
            [x],
            [100 * value],
            yerr=[[100 * (value - low)], [100 * (high - value)]],
            fmt=marker,
            ms=size,
            capsize=size / 2 + 1,
            c=colour,
            mfc="white" if hollow else colour,
        )

    labels: list[str] = []
    for sensor, part in table.groupby("sensor", sort=False):
        for row in part.itertuples(index=False):
            x = len(labels)
            if column != "change":
                point(x + 0.18, row.change, row.change_lo, row.change_hi, "o", 4, "grey", True)
            values = (
                getattr(row, column),
                getattr(row, f"{column}_lo"),
                getattr(row, f"{column}_hi"),
            )
            point(x, *values, "o", 4, "tab:blue")
            labels.append(f"{sensor}\nunit {row.unit}")
        claim = claims[str(sensor)]
        point(len(labels), claim["change"], *claim["interval"], "D", 6, "black")
        labels.append(f"{sensor}\nover units")
    if "all" in claims:
        point(len(labels), claims["all"]["change"], *claims["all"]["interval"], "s", 6, "black")
        labels.append("every unit")
    ax.axhspan(-100 * MSE_WITHIN, 100 * MSE_WITHIN, color="tab:green", alpha=0.15, lw=0)
    ax.axhline(0, c="grey", lw=0.8)
    ax.set_xticks(range(len(labels)), labels, fontsize=6)
    ax.set_ylabel("quick vs full: mean validation MSE (%)", fontsize=8)
    ax.tick_params(labelsize=7)
    title = f"quick against each unit's full calibration, scored against {AGAINST[column]}"
    if column != "change":
        title += f"\n(hollow: against {AGAINST['change']}; {LEVEL:.0%} intervals)"
    else:
        title += f" ({LEVEL:.0%} intervals)"
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def study_summary(table: pd.DataFrame) -> dict:
    """summary.json: the claims, scored against the bench's truth where every unit has one (module
    docstring), else against the full calibrations' labels; on the bench, those beside them."""
    column = "truth_change" if table["truth_change"].notna().all() else "change"
    summary = {"column": column, "scored_against": AGAINST[column]}
    summary["claims"] = over_units(table, column=column)
    if column != "change":
        summary["against_full_labels"] = over_units(table, column="change")
    return summary


def study_stage(pairs: Sequence[UnitPair], out: Mapping[str, str | Path]) -> dict:
    """The `quick_study` rule: units.csv, summary.json and units.png."""
    rows = [unit_row(pair) for pair in pairs]
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    summary = study_summary(table)
    for path in out.values():
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out["table"], index=False, float_format="%.6g")
    Path(out["summary"]).write_text(json.dumps(summary, indent=2) + "\n")
    study_figure(table, summary, out["figure"])
    for part in ("claims", "against_full_labels"):
        for claim in summary.get(part, {}).values():
            logging.getLogger("threedcal").info("%s", claim["line"])
    return summary
