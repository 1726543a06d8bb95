"""One scene's collection, end to end: profiles → plan → validation → bench or hardware → store.

Used by the `collect` rule and by `threedcal collect`. Everything that can be wrong with the input is
checked before the printer is opened. The store is filled in a staging path and moved into place
only when complete, so a failed run never deletes what it captured: the next run resumes.
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from threedcal.collect.plan import plan_from_config, validate_plan
from threedcal.collect.run import MotionSettings, RunResult, collect
from threedcal.collect.store import IMAGE_LAYOUT, RawStore, frame_offsets, readings_layout
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile


@dataclass
class ScenePlan:
    sensor: dict
    printer: dict
    plan: pd.DataFrame
    settings: MotionSettings


def prepare(scene: Mapping, source: str = "scene") -> ScenePlan:
    """Load the profiles and the plan and validate all of it; nothing moves yet."""
    sensor = load_profile("sensor", scene["sensor"])
    printer = load_profile("printer", scene["printer"])
    plan = plan_from_config(scene["plan"], sensor)
    plan_source = scene["plan"].get("csv") or f"{source} grid plan"
    validate_plan(plan, sensor, printer, source=str(plan_source))
    if scene["port"] != "sim" and str(scene.get("camera", "sim")) == "sim":
        device = (
            "set the scene's `camera` to the ReSkin board's serial device (e.g. /dev/ttyACM0)"
            if is_magnetic(sensor)
            else "give the sensor's video device (index or /dev/v4l/by-id path)"
        )
        raise ConfigError(
            f"{source}: port {scene['port']!r} is a real printer but camera is 'sim': {device}, "
            "or use port: sim"
        )
    return ScenePlan(sensor, printer, plan, MotionSettings.from_profile(sensor))


class _BenchClock:
    def __init__(self, firmware):
        self.firmware = firmware

    def now(self) -> float:
        return self.firmware.clock.now()

    def sleep(self, seconds: float) -> None:
        self.firmware.clock.advance(seconds)


def _store_attrs(name: str, scene: Mapping, prepared: ScenePlan) -> dict[str, Any]:
    from threedcal.scenes import package_versions

    return {
        "scene": name,
        "config": dict(scene),
        "sensor_profile": prepared.sensor,
        "printer_profile": prepared.printer,
        "plan": prepared.plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_dict("list"),
        "seed": scene["seed"],
        "software": package_versions(),
    }


def collect_scene(
    name: str,
    scene: Mapping,
    store_path: str | Path,
    *,
    staging_path: str | Path | None = None,
    truth_path: str | Path | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Collect (or resume) a scene into `store_path`; returns the summary."""
    prepared = prepare(scene, source=f"scenes.{name}")
    store_path = Path(store_path)
    staging = Path(staging_path) if staging_path else store_path
    if store_path.exists() and staging != store_path:
        raise ConfigError(f"{store_path}: already exists; refusing to overwrite collected data")
    shape, layout = _sample_layout(prepared)
    if staging.exists():
        store = RawStore.open_for_resume(staging, prepared.plan)
    else:
        staging.parent.mkdir(parents=True, exist_ok=True)
        store = RawStore.create(
            staging,
            prepared.plan,
            shape,
            prepared.settings.n_blank,
            _store_attrs(name, scene, prepared),
            layout,
        )
    runs = list(store.group.attrs.get("runs", []))
    if scene["port"] == "sim":
        result, truth = _collect_simulated(scene, prepared, store, progress)
        if truth_path is not None:
            truth.write(truth_path)
    else:
        result = _collect_hardware(scene, prepared, store, progress)
    runs.append(
        {
            "points": result.points,
            "frames": result.frames,
            "duration_s": result.duration_s,
            "hardware_s": result.hardware_s,
            "resumed_at": result.resumed_at,
        }
    )
    store.group.attrs["runs"] = runs
    summary = _summary(store, runs)
    store.finalize({"summary": summary})
    if staging != store_path:
        shutil.move(str(staging), str(store_path))
    summary["store"] = str(store_path)
    return summary


def is_magnetic(sensor: Mapping) -> bool:
    """Magnetic sensors (ReSkin) stream readings over serial instead of camera frames."""
    return sensor.get("type") == "magnetic"


def _sample_layout(prepared: ScenePlan):
    """Shape of one sample and how the store keeps it: an RGB frame, or a ReSkin reading."""
    if is_magnetic(prepared.sensor):
        from threedcal.hardware.reskin import value_names

        names = value_names(prepared.sensor)
        return (len(names),), readings_layout(names, prepared.plan)
    image = prepared.sensor["image"]
    return (image["height_px"], image["width_px"], 3), IMAGE_LAYOUT


def _collect_simulated(scene, prepared: ScenePlan, store: RawStore, progress: bool):
    """The simulated bench: fake printer and simulated sensor — the gel camera, or the ReSkin board
    behind its own serial URL — coupled through the head pose."""
    from threedcal.hardware.printer import MarlinHost

    if is_magnetic(prepared.sensor):
        from threedcal.sim.reskin import ReSkinBench as Bench
    else:
        from threedcal.sim.bench import SimBench as Bench
    bench_settings = scene["bench"]
    with contextlib.ExitStack() as stack:
        bench = stack.enter_context(
            Bench(
                prepared.sensor,
                scene["probe"]["radius_mm"],
                bench_settings,
                scene["seed"],
                printer=prepared.printer,
                faults=bench_settings.get("faults", ""),
                fault_rate=bench_settings.get("fault_rate", 0.0),
            )
        )
        host = stack.enter_context(MarlinHost(bench.url, prepared.printer))
        if is_magnetic(prepared.sensor):
            from threedcal.hardware.reskin import ReSkinReader

            source = stack.enter_context(ReSkinReader(prepared.sensor, bench.sensor_url))
        else:
            source = bench.camera
        result = collect(
            store,
            prepared.sensor,
            host,
            source,
            prepared.settings,
            hardware_clock=bench.firmware.clock.now,
            clock=_BenchClock(bench.firmware),
            progress=progress,
        )
        return result, bench.truth


def _collect_hardware(scene, prepared: ScenePlan, store: RawStore, progress: bool) -> RunResult:
    from threedcal.hardware.camera import OpenCVCamera
    from threedcal.hardware.printer import MarlinHost

    device = scene["camera"]
    if isinstance(device, str) and device.isdigit():
        device = int(device)

    def attach_probe() -> None:
        input("Attach the probe to the print head, then press Enter to start probing... ")

    if is_magnetic(prepared.sensor):
        from threedcal.hardware.reskin import ReSkinReader

        reader = ReSkinReader(prepared.sensor, str(scene["camera"]))
    else:
        reader = OpenCVCamera(prepared.sensor, device)
    with reader, MarlinHost(scene["port"], prepared.printer) as host:
        return collect(
            store,
            prepared.sensor,
            host,
            reader,
            prepared.settings,
            attach_probe=attach_probe,
            progress=progress,
        )


def _summary(store: RawStore, runs: list[dict]) -> dict[str, Any]:
    duration = sum(r["duration_s"] for r in runs)
    frames = sum(r["frames"] for r in runs)
    return {
        "points": len(store.plan),
        "frames": int(store.offsets[-1]),
        "duration_s": round(duration, 3),
        "frames_per_s": round(frames / duration, 2) if duration > 0 else None,
        "estimated_hardware_s": round(sum(r["hardware_s"] for r in runs), 1),
        "runs": len(runs),
    }


class _EstimateSink:
    """Stands in for the store when only the printer's time is wanted: nothing is kept."""

    def __init__(self, plan: pd.DataFrame):
        self.plan = plan
        self.offsets = frame_offsets(plan)
        self._blank = False

    def first_uncaptured(self) -> int:
        return 0

    def has_blank(self) -> bool:
        return self._blank

    def write_blank(self, frames) -> None:
        self._blank = True

    def write_point(self, point, record) -> None:
        pass


class _ClockOnlyCamera:
    """Takes samples at the sensor's rate without rendering them."""

    def __init__(self, clock, fps: float):
        self.clock, self.fps = clock, fps

    def flush(self) -> None:
        pass

    def capture(self, count: int):
        stamps = []
        for _ in range(count):
            self.clock.advance(1.0 / self.fps)
            stamps.append(self.clock.now())
        return np.zeros((count, 1, 1, 3), np.uint8), np.asarray(stamps)


def estimate_hardware_s(
    sensor: Mapping, printer: Mapping, plan: pd.DataFrame, progress: bool = False
) -> float:
    """Seconds the real printer needs for `plan`: the same loop, driven against the fake firmware's
    motion model (homing, trapezoidal moves, M400 waits, settling, capture at the camera's rate)."""
    from threedcal.hardware.printer import MarlinHost
    from threedcal.sim.marlin import SimMarlin, forget, register

    firmware = SimMarlin(printer, speedup=math.inf)
    name = f"estimate-{id(firmware)}"
    register(name, firmware)
    try:
        with MarlinHost(f"simmarlin://{name}", printer) as host:
            result = collect(
                _EstimateSink(plan),
                sensor,
                host,
                _ClockOnlyCamera(firmware.clock, _sample_rate_hz(sensor)),
                MotionSettings.from_profile(sensor),
                hardware_clock=firmware.clock.now,
                clock=_BenchClock(firmware),
                progress=progress,
            )
    finally:
        forget(name)
    return result.hardware_s


def _sample_rate_hz(sensor: Mapping) -> float:
    if is_magnetic(sensor):
        return float(sensor["serial"]["rate_hz"])
    return float(sensor["camera"]["default_fps"])


def write_summary(summary: Mapping, path: str | Path) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(dict(summary), indent=2, sort_keys=True) + "\n")


def collect_stage(
    name: str,
    scene: Mapping,
    *,
    store: str | Path,
    staging: str | Path,
    summary: str | Path,
    coverage: str | Path,
    mosaic: str | Path,
    truth: str | Path,
    progress: bool = True,
) -> dict[str, Any]:
    """The `collect` rule: store, summary.json, coverage and sample-frame figures, bench truth.

    For a magnetic sensor `mosaic` receives a figure of sample readings instead of frames."""
    from threedcal.collect.figures import coverage_figure, mosaic_figure
    from threedcal.collect.store import open_raw

    prepared = prepare(scene, source=f"scenes.{name}")
    result = collect_scene(
        name, scene, store, staging_path=staging, truth_path=truth, progress=progress
    )
    if scene["port"] != "sim":
        Path(truth).write_text(json.dumps({"simulated": False}) + "\n")
    write_summary(result, summary)
    coverage_figure(
        prepared.plan, prepared.sensor, coverage, title=f"{name}: {len(prepared.plan)} probe points"
    )
    if is_magnetic(prepared.sensor):
        from threedcal.reskin.figures import readings_figure

        readings_figure(open_raw(store), prepared.sensor, mosaic, title=f"{name}: sample readings")
    else:
        mosaic_figure(open_raw(store), mosaic, title=f"{name}: sample frames")
    return result
