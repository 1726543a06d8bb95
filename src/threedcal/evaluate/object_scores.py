"""The `objects` stage: every model's depth of every pressed test object, scored under both
protocols (`printer`: the ground truth where the printer put the object; `paper`: aligned to the
prediction, as the paper did), and the tables of the scores (Sec. IV, Table II)."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.dataset.trainset import pool_to
from threedcal.evaluate.groundtruth import HeightMap, surface_height
from threedcal.evaluate.object_errors import (
    PROTOCOLS,
    crossed_mean_interval,
    evaluate_press,
    pixel_errors_um,
    printer_press,
)
from threedcal.evaluate.object_figures import (
    plot_depth_sections,
    plot_error_violins,
    plot_pill_by_fraction,
)
from threedcal.evaluate.object_presses import read_presses
from threedcal.evaluate.objects import object_label
from threedcal.evaluate.press_plan import (
    SETS,
    ObjectsSetup,
    Placement,
    PrinterFrame,
    object_mesh,
    read_registration,
)
from threedcal.lens import RadialLens, rectify_if
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator


def _checkpoint_estimator(model: str | Path, blank: np.ndarray):
    checkpoint = read_checkpoint(model)
    shape = tuple(checkpoint.get("image_shape") or np.asarray(checkpoint["blank"]).shape[:2])
    return DepthEstimator(checkpoint, device="cpu", blank=pool_to(blank, shape))


def evaluate_objects(
    setup: ObjectsSetup,
    models: Mapping[int, object | Sequence[object]],
    pressing_dir: str | Path,
    registration_path: str | Path,
    out_dir: str | Path,
    *,
    estimator: Callable = _checkpoint_estimator,
    plots: bool = True,
    progress: bool = True,
) -> pd.DataFrame:
    """Score every model's depth of every press under both protocols; write tables and figures.

    `models[p]` is one model or a list of them, one per ablation replicate (list position =
    replicate). `estimator(model, session_blank)` gives an object with `px_per_mm`, `image_shape`
    and `depth(frame, method=)` (a DepthEstimator by default). `plots=False` skips the figures
    (drawn from replicate 0). Every press is rendered once (by the object_presses rule); the
    printer protocol's ground truth is rasterised once per press and frame size. errors.csv:
    reporting presses only, per object, P and protocol, the mean over presses and replicates with
    its 95 % interval (`object_error_summary`); tuning.csv: the same over the tuning presses,
    under the printer protocol only (the one settings are chosen on).
    """
    started = time.perf_counter()
    scoring = _Scoring(setup, models, pressing_dir, registration_path, Path(out_dir), estimator)
    scoring.plots = plots
    plan = scoring.plan
    for press in tqdm(
        plan.itertuples(index=False), total=len(plan), desc="objects", disable=not progress
    ):
        scoring.score(press)
    errors = scoring.write()
    seconds = time.perf_counter() - started
    n_models = sum(len(v) for v in scoring.replicates.values())
    logging.getLogger("threedcal").info(
        "objects: %d presses x %d models scored under both protocols in %.1f s "
        "(%.2f s per press, %.3f s per press and model, figures included)",
        len(plan),
        n_models,
        seconds,
        seconds / max(len(plan), 1),
        seconds / max(len(plan) * n_models, 1),
    )
    return errors


class _Scoring:
    """One objects stage: the presses and models it scores, and the rows and figures it gathers."""

    def __init__(self, setup, models, pressing_dir, registration_path, out_dir: Path, estimator):

        self.out_dir = out_dir
        self.figures = out_dir / "figures"
        self.figures.mkdir(parents=True, exist_ok=True)
        sensor = setup.sensor
        self.limit = float(sensor["gel"]["max_penetration_mm"])
        self.dome = sensor["gel"].get("dome")  # the truth is the depth below the undeformed gel
        registration = read_registration(registration_path)
        self.frame_map = PrinterFrame(sensor, registration, setup.mount)
        self.plan, frames, blanks, truth = read_presses(pressing_dir)
        # into the ideal frame the models were trained in, through the lens the registration fitted
        lens = RadialLens.from_record(read_registration(registration_path).get("lens"))
        self.frames = rectify_if(lens, frames)
        blanks = {name: rectify_if(lens, blank) for name, blank in blanks.items()}
        self.true_presses = truth.get("presses") if truth.get("simulated") else None
        self.integrators = list(setup.integrators)
        self.replicates = {
            p: list(m) if isinstance(m, (list, tuple)) else [m] for p, m in models.items()
        }
        self.fractions = sorted(self.replicates)
        self.full = self.fractions[-1]
        self.drawn = ", replicate 0" if any(len(v) > 1 for v in self.replicates.values()) else ""
        self.estimators = {
            (p, r, s): estimator(model, blanks[s])
            for p in self.fractions
            for r, model in enumerate(self.replicates[p])
            for s in SETS
            if s in blanks
        }
        plan = self.plan
        reporting = plan[plan["set"] == "reporting"]
        self.first_reporting = reporting.groupby("object")["frame"].min().to_dict()
        self.plots = True
        self.meshes: dict[str, object] = {}
        self.truths: dict[tuple[int, tuple], HeightMap] = {}
        self.rows, self.comparison, self.pixel_tables = [], [], []
        self.pill_maps: dict[int, np.ndarray] = {}

    def score(self, press) -> None:
        """Every model's depth of one press, under both protocols (the paper's on the first
        integrator of the reporting presses only)."""
        mesh = self.meshes.setdefault(press.object, object_mesh(press.object))
        placed = self.frame_map.placement(head_position(press))
        true = None if self.true_presses is None else self.true_presses[press.frame]
        facts = _press_facts(press, placed, true)
        image_full = self.frames[press.frame]
        for p, r in [(q, r) for q in self.fractions for r in range(len(self.replicates[q]))]:
            est = self.estimators[(p, r, press.set)]
            factor = image_full.shape[0] / est.image_shape[0]
            image = pool_to(image_full, est.image_shape)
            pose = placed.at_scale(factor)
            surface = self._truth(press.frame, mesh, est.image_shape, pose)
            for k, method in enumerate(
                self.integrators if p == self.full else self.integrators[:1]
            ):
                depth = est.depth(image, method=method)
                results = score_press(
                    depth,
                    mesh,
                    pose,
                    surface,
                    px_per_mm=est.px_per_mm,
                    max_penetration_mm=self.limit,
                    dome=self.dome,
                    # the paper's protocol for comparison on the reporting presses; the
                    # integrators are compared, and settings chosen, under the printer protocol
                    paper=k == 0 and press.set == "reporting",
                )
                for protocol, result in results.items():
                    row = _score_row(press, p, r, protocol, result, factor, facts)
                    if protocol == "printer":
                        self.comparison.append({**row, "integrator": method})
                    if k == 0:
                        self.rows.append(row)
                if k == 0 and r == 0 and press.set == "reporting" and self.plots:
                    self._keep_for_figures(press, p, method, depth, results["printer"].gt_mm, est)

    def _truth(self, frame: int, mesh, shape, pose: Placement) -> HeightMap:
        """The printer protocol's ground truth of a press on a frame of `shape` (once each)."""
        key = (frame, tuple(shape))
        if key not in self.truths:
            self.truths[key] = surface_height(
                mesh, shape, 1.0, pose.center_px, 0.0, pose.linear_px_per_mm, dome=self.dome
            )
        return self.truths[key]

    def _keep_for_figures(self, press, p, method, depth, truth_mm, est) -> None:
        label = object_label(press.object)
        first = press.frame == self.first_reporting[press.object]
        if p == self.full:
            self.pixel_tables.append(pixel_errors_um(label, depth, truth_mm))
            if first:
                plot_depth_sections(
                    depth,
                    truth_mm,
                    self.figures / f"{label}_sections.png",
                    px_per_mm=est.px_per_mm,
                    title=f"{label}: P = {p} %{self.drawn}, {method}, printer protocol",
                )
        if label == "pill" and first:
            self.pill_maps[p] = depth

    def write(self) -> pd.DataFrame:
        """presses.csv, errors.csv, tuning.csv, integrators.csv and the figures; errors.csv's table."""
        out_dir = self.out_dir
        per_press = pd.DataFrame(self.rows)
        per_press.to_csv(out_dir / "presses.csv", index=False)
        errors = object_error_summary(per_press[per_press["set"] == "reporting"])
        errors.to_csv(out_dir / "errors.csv", index=False)
        tuning = object_error_summary(per_press[per_press["set"] == "tuning"])
        tuning.to_csv(out_dir / "tuning.csv", index=False)
        pd.DataFrame(self.comparison).to_csv(out_dir / "integrators.csv", index=False)
        if self.pixel_tables:
            plot_error_violins(
                pd.concat(self.pixel_tables),
                out_dir / "violins.png",
                title=f"pixelwise depth errors, P = {self.full} %{self.drawn}, printer protocol, "
                "reporting presses",
            )
        if self.pill_maps:
            plot_pill_by_fraction(self.pill_maps, self.figures / "pill_by_P.png")
        return errors


def _score_row(press, p, r, protocol, result, factor: float, facts: dict) -> dict:
    return {
        "object": object_label(press.object),
        "set": press.set,
        "press": press.press,
        "P": p,
        "replicate": r,
        "protocol": protocol,
        **{m: result.errors[m] for m in SUMMARY_METRICS},
        "depth_mm": result.indentation_mm,
        "depth_ratio": result.indentation_mm / facts["true_depth_mm"]
        if facts["true_depth_mm"] > 0
        else float("nan"),
        "shift_x_px": result.shift_px[0] * factor,
        "shift_y_px": result.shift_px[1] * factor,
        **facts,
    }


def score_press(
    depth: np.ndarray,
    mesh,
    pose: Placement,
    surface: HeightMap,
    *,
    px_per_mm: float,
    max_penetration_mm: float,
    paper: bool = True,
    dome: Mapping | None = None,
) -> dict:
    """One predicted depth map under each protocol: {"printer": ..., "paper": ...}.

    `pose` and `surface`: where the printer put the object, on the prediction's pixel grid
    (`surface` measured from the gel's `dome` when it has one, as the paper protocol's rasters)."""
    results = {
        "printer": printer_press(
            depth, surface, pose.depth_mm, max_penetration_mm=max_penetration_mm
        )
    }
    if paper:
        results["paper"] = evaluate_press(
            depth,
            mesh,
            px_per_mm=px_per_mm,
            nominal_indentation_mm=min(max(pose.depth_mm, 0.0), max_penetration_mm),
            max_penetration_mm=max_penetration_mm,
            center_px=pose.center_px,
            linear_px_per_mm=pose.linear_px_per_mm,
            surface=surface,
            dome=dome,
        )
    return results


def head_position(press) -> tuple[float, float, float]:
    """Where the printer says its head was: the stepper counts when M114 gave them, else the
    commanded position."""
    steps = (press.steps_x_mm, press.steps_y_mm, press.steps_z_mm)
    if all(math.isfinite(v) for v in steps):
        return steps
    return press.cmd_x_mm, press.cmd_y_mm, press.cmd_z_mm


def _press_facts(press, placed: Placement, true: Mapping | None) -> dict:
    """Registered (printer) pose of a press, and the bench's true one where there is a bench."""
    facts = {
        "registered_x_px": placed.center_px[0],
        "registered_y_px": placed.center_px[1],
        "registered_rotation_deg": placed.rotation_deg,
        "registered_depth_mm": placed.depth_mm,
        "true_x_px": float("nan"),
        "true_y_px": float("nan"),
        "true_rotation_deg": float("nan"),
        "true_depth_mm": float("nan"),
    }
    if true is not None:
        facts.update(
            true_x_px=float(true["center_px"][0]),
            true_y_px=float(true["center_px"][1]),
            true_rotation_deg=float(true["rotation_deg"]),
            true_depth_mm=float(true["depth_mm"]),
        )
    return facts


SUMMARY_METRICS = ("overall_um", "type1_um", "type2_um")


def object_error_summary(per_press: pd.DataFrame) -> pd.DataFrame:
    """Per object, P and protocol: the number of presses and replicate models, each metric's mean
    over both with its 95 % interval (`_lo`, `_hi`; `crossed_mean_interval`: presses and models
    both random, a t interval over presses when there is one replicate), and the mean depth ratio
    (protocol depth / true)."""
    columns = ["object", "P", "protocol", "presses", "replicates"]
    columns += [f"{m}{s}" for m in SUMMARY_METRICS for s in ("", "_lo", "_hi")] + ["depth_ratio"]
    out = []
    for (name, p, protocol), group in per_press.groupby(["object", "P", "protocol"], sort=False):
        row = {
            "object": name,
            "P": p,
            "protocol": protocol,
            "presses": group["press"].nunique(),
            "replicates": group["replicate"].nunique(),
        }
        for m in SUMMARY_METRICS:
            cells = group.pivot(index="replicate", columns="press", values=m)
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = crossed_mean_interval(cells.to_numpy())
        row["depth_ratio"] = float(group["depth_ratio"].mean())
        out.append(row)
    table = pd.DataFrame(out, columns=columns)
    if table.empty:
        return table
    ranks = {
        "protocol": {p: i for i, p in enumerate(PROTOCOLS)},
        "object": {o: i for i, o in enumerate(dict.fromkeys(table["object"]))},
    }
    table = table.sort_values(
        ["protocol", "object", "P"], key=lambda c: c.map(ranks[c.name]) if c.name in ranks else c
    )
    return table.reset_index(drop=True)
