"""One scene's collection, end to end: profiles → plan → validation → bench or hardware → store.

Used by the `collect` rule and by `threedcal collect`. Everything that can be wrong with the input is
checked before the printer is opened. The store is filled in a staging path and moved into place
only when complete, so a failed run never deletes what it captured: the next run resumes.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import zarr

from threedcal.collect.figures import coverage_figure, mosaic_figure
from threedcal.collect.plan import touch_search_range, validate_plan
from threedcal.collect.run import MotionSettings, RunResult, collect
from threedcal.collect.scene_plan import plan_from_config
from threedcal.collect.store import (
    IMAGE_LAYOUT,
    RawStore,
    SettingsMismatch,
    StoreError,
    canonical_json,
    check_settings,
    frame_offsets,
    plan_digest,
    readings_layout,
    settings_digest,
    store_summary,
)
from threedcal.collect.store_read import open_raw
from threedcal.dataset.touch import planned_touch_search
from threedcal.errors import ConfigError
from threedcal.hardware.printer import MarlinHost
from threedcal.hardware.reskin import value_names
from threedcal.profiles import load_profile
from threedcal.reskin.figures import readings_figure
from threedcal.rig import (
    Ask,
    BenchClock,
    Rig,
    bench_sensor,
    check_devices,
    is_magnetic,
    open_rig,
)
from threedcal.sim.bench import draw_truth
from threedcal.sim.marlin import FIRMWARES, SimMarlin, parse_faults
from threedcal.sim.reskin import draw_reskin_truth
from threedcal.study.config import quick_run
from threedcal.study.paths import package_versions
from threedcal.study.scene import rig_settings, scene_sensor


@dataclass
class ScenePlan:
    sensor: dict
    printer: dict
    plan: pd.DataFrame
    settings: MotionSettings


def prepare(scene: Mapping, source: str = "scene") -> ScenePlan:
    """Load the profiles and the plan and validate all of it; nothing moves yet."""
    sensor = scene_sensor(scene, source)
    printer = load_profile("printer", scene["printer"])
    plan = plan_from_config(scene["plan"], sensor, quick_run(scene))
    plan_source = scene["plan"].get("csv") or f"{source} grid plan"
    validate_plan(plan, sensor, printer, source=str(plan_source))
    if scene["port"] == "sim":
        try:
            parse_faults(scene.get("bench", {}).get("faults", ""))
        except ConfigError as exc:
            raise ConfigError(f"{source}.bench.faults: {exc}") from None
    check_devices(rig_settings(scene), sensor, source)
    return ScenePlan(sensor, printer, plan, MotionSettings.from_profile(sensor))


def _store_attrs(name: str, scene: Mapping, prepared: ScenePlan) -> dict[str, Any]:
    return {
        "scene": name,
        "config": dict(scene),
        "sensor_profile": prepared.sensor,
        "printer_profile": prepared.printer,
        "plan": prepared.plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_dict("list"),
        "seed": scene["seed"],
        "software": package_versions(),
    }


def frame_settings(scene: Mapping, prepared: ScenePlan) -> dict[str, Any]:
    """Everything the collected frames depend on, canonical: the plan (its points, not how the
    config spells it), the probe, the full sensor and printer profiles and, on the simulated
    bench, the seed and the bench settings. Recorded in the store: a resume or a rerun with other
    settings is refused, naming the keys. Device names (port, camera path) are not included: they
    change when a cable moves, the frames do not."""
    plan = prepared.plan
    simulated = scene["port"] == "sim"
    settings: dict[str, Any] = {
        "plan": {
            "points": len(plan),
            "frames": int(plan["frames"].sum()),
            "digest": plan_digest(plan),
        },
        "probe": dict(scene["probe"]),
        "sensor": _profile_content(prepared.sensor),
        "printer": _profile_content(prepared.printer),
        "simulated": simulated,
    }
    if simulated:
        settings["seed"] = int(scene["seed"])
        settings["bench"] = dict(scene.get("bench", {}))
    return json.loads(canonical_json(settings))


# Profile keys no frame depends on: where the file was read from, words, and how the host talks to
# the printer and stops it. Changing them never blocks a resume or a rerun.
NOT_FRAME_SETTINGS = ("source", "description", "timeouts_s", "safe_stop")


def _profile_content(profile: Mapping) -> dict:
    """A profile's content that frames can depend on."""
    return {k: v for k, v in profile.items() if k not in NOT_FRAME_SETTINGS}


def _refuse_foreign(path: Path) -> None:
    """`path` may be absent or a collection store; anything else is never written into."""
    if not path.exists():
        return
    if not path.is_dir():
        raise ConfigError(
            f"{path}: exists and is a file, not a collection store; refusing to write there "
            "(choose another --out, or move the file away)"
        )
    if not (path / "zarr.json").is_file():
        raise ConfigError(
            f"{path}: exists and is not a collection store (no zarr.json); refusing to write into "
            "it (choose another --out, or move it away)"
        )


def collect_scene(
    name: str,
    scene: Mapping,
    store_path: str | Path,
    *,
    staging_path: str | Path | None = None,
    truth_path: str | Path | None = None,
    progress: bool = True,
    ask: Ask | None = None,
    rig: Rig | None = None,
    on_row=None,
) -> dict[str, Any]:
    """Collect (or resume, or find already collected) a scene's store at `store_path`; its summary.

    With `staging_path` the store is filled there and moved to `store_path` only when complete. A
    store at `store_path` is never touched: if its recorded settings are the config's, its summary
    is returned; if not, a SettingsMismatch names the keys that differ. A partial store is resumed
    only with the settings it was started with. `ask`: how a real rig asks its user to attach
    the probe (threedcal.rig). `rig`: one opened already (`threedcal rig` holds its printer);
    `on_row`: collect's watcher (threedcal.collect.run.collect).
    """
    source = f"scenes.{name}"
    prepared = prepare(scene, source=source)
    settings = frame_settings(scene, prepared)
    digest = settings_digest(settings)
    store_path = Path(store_path)
    staging = Path(staging_path) if staging_path else store_path
    simulated = scene["port"] == "sim"
    if staging != store_path and store_path.exists():
        summary = finished_store_summary(store_path, prepared.plan, settings)
        if staging.exists():
            logging.getLogger("threedcal").warning(
                "%s is finished; the partial store %s beside it is ignored (move it away)",
                store_path,
                staging,
            )
    else:
        store = open_store(staging, name, scene, prepared, settings)
        if not store.complete:
            collect_on_rig(scene, prepared, store, progress, ask, rig=rig, on_row=on_row)
            store.finalize({"summary": store_summary(store)})
        elif staging != store_path:  # completed, then killed before the rename: maybe before
            store.consolidate()  # finalize's last step too
        if staging != store_path:
            os.replace(staging, store_path)  # one rename: the store is whole or not there at all
        summary = store_summary(
            RawStore(store_path, zarr.open_group(str(store_path), mode="r"), prepared.plan)
        )
    if simulated and truth_path is not None:
        simulated_truth(scene, prepared).write(truth_path)
    return {**summary, "store": str(store_path), "frame_digest": digest}


def open_store(
    path: Path, name: str, scene: Mapping, prepared: ScenePlan, settings: Mapping[str, Any]
) -> RawStore:
    """The store being filled at `path`: resumed when there (with the same frame `settings`
    only), else created empty from the plan; anything else at `path` is refused."""
    _refuse_foreign(path)
    if path.exists():
        return RawStore.open_for_resume(path, prepared.plan, settings)
    path.parent.mkdir(parents=True, exist_ok=True)
    shape, layout = _sample_layout(prepared)
    return RawStore.create(
        path,
        prepared.plan,
        shape,
        prepared.settings.n_blank,
        _store_attrs(name, scene, prepared),
        layout,
        settings=settings,
    )


def finished_store_summary(
    path: Path, plan: pd.DataFrame, settings: Mapping[str, Any]
) -> dict[str, Any]:
    """The summary of a finished store, after checking it holds what the config asks for."""
    try:
        group = zarr.open_group(str(path), mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:  # noqa: BLE001 - any failure to open is one message naming the store
        raise StoreError(
            f"{path}: exists but is not a readable collection store ({exc}); it is never "
            "overwritten: move it away to collect anew"
        ) from None
    store = RawStore(path, group, plan)
    if not attrs.get("complete", False):
        raise StoreError(
            f"{path}: exists but is not complete ({store.progress()}); move it to the staging "
            "path to resume it, or away to collect anew (it is never overwritten)"
        )
    check_settings(path, attrs, settings, store.progress(), finished=True)
    if attrs.get("plan_digest") != plan_digest(plan):
        raise SettingsMismatch(
            f"{path}: was collected with another plan (digest {attrs.get('plan_digest')}, the "
            f"config's {plan_digest(plan)}); restore the plan to use it, or move it away to "
            "collect anew (it is never overwritten)"
        )
    return store_summary(store)


def simulated_truth(scene: Mapping, prepared: ScenePlan):
    """The simulated bench's hidden truth (seating, touch height): drawn from the seed alone, so
    it is the same whether or not this run collected the frames."""
    if is_magnetic(prepared.sensor):
        return draw_reskin_truth(scene["bench"], scene["seed"])

    return draw_truth(
        bench_sensor(rig_settings(scene), prepared.sensor), scene["bench"], scene["seed"]
    )


def _sample_layout(prepared: ScenePlan):
    """Shape of one sample and how the store keeps it: an RGB frame, or a ReSkin reading."""
    if is_magnetic(prepared.sensor):
        names = value_names(prepared.sensor)
        return (len(names),), readings_layout(names, prepared.plan)
    image = prepared.sensor["image"]
    return (image["height_px"], image["width_px"], 3), IMAGE_LAYOUT


# What a person at a real rig is asked to do before the probing starts.
ATTACH_PROBE = "Attach the probe to the print head"


def collect_on_rig(
    scene,
    prepared: ScenePlan,
    store: RawStore,
    progress: bool,
    ask: Ask | None,
    rig: Rig | None = None,
    **rounds,
) -> RunResult:
    """The scene's rig (threedcal.rig): the simulated bench, or the printer and the sensor; `rig`
    when one is open already. `rounds`: collect's `boundaries` and `at_boundary`, for a plan
    probed round by round, or its `on_row` watcher."""
    opened = (
        contextlib.nullcontext(rig)
        if rig is not None
        else open_rig(rig_settings(scene), prepared.sensor, prepared.printer, ask=ask)
    )
    with opened as rig:
        # Replay on the bench: a resumed run goes through the plan from the start, so the
        # simulated sensor sees an uninterrupted run's timeline and the store comes out
        # byte-identical.
        return collect(
            store,
            prepared.sensor,
            rig.printer,
            rig.sensor,
            prepared.settings,
            hardware_clock=rig.hardware_clock,
            clock=rig.clock,
            attach_probe=None if rig.simulated else lambda: rig.prompt(ATTACH_PROBE),
            progress=progress,
            replay=rig.simulated,
            touch_search=live_touch_search(scene, prepared),
            **rounds,
        )


def live_touch_search(scene: Mapping, prepared: ScenePlan):
    """The decider of a plan's bisecting touch search (plan.touch_search.method: bisect), the
    depth of each of its presses chosen from those before; None for a stepped search or none."""
    search = scene["plan"].get("touch_search") or {}
    plan = prepared.plan
    if search.get("method", "steps") != "bisect" or "phase" not in plan:
        return None
    rows = plan[plan["phase"] == "touch"]
    if rows.empty:
        return None
    low, high = touch_search_range(prepared.sensor, search)
    return planned_touch_search(
        rows[["x_mm", "y_mm"]].to_numpy(float),
        rows["depth_mm"].to_numpy(float),
        low,
        high,
        float(prepared.sensor["px_per_mm"]),
        float(scene["probe"]["radius_mm"]),
    )


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

    def write_points(self, first, records) -> None:
        pass

    def record_run(self, record, new: bool = False) -> None:
        pass

    @property
    def captured(self) -> np.ndarray:
        return np.zeros(len(self.plan), dtype=bool)


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
    firmware = SimMarlin(printer, speedup=math.inf)
    name = f"estimate-{id(firmware)}"
    FIRMWARES.serve(name, firmware)
    try:
        with MarlinHost(f"simmarlin://{name}", printer) as host:
            result = collect(
                _EstimateSink(plan),
                sensor,
                host,
                _ClockOnlyCamera(firmware.clock, _sample_rate_hz(sensor)),
                MotionSettings.from_profile(sensor),
                hardware_clock=firmware.clock.now,
                clock=BenchClock(firmware),
                progress=progress,
            )
    finally:
        FIRMWARES.withdraw(name)
    return result.hardware_s


def _sample_rate_hz(sensor: Mapping) -> float:
    if is_magnetic(sensor):
        return float(sensor["serial"]["rate_hz"])
    return float(sensor["camera"]["default_fps"])


def write_collection_summary(summary: Mapping, path: str | Path) -> None:
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
    ask: Ask | None = None,
) -> dict[str, Any]:
    """The `collect` rule: store, summary.json, coverage and sample-frame figures, bench truth.

    For a magnetic sensor `mosaic` receives a figure of sample readings instead of frames."""
    prepared = prepare(scene, source=f"scenes.{name}")
    result = collect_scene(
        name, scene, store, staging_path=staging, truth_path=truth, progress=progress, ask=ask
    )
    if scene["port"] != "sim":
        Path(truth).write_text(json.dumps({"simulated": False}) + "\n")
    write_collection_summary(result, summary)
    coverage_figure(
        prepared.plan, prepared.sensor, coverage, title=f"{name}: {len(prepared.plan)} probe points"
    )
    if is_magnetic(prepared.sensor):
        readings_figure(open_raw(store), prepared.sensor, mosaic, title=f"{name}: sample readings")
    else:
        mosaic_figure(open_raw(store), mosaic, title=f"{name}: sample frames")
    return result
