"""The quick calibration's plan: a seeded space-filling design over the gel the camera sees,
pressed in rounds (each round's prefix spread evenly), optionally pausing to register on the way
down."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from threedcal.collect.plan import camera_view_mm, check_plan_size, dome_sag_mm, plan_area_mm
from threedcal.errors import ConfigError
from threedcal.seeds import replicate_seed

# The quick plan's rounds: fewer presses than this cannot reach every quarter of the gel, and the
# stop rule's paired interval needs a few presses a round to say anything.
MIN_ROUND_PRESSES = 4


# The quick plan's default area keeps this far inside the camera's nominal view: a seating error
# of the sensor in its base (the bench draws up to 0.4 mm) must not carry a press out of the frame.
QUICK_VIEW_MARGIN_MM = 0.5


def quick_area_mm(sensor: Mapping, plan_config: Mapping) -> tuple[float, float, float, float]:
    """The area a quick plan spreads its presses over: `area_mm` as configured, else the part of
    the probe area the camera sees, QUICK_VIEW_MARGIN_MM inside the view."""
    if plan_config.get("area_mm") is not None:
        x0, y0, x1, y1 = (float(v) for v in plan_config["area_mm"])
        return x0, y0, x1, y1
    width, height = plan_area_mm(sensor)
    vx0, vy0, vx1, vy1 = camera_view_mm(sensor)
    margin = QUICK_VIEW_MARGIN_MM
    return (
        max(vx0 + margin, 0.0),
        max(vy0 + margin, 0.0),
        min(vx1 - margin, width),
        min(vy1 - margin, height),
    )


def quick_problems(plan_config: Mapping, sensor: Mapping) -> list[str]:
    """Why a quick plan's rounds could not cover the gel the camera sees ([] when they can)."""
    problems = []
    per_round = int(plan_config.get("round_presses", 10))
    most = int(plan_config.get("max_presses", 50))
    if pauses_to_register(plan_config):
        registration = plan_config["registration"]
        if float(registration.get("spacing_mm", 0.0)) > 0:
            problems.append(
                "plan.registration: each_press registers the rounds' presses; a lattice "
                "(spacing_mm > 0) as well is not allowed"
            )
        if float(registration.get("depth_mm", 0.4)) >= float(plan_config["depth_mm"]):
            problems.append(
                f"plan.registration.depth_mm: {registration.get('depth_mm', 0.4)} must lie above "
                f"plan.depth_mm ({plan_config['depth_mm']}): each press pauses there on its way "
                "down"
            )
    if per_round < MIN_ROUND_PRESSES:
        problems.append(
            f"plan.round_presses: {per_round} presses a round cannot cover the gel (at least "
            f"{MIN_ROUND_PRESSES}: one per quarter, and the stop rule compares presses in pairs)"
        )
    if most < per_round:
        problems.append(
            f"plan.max_presses: {most} is fewer than one round (round_presses: {per_round})"
        )
    if sensor.get("type") != "vision":
        problems.append("plan.pattern: quick calibrates a vision sensor (a camera's frames)")
        return problems
    x0, y0, x1, y1 = quick_area_mm(sensor, plan_config)
    vx0, vy0, vx1, vy1 = camera_view_mm(sensor)
    width, height = plan_area_mm(sensor)
    lo_x, lo_y, hi_x, hi_y = max(vx0, 0.0), max(vy0, 0.0), min(vx1, width), min(vy1, height)
    tolerance = 1e-9
    if not (x1 > x0 and y1 > y0):
        problems.append(f"plan.area_mm: {[x0, y0, x1, y1]} is empty (x0 < x1 and y0 < y1 needed)")
    elif (
        x0 < lo_x - tolerance
        or y0 < lo_y - tolerance
        or x1 > hi_x + tolerance
        or y1 > hi_y + tolerance
    ):
        problems.append(
            f"plan.area_mm: [{x0:g}, {y0:g}, {x1:g}, {y1:g}] mm reaches outside what the camera "
            f"sees of the probe area ([{lo_x:.2f}, {lo_y:.2f}, {hi_x:.2f}, {hi_y:.2f}] mm, "
            "plan-relative): presses there give no frames to learn from"
        )
    return problems


def quick_plan(sensor: Mapping, plan_config: Mapping, run: int = 1) -> pd.DataFrame:
    """The quick plan's presses: `max_presses` of a seeded scrambled Halton design over the quick
    area (threedcal.collect.design), each `depth_mm` deep (dome compensated) for `frames` frames,
    in rounds of `round_presses` (each round's prefix spreads evenly), each round a short path.
    Run r of a calibration (`quick.run`) scrambles with plan.seed's replicate r − 1."""
    # local: scipy stays out of the Snakefile's parse
    from threedcal.collect.design import halton_design, round_order

    problems = quick_problems(plan_config, sensor)
    if problems:
        raise ConfigError("; ".join(problems))
    most, per_round = int(plan_config.get("max_presses", 50)), int(plan_config["round_presses"])
    check_plan_size(most, most * int(plan_config["frames"]), f"plan.max_presses={most}")
    area = quick_area_mm(sensor, plan_config)
    seed = replicate_seed(int(plan_config.get("seed", 0)), run - 1)
    xy = halton_design(most, area, seed, per_round)
    xy = np.round(xy[round_order(xy, per_round, start=(area[0], area[1]))], 4)
    sag = dome_sag_mm(sensor, xy[:, 0], xy[:, 1])
    presses = pd.DataFrame(
        {
            "x_mm": xy[:, 0],
            "y_mm": xy[:, 1],
            "depth_mm": np.round(float(plan_config["depth_mm"]) + sag, 4),
            "frames": int(plan_config["frames"]),
            "phase": "grid",
        }
    )
    if not pauses_to_register(plan_config):
        return presses
    # each press pauses on its way down: a "register" row, then its "grid" row at the same place
    paused = presses.assign(
        depth_mm=np.round(float(plan_config["registration"]["depth_mm"]) + sag, 4),
        frames=int(plan_config["registration"].get("frames", 1)),
        phase="register",
    )
    rows = pd.concat([paused, presses], keys=[0, 1]).swaplevel().sort_index(kind="stable")
    return rows.reset_index(drop=True)


def pauses_to_register(plan_config: Mapping) -> bool:
    """Whether a quick plan's presses register on their way down (`registration.each_press`):
    each pauses at the registration depth for its frames there, then goes on to its own depth."""
    registration = plan_config.get("registration") or {}
    return plan_config.get("pattern") == "quick" and bool(registration.get("each_press"))


def rows_per_press(plan_config: Mapping) -> int:
    """Plan rows a quick press takes: two when it pauses to register on its way down."""
    return 2 if pauses_to_register(plan_config) else 1


def quick_rounds(plan_config: Mapping, first_row: int) -> list[int]:
    """The plan rows at which each round of a quick plan ends (exclusive), its presses starting
    at `first_row` (after the touch search and any registration lattice)."""
    most, per_round = int(plan_config["max_presses"]), int(plan_config["round_presses"])
    ends = list(range(per_round, most, per_round)) + [most]
    return [first_row + end * rows_per_press(plan_config) for end in ends]


def continued_presses(plan: pd.DataFrame) -> np.ndarray:
    """Per plan row: whether it goes on with the row before as one press (the probe stays down
    and goes deeper at the same place): a quick press's grid row after its pause to register."""
    if "phase" not in plan or len(plan) < 2:
        return np.zeros(len(plan), dtype=bool)
    phase = plan["phase"].astype(str).to_numpy()
    x, y, depth = (plan[c].to_numpy(float) for c in ("x_mm", "y_mm", "depth_mm"))
    out = np.zeros(len(plan), dtype=bool)
    out[1:] = (
        (phase[:-1] == "register")
        & (phase[1:] == "grid")
        & (x[1:] == x[:-1])
        & (y[1:] == y[:-1])
        & (depth[1:] >= depth[:-1])
    )
    return out
