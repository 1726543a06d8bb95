"""The quick calibration: rounds of presses, each scored before it trains, until more stop paying.

One collection run (threedcal.collect.run, homed once) stops at the end of every round of the
quick plan (threedcal.collect.quick_plan) and hands over to `QuickLoop.round_done`, the probe
held over the gel. There the rows captured so far are registered and labelled
(threedcal.dataset.build.collected_so_far); the round's presses are scored by the model as it
stood before them (prequential: no model has seen them) and by the one before that; the model is
fine-tuned for a fixed number of steps on every press so far, from the last round's weights
(round 1: `model.init`'s); and the stop rule (threedcal.stop_rule) says whether to go on.

The store is a source like any scene's raw.zarr: filled under a staging path, moved into place
when the rule stops (marked with the rows it holds), never overwritten. A rerun with the store in
place replays the rounds from it without a printer: the same config gives the same models and
the same decisions; a rule that now asks for more presses than the store holds is refused.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import zarr

from threedcal.collect.quick_plan import quick_rounds, rows_per_press
from threedcal.collect.store import StoreError
from threedcal.dataset.build import collected_so_far
from threedcal.dataset.splits import replicate_seed
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError, ThreedcalError
from threedcal.evaluate.object_errors import mean_interval
from threedcal.evaluate.validation import coordinate_mse
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.contact_guard import contact_figures, median_press, warn_if_oversized
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import save_initial, train
from threedcal.model.train_settings import TrainSettings
from threedcal.stop_rule import Improvement, decide, paired_improvement, rule_problems
from threedcal.study.config import quick_run, quick_scene_problems
from threedcal.study.scene import dataset_settings
from threedcal.study.session import (
    collect_on_rig,
    estimate_hardware_s,
    finished_store_summary,
    frame_settings,
    open_store,
    prepare,
)
from threedcal.study.training import train_settings


@dataclass(frozen=True)
class QuickSettings:
    """The scene's `quick:` section: steps a round, the stop rule's margin and confidence."""

    steps: int
    margin: float
    confidence: float

    @classmethod
    def from_scene(cls, scene: Mapping) -> QuickSettings:
        quick = scene.get("quick") or {}
        settings = cls(
            steps=int(quick.get("steps", 2400)),
            margin=float(quick.get("margin", 0.05)),
            confidence=float(quick.get("confidence", 0.9)),
        )
        problems = rule_problems(settings.margin, settings.confidence)
        if problems:
            raise ConfigError("; ".join(problems))
        return settings


@dataclass
class RoundRecord:
    round: int
    presses: int  # quick presses collected so far
    presses_scored: int  # of this round's, the ones labelled (their probe centre in view)
    printer_s: float  # the printer's time so far, from the motion model
    mse: float  # prequential: this round's presses under the model before them
    mse_low: float
    mse_high: float
    improvement: float  # what the previous round's data did on this round's presses
    improvement_upper: float
    decision: str
    train_s: float  # wall time of this round's labelling, scoring and fine-tuning
    # the model before the round on its presses: median contact area over the probe's disc
    # (threedcal.model.contact_guard; above 1, more than the probe can touch)
    contact_area_ratio: float


# rounds.csv's columns: RoundRecord's fields, in order (a new figure per round is a new field)
ROUND_COLUMNS = tuple(field.name for field in fields(RoundRecord))


def round_train_settings(scene: Mapping) -> TrainSettings:
    """How each round fine-tunes: the scene's `model:` with a fixed budget, one cosine cycle of
    `quick.steps` on every press so far (nothing held out); run r with the seed's replicate r − 1."""
    base = train_settings(scene)
    base = replace(base, seed=replicate_seed(base.seed, quick_run(scene) - 1))
    steps = QuickSettings.from_scene(scene).steps
    fixed = {"rule": "doubling", "holdout": 0.0, "first_cycle": steps, "min_gain": 0.0}
    return replace(base, stopping={**fixed, "max_steps": steps})


class QuickLoop:
    """The rounds of one scene's quick calibration: `round_done(rows)` at each round's end."""

    def __init__(
        self,
        scene: Mapping,
        plan: pd.DataFrame,
        store_path: str | Path,
        work_dir: str | Path,
        sensor: Mapping,
        printer: Mapping,
        progress: bool = False,
    ):
        self.scene, self.plan, self.sensor, self.printer = scene, plan, sensor, printer
        self.store_path, self.work = Path(store_path), Path(work_dir)
        self.progress = progress
        self.settings = QuickSettings.from_scene(scene)
        self.dataset_settings = dataset_settings(scene)  # every round registers and labels with it
        # the rounds' first row: after the touch search and any registration lattice
        self.per_press = rows_per_press(scene["plan"])
        self.first_row = int(np.flatnonzero(plan["phase"].to_numpy() == "grid")[0])
        self.first_row -= self.per_press - 1
        self.ends = quick_rounds(scene["plan"], self.first_row)
        self.train_settings = round_train_settings(scene)
        self.models: list[Path] = []  # M0 (the starting weights), M1 (after round 1), ...
        self.records: list[RoundRecord] = []
        self.stopped: str | None = None
        self.registration: dict = {}
        self._registered = None  # the last round's registered store: its fit serves the next

    @property
    def rows_used(self) -> int:
        return self.ends[len(self.records) - 1] if self.records else self.first_row

    def round_done(self, rows: int) -> bool:
        """Every round that ends at or before `rows` and is not yet done: score, train, decide.
        False once the rule has stopped."""
        while self.stopped is None and len(self.records) < len(self.ends):
            end = self.ends[len(self.records)]
            if end > rows:
                break
            self._round(end)
        return self.stopped is None

    def _round(self, rows: int) -> None:
        began = time.perf_counter()
        k = len(self.records) + 1
        trainset, self.registration, self._registered = collected_so_far(
            self.dataset_settings, self.store_path, rows, prior=self._registered
        )
        if not self.models:
            initial = self.work / "r0" / "model.pt"
            save_initial(trainset, initial, self.train_settings)
            self.models.append(initial)
        start = self.ends[k - 2] if k > 1 else self.first_row
        after = self._press_mse(self.models[k - 1], trainset, start, rows)
        area_ratio = self._contact_area_ratio(self.models[k - 1], trainset, start, rows, k)
        improvement = None
        if k > 1:
            before = self._press_mse(self.models[k - 2], trainset, start, rows)
            improvement = _paired(before, after, self.settings.confidence)
        settings = self.train_settings
        if k > 1:  # from the last round's weights (round 1: model.init's, as configured)
            settings = replace(settings, init=str(self.models[k - 1]))
        train(trainset, self.work / f"r{k}", 80, settings, progress=self.progress)
        self.models.append(self.work / f"r{k}" / "model.pt")
        decision = decide(improvement, self.settings.margin, at_cap=rows == self.ends[-1])
        mse, low, high = (
            mean_interval(after, self.settings.confidence) if len(after) else (math.nan,) * 3
        )
        self.records.append(
            RoundRecord(
                round=k,
                presses=self.presses(rows),
                presses_scored=len(after),
                printer_s=round(self.printer_s(rows), 1),
                mse=mse,
                mse_low=low,
                mse_high=high,
                improvement=math.nan if improvement is None else improvement.estimate,
                improvement_upper=math.nan if improvement is None else improvement.upper,
                decision=decision.reason if decision.go_on else f"stop: {decision.reason}",
                train_s=round(time.perf_counter() - began, 2),
                contact_area_ratio=area_ratio,
            )
        )
        if not decision.go_on:
            self.stopped = decision.reason
        logging.getLogger("threedcal").info("quick round %d: %s", k, self.records[-1])

    def _press_mse(self, model_path: Path, trainset, start: int, stop: int) -> np.ndarray:
        """Per press of plan rows start..stop−1 (those labelled), the model's gradient MSE
        (the stats stage's: a disc of 1.5 contact radii about the probe)."""
        rows = trainset.samples["plan_row"].to_numpy()
        scored = (rows >= start) & (rows < stop)
        if not scored.any():
            return np.zeros(0)
        samples = trainset.samples.assign(split=np.where(scored, "score", "train"))
        view = TrainingSet(
            trainset.frames,
            trainset.blank,
            samples,
            trainset.px_per_mm,
            trainset.sphere_radius_mm,
            trainset.max_slope_deg,
            trainset.meta,
        )
        estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
        return coordinate_mse(estimator, view, split="score")["mse"].to_numpy(float)

    def presses(self, rows: int) -> int:
        """The rounds' presses in the plan's first `rows` rows."""
        return (rows - self.first_row) // self.per_press

    def _contact_area_ratio(self, model_path: Path, trainset, start: int, stop: int, k: int):
        """The median contact area over the probe's disc of the round's presses (plan rows
        start..stop−1) under `model_path`; a median press over the bound is warned of."""
        rows = trainset.samples["plan_row"].to_numpy()
        scored = np.flatnonzero((rows >= start) & (rows < stop))
        if not scored.size:
            return math.nan
        estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
        depth = estimator.depth(np.asarray(trainset.frames)[scored])
        radius = float(trainset.sphere_radius_mm)
        figures = [contact_figures(d, radius, trainset.px_per_mm) for d in depth]
        unit = f"sensor {self.sensor.get('name')}, quick calibration round {k}"
        warn_if_oversized(unit, median_press(figures), radius)
        return float(np.median([f.area_ratio for f in figures]))

    def printer_s(self, rows: int) -> float:
        """The printer's time for the plan's first `rows` rows, from the motion model (homing,
        moves, waits, settling, capture): what the user waits at the rig, training aside."""
        return estimate_hardware_s(self.sensor, self.printer, self.plan.iloc[:rows])

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([asdict(r) for r in self.records], columns=list(ROUND_COLUMNS))

    def stop_record(self) -> dict[str, Any]:
        last = self.records[-1]
        return {
            "stopped": self.stopped,
            "round": last.round,
            "presses": last.presses,
            "presses_in_all": last.presses
            + self.first_row,  # the touch search's and any registration lattice's too
            "touch_presses": int(np.sum(self.plan["phase"].to_numpy() == "touch")),
            "printer_s": last.printer_s,
            "printer_minutes": round(last.printer_s / 60, 2),
            "mse": None if math.isnan(last.mse) else last.mse,
            "improvement": None if math.isnan(last.improvement) else last.improvement,
            "improvement_upper": None
            if math.isnan(last.improvement_upper)
            else last.improvement_upper,
            "margin": self.settings.margin,
            "confidence": self.settings.confidence,
            "steps_per_round": self.settings.steps,
            "max_presses": int(self.scene["plan"]["max_presses"]),
            "round_presses": int(self.scene["plan"]["round_presses"]),
            "registration": {
                k: self.registration.get(k)
                for k in (
                    "residual_px",
                    "touch_offset_mm",
                    "contact_z_mm",
                    "touch_method",
                    "contacts_used",
                    "lens_free",
                    "affine_px_per_mm",
                    "lens",
                )
            },
        }


def _paired(before: np.ndarray, after: np.ndarray, confidence: float) -> Improvement | None:
    if len(before) == 0:
        return None
    try:
        return paired_improvement(before, after, confidence)
    except ValueError as exc:  # a diverged model: named, not a bare statistics error
        raise ThreedcalError(f"quick round: {exc} (did a fine-tuning diverge?)") from exc


def quick_stage(
    name: str,
    scene: Mapping,
    *,
    store: str | Path,
    staging: str | Path,
    model: str | Path,
    rounds: str | Path,
    stop: str | Path,
    work: str | Path,
    progress: bool = True,
    ask=None,
) -> dict[str, Any]:
    """The `quick` rule: collect round by round until the stop rule or the cap (or replay the
    rounds from a store in place), then write model.pt, rounds.csv and stop.json."""
    source = f"scenes.{name}"
    if scene["plan"].get("pattern") != "quick":
        raise ConfigError(f"{source}.plan.pattern: the quick stage needs `quick`")
    began = time.perf_counter()
    prepared = prepare(scene, source=source)
    problems = _start_problems(scene, prepared.sensor)
    if problems:  # before the printer moves
        raise ConfigError(f"{source}: " + f"\n  {source}.".join(problems))
    settings = frame_settings(scene, prepared)
    store, staging, work = Path(store), Path(staging), Path(work)
    if work.exists():
        shutil.rmtree(work)  # the rounds are made again from the store, never mixed with old ones
    loop = QuickLoop(scene, prepared.plan, store, work, prepared.sensor, prepared.printer, progress)
    if store.exists():
        held = _finished_rows(store, prepared.plan, settings)
        loop.store_path = store
        loop.round_done(held)
        if loop.stopped is None:
            raise StoreError(
                f"{store}: holds {loop.presses(held)} quick presses, but the stop rule as "
                "configured now asks for more; restore the settings it was collected with, or "
                f"move it away to collect anew (e.g. `mv {store} {store}.old`)"
            )
    else:
        loop.store_path = staging
        raw = open_store(staging, name, scene, prepared, settings)
        if not raw.complete:
            held = int(np.sum(raw.captured))
            if held:  # a resumed run: the rounds it holds are decided before the printer moves
                loop.round_done(held)
            if loop.stopped is None:
                _collect_rounds(scene, prepared, raw, loop, progress, ask)
                loop.round_done(int(np.sum(raw.captured)))  # rounds a resumed run did not pass
            if loop.stopped is None:
                raise StoreError(f"{staging}: the collection ended before the stop rule decided")
            raw.finalize({"quick": loop.stop_record()}, rows=loop.rows_used)
        else:  # finished, then stopped before the move: its rounds replayed as a finished store's
            loop.round_done(int(raw.group.attrs.get("captured_rows") or len(prepared.plan)))
        os.replace(staging, store)
    record = loop.stop_record()
    record.update(store=str(store), wall_s=round(time.perf_counter() - began, 1))
    for path in (model, rounds, stop):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(loop.models[-1], model)
    loop.table().to_csv(rounds, index=False)
    Path(stop).write_text(json.dumps(record, indent=2, default=_plain) + "\n")
    return record


def _start_problems(scene: Mapping, sensor: Mapping) -> list[str]:
    """The config check's refusals of a quick scene, and a checkpoint `model.init` that does not
    fit the network or the frames: found before anything is pressed."""
    problems = quick_scene_problems(scene, sensor)
    model = scene.get("model") or {}
    init = model.get("init")
    if problems or init in (None, "pretrained"):
        return problems
    source = read_checkpoint(init)
    factor = int(scene["dataset"]["downscale"])
    frames = (sensor["image"]["height_px"] // factor, sensor["image"]["width_px"] // factor)
    if source.get("preset") != model.get("preset"):
        problems.append(
            f"model.init: {init} holds a {source.get('preset')!r} network, model.preset is "
            f"{model.get('preset')!r}"
        )
    if source.get("image_shape") and tuple(source["image_shape"]) != frames:
        problems.append(
            f"model.init: {init} was trained on {tuple(source['image_shape'])} px frames, this "
            f"sensor's are {frames} at dataset.downscale {factor}"
        )
    return problems


def _plain(value):
    return value.item() if isinstance(value, np.generic) else str(value)


def _finished_rows(path: Path, plan: pd.DataFrame, settings: Mapping) -> int:
    """The plan rows a finished quick store holds, after checking its settings are the config's."""
    finished_store_summary(path, plan, settings)
    attrs = zarr.open_group(str(path), mode="r").attrs
    return int(attrs.get("captured_rows") or len(plan))


def _collect_rounds(scene, prepared, store, loop: QuickLoop, progress: bool, ask) -> None:
    """One collection run over the rig, stopping at the round the rule ends."""
    collect_on_rig(
        scene, prepared, store, progress, ask, boundaries=loop.ends, at_boundary=loop.round_done
    )
