"""Probe plans: where to press, how deep, how many frames — read, generated, ordered and validated.

A plan is a table in *plan-relative* millimetres (origin at the sensor's plan origin, printer axes):
``x_mm, y_mm, depth_mm, frames``. ``depth_mm`` is how far below the first-touch height of the gel's
apex the probe is commanded; on a domed gel the surface away from the apex sits lower, so a grid
with dome compensation commands ``depth + sag(x, y)`` to keep the penetration even — the rule the
authors' DIGIT plan follows. py3DCal plan CSVs (``x, y, depth, frames`` with a ``#`` header) load as is.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError

PLAN_COLUMNS = ("x_mm", "y_mm", "depth_mm", "frames")
# Size limits, checked before a plan is generated: the paper's densest plan has ~1,400 points and
# ~40,000 frames; a mistyped spacing must not allocate gigabytes or queue months of printer time.
MAX_PLAN_POINTS = 100_000
MAX_PLAN_FRAMES = 1_000_000


def dome_sag_mm(sensor: Mapping, x_mm, y_mm) -> np.ndarray:
    """How far the gel surface at plan (x, y) lies below its apex, from the profile's `gel.dome`.

    The dome is described in image axes about the image centre (u right, v down, mm); the nominal
    seating puts the plan-area centre there with printer +X along u and printer +Y along −v.
    """
    dome = sensor.get("gel", {}).get("dome")
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    if not dome:
        return np.zeros(np.broadcast(x, y).shape)
    width, height = plan_area_mm(sensor)
    u = x - width / 2 - dome.get("apex_x_mm", 0.0)
    v = -(y - height / 2) - dome.get("apex_y_mm", 0.0)
    return dome["kx_per_mm"] * u**2 + dome["ky_per_mm"] * v**2


def plan_area_mm(sensor: Mapping) -> tuple[float, float]:
    """Width (printer X) and height (printer Y) of the area a plan may probe, from plan origin (0, 0)."""
    width, height = sensor["probing"]["plan_area_mm"]
    return float(width), float(height)


def read_plan_csv(path: str | Path) -> pd.DataFrame:
    """A plan CSV: four numeric columns x, y, depth, frames; a header line (with or without '#')."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read plan ({exc.strerror})") from exc
    rows = []
    for number, line in enumerate(lines, start=1):
        text = line.strip().lstrip("\ufeff")
        if not text:
            continue
        fields = [f.strip() for f in text.lstrip("#").split(",")]
        if text.startswith("#") or (number == 1 and not _is_number(fields[0])):
            continue  # header or comment
        if len(fields) != 4:
            raise ConfigError(
                f"{path}, line {number}: expected 4 values (x, y, depth, frames), got {len(fields)}"
            )
        values = []
        for name, field in zip(PLAN_COLUMNS, fields, strict=True):
            if not _is_number(field):
                raise ConfigError(f"{path}, line {number}: {name}={field!r} is not a number")
            values.append(float(field))
        if values[3] != int(values[3]) or values[3] < 1:
            raise ConfigError(
                f"{path}, line {number}: frames={fields[3]!r} must be a whole number >= 1"
            )
        rows.append(values + [number])
    if not rows:
        raise ConfigError(f"{path}: the plan has no probe point")
    plan = pd.DataFrame(rows, columns=[*PLAN_COLUMNS, "line"])
    plan["frames"] = plan["frames"].astype(int)
    plan["depth_mm"] = plan["depth_mm"].abs()  # py3DCal plans may write depth as negative Z
    return plan


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def grid_plan(
    sensor: Mapping,
    spacing_mm: float,
    depths_mm,
    frames: int,
    dome_compensation: bool = True,
) -> pd.DataFrame:
    """A regular grid over the sensor's probe area (profile `probing.plan_area_mm`), serpentine ordered.

    With several depths each point is pressed at every one in the order listed before the
    gantry moves on: a model trained on one depth learns that depth's contact size as a shape prior
    and misjudges shallower or deeper objects."""
    depths = _depths(depths_mm)
    if spacing_mm <= 0 or not np.isfinite(spacing_mm):
        raise ConfigError(f"plan spacing_mm must be a positive number, got {float(spacing_mm)}")
    width, height = plan_area_mm(sensor)
    xs = np.arange(0.0, width + 1e-9, spacing_mm)
    ys = np.arange(0.0, height + 1e-9, spacing_mm)
    gx, gy = np.meshgrid(xs, ys)
    x, y = np.repeat(gx.ravel(), len(depths)), np.repeat(gy.ravel(), len(depths))
    depth = np.tile(depths, gx.size)
    if dome_compensation:
        depth = depth + dome_sag_mm(sensor, x, y)
    plan = pd.DataFrame(
        {"x_mm": x, "y_mm": y, "depth_mm": np.round(depth, 4), "frames": int(frames)}
    )
    return serpentine(plan)  # stable: a point's depths keep their order


def _depths(depths_mm) -> np.ndarray:
    depths = np.atleast_1d(np.asarray(depths_mm, dtype=float))
    if depths.size == 0:
        raise ConfigError("plan depths_mm must list at least one depth")
    if not np.all(np.isfinite(depths) & (depths > 0)):
        raise ConfigError(f"plan depths must be positive numbers, got {depths.tolist()}")
    return depths


def cross_plan(
    sensor: Mapping,
    spacing_mm: float,
    depths_mm,
    frames: int,
    arm_width_mm: float,
) -> pd.DataFrame:
    """The authors' ReSkin plan shape: a grid over the probe area, kept where it lies within
    `arm_width_mm`/2 of the area's centre lines (a plus sign), repeated at every depth in turn, each
    pass serpentine ordered. 1 mm spacing, arms 6 mm wide over 16 x 16 mm give 189 points a depth."""
    if spacing_mm <= 0 or not np.isfinite(spacing_mm):
        raise ConfigError(f"plan spacing_mm must be a positive number, got {float(spacing_mm)}")
    if arm_width_mm < 0 or not np.isfinite(arm_width_mm):
        raise ConfigError(f"plan arm_width_mm must be >= 0, got {float(arm_width_mm)}")
    depths = _depths(depths_mm)
    width, height = plan_area_mm(sensor)
    xs = np.arange(0.0, width + 1e-9, spacing_mm)
    ys = np.arange(0.0, height + 1e-9, spacing_mm)
    gx, gy = np.meshgrid(xs, ys)
    half = arm_width_mm / 2 + 1e-9
    keep = (np.abs(gx - width / 2) <= half) | (np.abs(gy - height / 2) <= half)
    x, y = gx[keep], gy[keep]
    passes = []
    for depth in depths:
        one = pd.DataFrame(
            {
                "x_mm": x,
                "y_mm": y,
                "depth_mm": np.round(depth + dome_sag_mm(sensor, x, y), 4),
                "frames": int(frames),
            }
        )
        passes.append(serpentine(one))
    return pd.concat(passes, ignore_index=True)


def serpentine(plan: pd.DataFrame, row_tolerance_mm: float = 1e-6) -> pd.DataFrame:
    """Order by rows of equal y; alternate the x direction each row, so travel between points is short."""
    plan = plan.copy()
    row = np.round(plan["y_mm"].to_numpy() / max(row_tolerance_mm, 1e-12)).astype(np.int64)
    rank = pd.Series(row).rank(method="dense").astype(int).to_numpy() - 1
    key = np.where(rank % 2 == 0, plan["x_mm"], -plan["x_mm"])
    order = np.lexsort((key, rank))
    return plan.iloc[order].reset_index(drop=True)


def _describe_row(plan: pd.DataFrame, i: int, source: str) -> str:
    if "line" in plan:
        return f"{source}, line {int(plan['line'].iloc[i])}"
    return f"{source}, point {i}"


def validate_plan(
    plan: pd.DataFrame,
    sensor: Mapping,
    printer: Mapping | None = None,
    source: str = "plan",
) -> None:
    """Every check that must pass before the printer moves; the first failure names its row."""
    max_depth = float(sensor["gel"]["max_penetration_mm"])
    width, height = plan_area_mm(sensor)
    margin = 1e-9
    for i in range(len(plan)):
        x, y, depth, frames = (plan[c].iloc[i] for c in PLAN_COLUMNS)
        where = _describe_row(plan, i, source)
        if not all(np.isfinite([x, y, depth, frames])):
            raise ConfigError(
                f"{where}: x, y, depth and frames must be finite numbers (got {x}, {y}, {depth}, {frames})"
            )
        penetration = depth - float(dome_sag_mm(sensor, x, y))
        if depth < 0 or penetration > max_depth + margin:
            raise ConfigError(
                f"{where}: depth {depth:g} mm gives {penetration:g} mm penetration, beyond the "
                f"sensor's maximum of {max_depth:g} mm"
            )
        if not (-margin <= x <= width + margin and -margin <= y <= height + margin):
            raise ConfigError(
                f"{where}: point ({x:g}, {y:g}) mm lies outside the gel's probe area "
                f"(0..{width:g} x 0..{height:g} mm)"
            )
        if frames < 1:
            raise ConfigError(f"{where}: frames must be >= 1, got {frames}")
        if printer is not None:
            target = plan_to_printer(sensor, x, y, depth)
            travel = printer["travel_mm"]
            for axis, value in zip("xyz", target, strict=True):
                if not 0 <= value <= travel[axis]:
                    raise ConfigError(
                        f"{where}: printer {axis.upper()}={value:g} mm lies outside the printer's "
                        f"travel 0..{travel[axis]:g} mm (check the sensor's mount offsets)"
                    )


def plan_to_printer(
    sensor: Mapping, x_mm: float, y_mm: float, depth_mm: float
) -> tuple[float, float, float]:
    """Plan-relative (x, y, depth) → absolute printer (X, Y, Z) from the sensor's mount offsets."""
    mount = sensor["mount"]
    return (
        mount["x_offset_mm"] + float(x_mm),
        mount["y_offset_mm"] + float(y_mm),
        mount["z_touch_mm"] - float(depth_mm),
    )


def clearance_z(sensor: Mapping) -> float:
    mount = sensor["mount"]
    return mount["z_touch_mm"] + mount["z_clearance_mm"]


def check_plan_size(points: float, frames: float, what: str = "the plan") -> None:
    """Refuse a plan over MAX_PLAN_POINTS points or MAX_PLAN_FRAMES frames, saying how many it has."""
    if points > MAX_PLAN_POINTS or frames > MAX_PLAN_FRAMES:
        raise ConfigError(
            f"{what} would have {int(points):,} probe points and {int(frames):,} frames (limits: "
            f"{MAX_PLAN_POINTS:,} points, {MAX_PLAN_FRAMES:,} frames); use a larger spacing_mm or "
            "fewer frames"
        )


def plan_from_config(plan_config: Mapping, sensor: Mapping) -> pd.DataFrame:
    """The plan a scene's `plan:` section describes (CSV, grid or cross)."""
    if plan_config.get("csv"):
        plan = read_plan_csv(plan_config["csv"])
        check_plan_size(len(plan), plan["frames"].sum(), str(plan_config["csv"]))
        return plan
    depths = plan_config.get("depths_mm") or [plan_config["depth_mm"]]
    spacing = float(plan_config["spacing_mm"])
    if spacing > 0 and np.isfinite(spacing):
        width, height = plan_area_mm(sensor)
        points = (width // spacing + 1) * (height // spacing + 1) * len(depths)
        check_plan_size(points, points * plan_config["frames"], f"spacing_mm={spacing:g}: the plan")
    if plan_config.get("pattern", "grid") == "cross":
        return cross_plan(
            sensor,
            spacing_mm=plan_config["spacing_mm"],
            depths_mm=depths,
            frames=plan_config["frames"],
            arm_width_mm=plan_config.get("arm_width_mm", 6.0),
        )
    return grid_plan(
        sensor, spacing_mm=plan_config["spacing_mm"], depths_mm=depths, frames=plan_config["frames"]
    )
