"""Probe plans: where to press, how deep, how many frames — read, generated, ordered and validated.

A plan is a table in *plan-relative* millimetres (origin at the sensor's plan origin, printer axes):
``x_mm, y_mm, depth_mm, frames``. ``depth_mm`` is how far below the first-touch height of the gel's
apex the probe is commanded; on a domed gel the surface away from the apex sits lower, so a grid
with dome compensation commands ``depth + sag(x, y)`` to keep the penetration even — the rule the
authors' DIGIT plan follows. py3DCal plan CSVs (``x, y, depth, frames`` with a ``#`` header) load as is.

A scene's plan (threedcal.collect.scene_plan) also has a ``phase`` column: ``touch`` rows come first
— a first-contact search that steps the probe down through the nominal touch height at a few places,
one row per step, from which the dataset stage measures where the gel really is — then the
``register`` rows — shallow presses over the whole probe area, whose small contacts lie whole in the
frame nearer its edges than the grid's, from which the dataset stage fits the camera's registration
— then the ``grid`` rows (grid, cross, CSV, or a quick plan's rounds) that the model trains on.
Touch rows may sit above the gel (negative depth); the collection loop and store carry them like any
other row.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError

PLAN_COLUMNS = ("x_mm", "y_mm", "depth_mm", "frames")
DEPTH_MODES = ("every", "cycle")
# The sensor schema's default of `probing.touch_uncertainty_mm`.
DEFAULT_TOUCH_UNCERTAINTY_MM = 0.2
# Size limits, checked before a plan is generated: the paper's densest plan has ~1,400 points and
# ~40,000 frames; a mistyped spacing must not allocate gigabytes or queue months of printer time.
MAX_PLAN_POINTS = 100_000
MAX_PLAN_FRAMES = 1_000_000
# Fewest presses a place of a bisecting touch search takes: the deepest, one halving and two past
# the onset to fit its growth (threedcal.dataset.touch.TouchBisection).
TOUCH_BISECTION_MIN_PRESSES = 4


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


def dome_sag_at_px(sensor: Mapping, col, row) -> np.ndarray:
    """How far the gel surface at image pixel (col, row) lies below its apex (the profile's
    `gel.dome`, in image axes about the image centre at the profile's px/mm; 0 for a flat gel).

    Where the registration has placed a press, this is its sag — the plan's `dome_sag_mm` assumes
    the sensor sits exactly where its base puts it nominally."""
    dome = sensor.get("gel", {}).get("dome")
    col = np.asarray(col, dtype=float)
    row = np.asarray(row, dtype=float)
    if not dome:
        return np.zeros(np.broadcast(col, row).shape)
    scale = float(sensor["px_per_mm"])
    u = (col - (sensor["image"]["width_px"] - 1) / 2) / scale - dome.get("apex_x_mm", 0.0)
    v = (row - (sensor["image"]["height_px"] - 1) / 2) / scale - dome.get("apex_y_mm", 0.0)
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
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (a plan CSV expected)") from None
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
        if not np.isfinite(values[3]) or values[3] != int(values[3]) or values[3] < 1:
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
    depth_mode: str = "every",
) -> pd.DataFrame:
    """A regular grid over the sensor's probe area (profile `probing.plan_area_mm`), serpentine ordered.

    With several depths and `depth_mode` "every", each point is pressed at every one in the order
    listed before the gantry moves on: a model trained on one depth learns that depth's contact
    size as a shape prior and misjudges shallower or deeper objects. "cycle" presses each point
    once, at the depth `_cycled` gives it: all depths over the whole area for the frames of one."""
    depths = _depths(depths_mm)
    if spacing_mm <= 0 or not np.isfinite(spacing_mm):
        raise ConfigError(f"plan spacing_mm must be a positive number, got {float(spacing_mm)}")
    width, height = plan_area_mm(sensor)
    xs = np.arange(0.0, width + 1e-9, spacing_mm)
    ys = np.arange(0.0, height + 1e-9, spacing_mm)
    gx, gy = np.meshgrid(xs, ys)
    if _depth_mode(depth_mode) == "cycle":
        x, y = gx.ravel(), gy.ravel()
        depth = _cycled(depths, *np.indices(gx.shape)[::-1]).ravel()
    else:
        x, y = np.repeat(gx.ravel(), len(depths)), np.repeat(gy.ravel(), len(depths))
        depth = np.tile(depths, gx.size)
    if dome_compensation:
        depth = depth + dome_sag_mm(sensor, x, y)
    plan = pd.DataFrame(
        {"x_mm": x, "y_mm": y, "depth_mm": np.round(depth, 4), "frames": int(frames)}
    )
    return serpentine(plan)  # stable: a point's depths keep their order


def _depth_mode(mode: str) -> str:
    if mode not in DEPTH_MODES:
        raise ConfigError(
            f"plan depth_mode {mode!r} is not allowed (allowed: {', '.join(DEPTH_MODES)})"
        )
    return mode


def _cycled(depths: np.ndarray, column: np.ndarray, row: np.ndarray) -> np.ndarray:
    """The depth of grid point (column, row) when each point gets one: depths[(column + row) mod n].

    Every depth then forms a diagonal lattice over the whole area, so any subset of coordinates
    (the training fractions) holds every depth in nearly equal shares."""
    return depths[(np.asarray(column) + np.asarray(row)) % len(depths)]


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
    depth_mode: str = "every",
) -> pd.DataFrame:
    """The authors' ReSkin plan shape: a grid over the probe area, kept where it lies within
    `arm_width_mm`/2 of the area's centre lines (a plus sign), repeated at every depth in turn, each
    pass serpentine ordered. 1 mm spacing, arms 6 mm wide over 16 x 16 mm give 189 points a depth.
    `depth_mode` "cycle" makes one pass, each point at one depth (as in `grid_plan`)."""
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
    if _depth_mode(depth_mode) == "cycle":
        column, row = np.indices(gx.shape)[::-1]
        passes = [_cycled(depths, column[keep], row[keep])]
    else:
        passes = [np.full(x.shape, depth) for depth in depths]
    sag = dome_sag_mm(sensor, x, y)
    return pd.concat(
        [
            serpentine(
                pd.DataFrame(
                    {
                        "x_mm": x,
                        "y_mm": y,
                        "depth_mm": np.round(depth + sag, 4),
                        "frames": int(frames),
                    }
                )
            )
            for depth in passes
        ],
        ignore_index=True,
    )


# A contact is located only when its rim lies this far inside the frame (the registration's
# `whole` test, threedcal.dataset.build.register_store).
WHOLE_CONTACT_MARGIN_PX = 5


def camera_view_mm(sensor: Mapping) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) plan mm the camera sees with the sensor seated as its base puts it: the
    image (profile `image`, `px_per_mm`) centred on the plan area, printer X along its columns."""
    width, height = plan_area_mm(sensor)
    scale = float(sensor["px_per_mm"])
    half_x = sensor["image"]["width_px"] / scale / 2
    half_y = sensor["image"]["height_px"] / scale / 2
    return (width / 2 - half_x, height / 2 - half_y, width / 2 + half_x, height / 2 + half_y)


def touch_uncertainty_mm(sensor: Mapping) -> float:
    """How far the gel's true first touch may lie from the profile's nominal `mount.z_touch_mm`."""
    return float(sensor["probing"].get("touch_uncertainty_mm", DEFAULT_TOUCH_UNCERTAINTY_MM))


def touch_search_depths(sensor: Mapping, search: Mapping) -> np.ndarray:
    """Commanded depths (below the nominal touch) of one place's search, shallowest first: from
    `touch_uncertainty_mm` above the nominal surface to `beyond_mm` past that much below it."""
    uncertainty = touch_uncertainty_mm(sensor)
    step, beyond = float(search["step_mm"]), float(search["beyond_mm"])
    if not (np.isfinite(step) and step > 0 and np.isfinite(beyond) and beyond > 0):
        raise ConfigError(
            f"plan.touch_search: step_mm and beyond_mm must be positive, got {step!r}, {beyond!r}"
        )
    count = int(np.floor((2 * uncertainty + beyond) / step + 1e-9)) + 1
    return np.round(-uncertainty + step * np.arange(count), 6)


def touch_search_range(sensor: Mapping, search: Mapping) -> tuple[float, float]:
    """The commanded depths (below the nominal touch) a place's search may press between:
    `touch_uncertainty_mm` above the nominal surface to `beyond_mm` past that much below it."""
    depths = touch_search_depths(sensor, {**search, "step_mm": search.get("step_mm", 0.02)})
    return float(depths[0]), float(touch_uncertainty_mm(sensor) + float(search["beyond_mm"]))


def touch_search_plan(sensor: Mapping, search: Mapping) -> pd.DataFrame:
    """The first-contact search rows (phase "touch"): `points` places on a circle of `spread_mm`
    about the probe area's centre (one place: the centre), `frames` frames a row. `method` steps:
    each place stepped down through the nominal touch height in `step_mm` steps
    (`touch_search_depths`). `method` bisect: `presses` rows a place, whose depths the collection
    decides press by press (threedcal.dataset.touch.TouchBisection) within `touch_search_range`;
    the plan holds the deepest, which no press passes.

    Near the centre: on a domed gel the apex sits there, where a seating error changes the sag
    least. Each step is its own press (the probe lifts between rows), approached from above."""
    points = int(search.get("points", 0))
    columns = [*PLAN_COLUMNS, "phase"]
    if points <= 0:
        return pd.DataFrame({c: [] for c in columns}).astype({"frames": int})
    width, height = plan_area_mm(sensor)
    spread = float(search["spread_mm"])
    angles = 2 * np.pi * np.arange(points) / points
    cx = width / 2 + (spread * np.cos(angles) if points > 1 else np.zeros(1))
    cy = height / 2 + (spread * np.sin(angles) if points > 1 else np.zeros(1))
    if search.get("method", "steps") == "bisect":
        low, high = touch_search_range(sensor, search)
        if int(search["presses"]) < TOUCH_BISECTION_MIN_PRESSES:
            raise ConfigError(
                f"plan.touch_search.presses: {search['presses']} (a bisecting search needs >= "
                f"{TOUCH_BISECTION_MIN_PRESSES}: the deepest, one halving, two past the onset)"
            )
        if low <= -float(sensor["mount"]["z_clearance_mm"]):
            raise ConfigError(
                f"plan.touch_search: its shallowest press ({low:g} mm) lies at or above the "
                f"clearance height ({sensor['mount']['z_clearance_mm']:g} mm over the touch): "
                "lower probing.touch_uncertainty_mm"
            )
        steps = np.full(int(search["presses"]), high)
    else:
        steps = touch_search_depths(sensor, search)
    x = np.repeat(np.round(cx, 6), len(steps))
    y = np.repeat(np.round(cy, 6), len(steps))
    depth = np.tile(steps, points) + dome_sag_mm(sensor, x, y)
    return pd.DataFrame(
        {
            "x_mm": x,
            "y_mm": y,
            "depth_mm": np.round(depth, 6),
            "frames": int(search["frames"]),
            "phase": "touch",
        }
    )[columns]


def registration_plan(sensor: Mapping, presses: Mapping) -> pd.DataFrame:
    """The registration presses (phase "register"): a grid of `spacing_mm` over the probe area,
    each point pressed `depth_mm` deep (dome compensated) for `frames` frames; none when
    `spacing_mm` is 0.

    Shallow, so that a contact is small: the locators only take contacts that lie whole in the
    frame, and the grid's 1-3 mm presses (radius up to R) leave a band along every edge where
    the lens fit extrapolates (docs/explanation/registration.md, Registration presses). One depth, so that
    every contact carries the locator's bias at that depth alike."""
    columns = [*PLAN_COLUMNS, "phase"]
    spacing = float(presses.get("spacing_mm", 0.0))
    if spacing == 0:
        return pd.DataFrame({c: [] for c in columns}).astype({"frames": int})
    if spacing > 0 and np.isfinite(spacing):
        width, height = plan_area_mm(sensor)
        points = (width // spacing + 1) * (height // spacing + 1)
        check_plan_size(
            points, points * int(presses["frames"]), f"plan.registration spacing_mm={spacing:g}"
        )
    rows = grid_plan(sensor, spacing, [float(presses["depth_mm"])], int(presses["frames"]))
    return rows.assign(phase="register")[columns]


def serpentine(plan: pd.DataFrame, row_tolerance_mm: float = 1e-6) -> pd.DataFrame:
    """Order by rows of equal y; alternate the x direction each row, so travel between points is short."""
    plan = plan.copy()
    row = np.round(plan["y_mm"].to_numpy() / max(row_tolerance_mm, 1e-12)).astype(np.int64)
    rank = pd.Series(row).rank(method="dense").astype(int).to_numpy() - 1
    key = np.where(rank % 2 == 0, plan["x_mm"], -plan["x_mm"])
    order = np.lexsort((key, rank))
    return plan.iloc[order].reset_index(drop=True)


def _describe_row(plan: pd.DataFrame, i: int, source: str) -> str:
    if _phase(plan, i) == "touch":
        return f"{source}, touch search row {i}"
    if _phase(plan, i) == "register":
        return f"{source}, registration press row {i}"
    if "line" in plan and pd.notna(plan["line"].iloc[i]):
        return f"{source}, line {int(plan['line'].iloc[i])}"
    return f"{source}, point {i}"


def _phase(plan: pd.DataFrame, i: int) -> str:
    return str(plan["phase"].iloc[i]) if "phase" in plan else "grid"


class _RowName:
    """A plan row's name in an error message, looked up only when a message is formatted."""

    def __init__(self, plan: pd.DataFrame, i: int, source: str) -> None:
        self.plan, self.i, self.source = plan, i, source

    def __str__(self) -> str:
        return _describe_row(self.plan, self.i, self.source)


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
    # The columns are read once and a row is described only when it fails: every Snakemake parse
    # validates the plan, and a pandas lookup per cell is slow on a study's thousands of rows.
    columns = [plan[c].to_numpy() for c in PLAN_COLUMNS]
    phases = plan["phase"].astype(str).to_numpy() if "phase" in plan else None
    for i in range(len(plan)):
        x, y, depth, frames = (column[i] for column in columns)
        where = _RowName(plan, i, source)
        if not all(np.isfinite([x, y, depth, frames])):
            raise ConfigError(
                f"{where}: x, y, depth and frames must be finite numbers (got {x}, {y}, {depth}, {frames})"
            )
        penetration = depth - float(dome_sag_mm(sensor, x, y))
        # a search step may sit above the gel, never above clearance
        if phases is not None and phases[i] == "touch":
            if depth <= -float(sensor["mount"]["z_clearance_mm"]):
                raise ConfigError(
                    f"{where}: depth {depth:g} mm lies at or above the clearance height "
                    f"({sensor['mount']['z_clearance_mm']:g} mm over the touch): lower "
                    "probing.touch_uncertainty_mm"
                )
        elif depth < 0:
            raise ConfigError(f"{where}: depth {depth:g} mm is negative (above the gel)")
        if penetration > max_depth + margin:
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


def whole_contacts(sensor: Mapping, rows: pd.DataFrame, probe_radius_mm: float) -> int:
    """How many of the presses `rows` (plan mm, depth below the touch) leave a contact whole in
    the frame, the sensor seated as its base puts it and the ball's contact radius that of a rigid
    gel: what the registration will locate, and so whether its lens fit can be made (a gel that
    yields widens a contact, a seating error moves it, so the count is an estimate)."""
    if rows.empty:
        return 0
    vx0, vy0, _, _ = camera_view_mm(sensor)
    scale = float(sensor["px_per_mm"])
    sag = dome_sag_mm(sensor, rows["x_mm"].to_numpy(float), rows["y_mm"].to_numpy(float))
    depth = np.clip(rows["depth_mm"].to_numpy(float) - sag, 0.0, probe_radius_mm)
    reach = np.sqrt(2 * probe_radius_mm * depth - depth**2) * scale + WHOLE_CONTACT_MARGIN_PX
    x = (rows["x_mm"].to_numpy(float) - vx0) * scale
    y = (rows["y_mm"].to_numpy(float) - vy0) * scale
    width, height = sensor["image"]["width_px"], sensor["image"]["height_px"]
    whole = (x >= reach) & (x <= width - 1 - reach) & (y >= reach) & (y <= height - 1 - reach)
    return int(whole.sum())
