"""The collection run: home, blank frames, then for every plan point lift → travel → press → wait →
settle → flush → capture → label → store. Crash-safe: every point is committed to the store before
the next starts, and a rerun resumes at the first point not captured.

Timing is synchronised, not guessed: a press is captured only after Marlin reports the queued moves
done (M400), and the travel to the next point is queued right after the capture, so the printer
moves while the store writes. The path is short: the probe lifts only to the clearance height above
the gel and rows are serpentine-ordered.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.collect.plan import clearance_z, dome_sag_mm, plan_area_mm, plan_to_printer
from threedcal.collect.store import PointRecord, RawStore


class FrameSource(Protocol):
    """What the run needs of a camera (threedcal.hardware.camera or the simulated bench)."""

    def flush(self) -> None: ...

    def capture(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """`count` fresh frames (count, H, W, 3) uint8 RGB and their time stamps (s)."""
        ...


class Clock(Protocol):
    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


@dataclass(frozen=True)
class MotionSettings:
    """Feeds and waits of a probing run (from the sensor profile's `probing` section)."""

    travel_feed_mm_s: float = 50.0
    plunge_feed_mm_s: float = 5.0
    settle_s: float = 0.3
    n_blank: int = 10
    hop_mm: float = 0.5  # lift above the higher gel surface of two neighbouring points

    @classmethod
    def from_profile(cls, sensor: Mapping) -> MotionSettings:
        probing = sensor.get("probing", {})
        return cls(**{k: probing[k] for k in cls.__dataclass_fields__ if k in probing})


@dataclass
class RunResult:
    points: int  # captured in this run (a resumed run counts only its own)
    frames: int
    duration_s: float  # wall time of this run
    hardware_s: float  # printer clock elapsed (the motion model's on the simulated bench)
    resumed_at: int


def collect(
    store: RawStore,
    sensor: Mapping,
    printer,  # threedcal.hardware.printer.MarlinHost (or anything with its motion methods)
    camera: FrameSource,
    settings: MotionSettings,
    *,
    hardware_clock: Callable[[], float] | None = None,
    clock: Clock | None = None,
    attach_probe: Callable[[], None] | None = None,
    progress: bool = True,
) -> RunResult:
    clock = clock or WallClock()
    hardware_clock = hardware_clock or clock.now
    plan: pd.DataFrame = store.plan
    start = store.first_uncaptured()
    started_wall, started_clock, started_hw = time.monotonic(), clock.now(), hardware_clock()
    if start is None:
        return RunResult(0, 0, 0.0, 0.0, len(plan))
    safe_z = clearance_z(sensor)
    printer.home()
    printer.hold_motors()
    if attach_probe is not None:
        attach_probe()
    if not store.has_blank():
        cx, cy = (v / 2 for v in plan_area_mm(sensor))
        x, y, _ = plan_to_printer(sensor, cx, cy, 0.0)
        printer.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
        printer.move_to(x=x, y=y, feed_mm_s=settings.travel_feed_mm_s)
        printer.wait_until_idle()
        clock.sleep(settings.settle_s)
        camera.flush()
        blank, _ = camera.capture(settings.n_blank)
        store.write_blank(blank)
    frames_done = 0
    offsets = store.offsets
    bar = tqdm(
        total=len(plan),
        initial=start,
        desc="collect",
        unit="pt",
        disable=not progress,
        dynamic_ncols=True,
    )
    # Hop height between two points: `hop_mm` above the higher of their gel surfaces (a domed gel
    # sits lower away from its apex), never above the clearance height.
    surface_z = sensor["mount"]["z_touch_mm"] - dome_sag_mm(sensor, plan["x_mm"], plan["y_mm"])
    try:
        for point in range(start, len(plan)):
            row = plan.iloc[point]
            target = plan_to_printer(sensor, row.x_mm, row.y_mm, row.depth_mm)
            previous = surface_z[point - 1] if point > start else np.inf
            hop_z = min(safe_z, max(previous, surface_z[point]) + settings.hop_mm)
            printer.move_to(z=hop_z, feed_mm_s=settings.plunge_feed_mm_s)
            printer.move_to(x=target[0], y=target[1], feed_mm_s=settings.travel_feed_mm_s)
            printer.move_to(z=target[2], feed_mm_s=settings.plunge_feed_mm_s)
            printer.wait_until_idle()
            clock.sleep(settings.settle_s)
            reported = tuple(printer.position())
            camera.flush()
            count = int(offsets[point + 1] - offsets[point])
            frames, stamps = camera.capture(count)
            hw_now = hardware_clock() - started_hw
            lift_to = surface_z[point + 1] if point + 1 < len(plan) else np.inf
            lift_z = min(safe_z, max(surface_z[point], lift_to) + settings.hop_mm)
            printer.move_to(z=lift_z, feed_mm_s=settings.plunge_feed_mm_s)  # lift while we store
            store.write_point(
                point,
                PointRecord(
                    frames=frames,
                    cmd_xyz=target,
                    reported_xyz=reported,
                    t_s=np.asarray(stamps, dtype=float) - started_clock,
                    hardware_s=np.full(count, hw_now),
                ),
            )
            frames_done += count
            bar.update(1)
        printer.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
        printer.wait_until_idle()
    finally:
        bar.close()
    return RunResult(
        points=len(plan) - start,
        frames=frames_done,
        duration_s=time.monotonic() - started_wall,
        hardware_s=hardware_clock() - started_hw,
        resumed_at=start,
    )


def summary(store: RawStore, runs: list[RunResult], estimated_hardware_s: float) -> dict[str, Any]:
    """results/{scene}/collect/summary.json content (the results layout in the README)."""
    frames = int(store.offsets[-1])
    duration = sum(r.duration_s for r in runs)
    return {
        "points": len(store.plan),
        "frames": frames,
        "duration_s": round(duration, 3),
        "frames_per_s": round(sum(r.frames for r in runs) / duration, 3) if duration > 0 else None,
        "estimated_hardware_s": round(estimated_hardware_s, 1),
        "resumed_at": [r.resumed_at for r in runs],
        "store": str(Path(store.path)),
    }
