"""The plan a scene's `plan:` section describes, phase by phase (touch search, registration
presses, then the grid, cross, CSV or quick rows), and the phases of a collected plan checked
against it."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from threedcal.collect.plan import (
    PLAN_COLUMNS,
    check_plan_size,
    cross_plan,
    grid_plan,
    plan_area_mm,
    read_plan_csv,
    registration_plan,
    touch_search_plan,
)
from threedcal.collect.quick_plan import pauses_to_register, quick_area_mm, quick_plan
from threedcal.errors import ConfigError


def plan_from_config(plan_config: Mapping, sensor: Mapping, run: int = 1) -> pd.DataFrame:
    """The plan a scene's `plan:` section describes: the touch search (vision sensors, when
    `touch_search.points` > 0), the registration presses (vision sensors, when
    `registration.spacing_mm` > 0), then the grid rows (CSV, grid or cross); column `phase`
    tells them apart."""
    if plan_config.get("csv"):
        rows = read_plan_csv(plan_config["csv"])
        check_plan_size(len(rows), rows["frames"].sum(), str(plan_config["csv"]))
    elif plan_config.get("pattern") == "quick":
        rows = quick_plan(sensor, plan_config, run)
    else:
        depths = plan_config.get("depths_mm") or [plan_config["depth_mm"]]
        mode = plan_config.get("depth_mode", "every")
        spacing = float(plan_config["spacing_mm"])
        if spacing > 0 and np.isfinite(spacing):
            width, height = plan_area_mm(sensor)
            points = (width // spacing + 1) * (height // spacing + 1)
            points *= len(depths) if mode == "every" else 1
            check_plan_size(
                points, points * plan_config["frames"], f"spacing_mm={spacing:g}: the plan"
            )
        if plan_config.get("pattern", "grid") == "cross":
            rows = cross_plan(
                sensor,
                spacing_mm=plan_config["spacing_mm"],
                depths_mm=depths,
                frames=plan_config["frames"],
                arm_width_mm=plan_config.get("arm_width_mm", 6.0),
                depth_mode=mode,
            )
        else:
            rows = grid_plan(
                sensor,
                spacing_mm=plan_config["spacing_mm"],
                depths_mm=depths,
                frames=plan_config["frames"],
                depth_mode=mode,
            )
            rows = _inside_area(rows, plan_config, sensor)
    rows = rows if "phase" in rows else rows.assign(phase="grid")
    before = [p for p in _leading_phases(plan_config, sensor) if not p.empty]
    if not before:
        return rows
    return pd.concat([*before, rows], ignore_index=True)


def _leading_phases(plan_config: Mapping, sensor: Mapping) -> list[pd.DataFrame]:
    """The rows a scene's plan starts with, in order: the touch search, the registration presses."""
    return [touch_search_of(plan_config, sensor), registration_presses_of(plan_config, sensor)]


def touch_search_of(plan_config: Mapping, sensor: Mapping) -> pd.DataFrame:
    """The touch-search rows a scene's plan starts with (none for a magnetic sensor or 0 points)."""
    search = plan_config.get("touch_search") or {}
    if sensor.get("type") != "vision" or int(search.get("points", 0)) <= 0:
        return touch_search_plan(sensor, {"points": 0})
    return touch_search_plan(sensor, search)


def registration_presses_of(plan_config: Mapping, sensor: Mapping) -> pd.DataFrame:
    """The registration presses a scene's plan holds after its touch search (none for a magnetic
    sensor or spacing 0). A quick plan keeps only the lattice's presses inside its area: one
    farther out leaves no whole contact in the frame, so the registration never uses it, and a
    quick calibration is short of printer time, not of lattice."""
    presses = plan_config.get("registration") or {}
    if sensor.get("type") != "vision":
        return registration_plan(sensor, {"spacing_mm": 0})
    rows = registration_plan(sensor, presses)
    if plan_config.get("pattern") == "quick" and not rows.empty:
        x0, y0, x1, y1 = quick_area_mm(sensor, plan_config)
        inside = rows["x_mm"].between(x0 - 1e-9, x1 + 1e-9) & rows["y_mm"].between(
            y0 - 1e-9, y1 + 1e-9
        )
        return rows[inside].reset_index(drop=True)
    return _inside_area(rows, plan_config, sensor)


def _inside_area(rows: pd.DataFrame, plan_config: Mapping, sensor: Mapping) -> pd.DataFrame:
    """A grid plan's rows (or its registration lattice) where they lie inside `area_mm` (x0, y0,
    x1, y1 plan mm: the part of the probe area the camera sees, say), the lattice kept as the
    whole area's (its points and depths); all of them without `area_mm`."""
    if plan_config.get("area_mm") is None or plan_config.get("pattern", "grid") != "grid":
        return rows
    x0, y0, x1, y1 = (float(v) for v in plan_config["area_mm"])
    width, height = plan_area_mm(sensor)
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise ConfigError(
            f"plan.area_mm: {[x0, y0, x1, y1]} must be x0 < x1, y0 < y1 inside the probe area "
            f"(0..{width:g} x 0..{height:g} mm)"
        )
    tolerance = 1e-9
    inside = rows["x_mm"].between(x0 - tolerance, x1 + tolerance) & rows["y_mm"].between(
        y0 - tolerance, y1 + tolerance
    )
    return rows[inside].reset_index(drop=True)


def plan_phases(stored_plan: Mapping, plan_config: Mapping, sensor: Mapping) -> np.ndarray:
    """The phase of every row of a collected plan (a store's ``plan`` attribute: x_mm, y_mm,
    depth_mm, frames lists), checked against the touch search and registration presses its
    config describes."""
    n_rows = len(stored_plan["x_mm"])
    stored = np.column_stack([np.asarray(stored_plan[c], dtype=float) for c in PLAN_COLUMNS])
    phases: list[str] = []
    for rows, key in zip(
        _leading_phases(plan_config, sensor),
        ("plan.touch_search", "plan.registration"),
        strict=True,
    ):
        start, stop = len(phases), len(phases) + len(rows)
        expected = rows[list(PLAN_COLUMNS)].to_numpy(dtype=float)
        if stop > n_rows or not np.allclose(stored[start:stop], expected, atol=1e-6):
            raise ConfigError(
                f"the collected plan does not hold the rows its {key} describes ({len(rows)} "
                f"rows from row {start}): was the store collected with another config?"
            )
        phases += [str(p) for p in rows["phase"]]
    rest = n_rows - len(phases)
    if pauses_to_register(plan_config):  # each quick press: its pause, then its own depth
        return np.array(phases + ["register", "grid"] * (rest // 2) + ["register"] * (rest % 2))
    return np.array(phases + ["grid"] * rest)
