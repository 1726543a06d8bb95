"""The collection loop against the fake Marlin firmware, with a camera that draws the head position."""

import uuid

import numpy as np
import pandas as pd
import pytest

from threedcal.collect.plan import grid_plan, plan_to_printer
from threedcal.collect.run import MotionSettings, collect
from threedcal.collect.store import RawStore, open_raw
from threedcal.hardware.printer import MarlinHost
from threedcal.sim.marlin import SimMarlin, forget, register

SENSOR = {
    "probing": {"plan_area_mm": [2.0, 1.0]},
    "gel": {"max_penetration_mm": 4.0},
    "mount": {
        "x_offset_mm": 100.0,
        "y_offset_mm": 100.0,
        "z_touch_mm": 20.0,
        "z_clearance_mm": 2.0,
    },
}
SETTINGS = MotionSettings(travel_feed_mm_s=50, plunge_feed_mm_s=5, settle_s=0.2, n_blank=2)


class PositionCamera:
    """Frames that encode where the head physically is when they are taken (x, y, z in DN·10)."""

    def __init__(self, firmware: SimMarlin, fps: float = 30.0):
        self.firmware = firmware
        self.fps = fps
        self.flushes = 0

    def flush(self):
        self.flushes += 1

    def capture(self, count):
        frames, stamps = [], []
        for _ in range(count):
            self.firmware.clock.advance(1 / self.fps)
            x, y, z = self.firmware.position()
            frame = np.zeros((4, 4, 3), np.uint8)
            frame[..., 0], frame[..., 1], frame[..., 2] = (x - 95) * 10, (y - 95) * 10, z * 10
            frames.append(frame)
            stamps.append(self.firmware.clock.now())
        return np.stack(frames), np.array(stamps)


class FirmwareClock:
    def __init__(self, firmware):
        self.firmware = firmware

    def now(self):
        return self.firmware.clock.now()

    def sleep(self, seconds):
        self.firmware.clock.advance(seconds)


@pytest.fixture
def bench():
    name = f"c{uuid.uuid4().hex[:8]}"
    firmware = register(name, SimMarlin("ender3", speedup=float("inf")))
    yield f"simmarlin://{name}", firmware
    forget(name)


def run(store, url, firmware, **kwargs):
    with MarlinHost(url) as host:
        return collect(
            store,
            SENSOR,
            host,
            PositionCamera(firmware),
            SETTINGS,
            hardware_clock=firmware.clock.now,
            clock=FirmwareClock(firmware),
            progress=False,
            **kwargs,
        )


def test_frames_are_taken_at_rest_at_the_commanded_press(tmp_path, bench):
    url, firmware = bench
    plan = grid_plan(SENSOR, 1.0, 1.5, frames=2)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    result = run(store, url, firmware)
    store.finalize()
    assert result.points == 6 and result.frames == 12 and result.resumed_at == 0
    ds = open_raw(tmp_path / "raw.zarr")
    for i in range(ds.sizes["frame"]):
        expected = plan_to_printer(
            SENSOR, ds.x_mm[i].item(), ds.y_mm[i].item(), ds.depth_mm[i].item()
        )
        seen = ds.frames[i, 0, 0].values.astype(float) / 10 + [95, 95, 0]
        np.testing.assert_allclose(seen, expected, atol=0.1)  # at rest, not mid-move
        np.testing.assert_allclose(
            [ds.reported_x_mm[i], ds.reported_y_mm[i], ds.reported_z_mm[i]], expected, atol=1e-3
        )
    assert np.all(np.diff(ds.hardware_s.values) >= 0)
    # Blank frames are taken at the clearance height above the plan centre.
    blank_z = ds.blank_frames[0, 0, 0, 2].item() / 10
    assert blank_z == pytest.approx(22.0, abs=0.1)


def test_resume_captures_only_the_missing_points(tmp_path, bench):
    url, firmware = bench
    plan = grid_plan(SENSOR, 1.0, 1.5, frames=1)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})

    class Crash(Exception):
        pass

    calls = {"n": 0}
    original = store.write_point

    def crash_on_third(point, record):
        calls["n"] += 1
        if calls["n"] == 3:
            raise Crash
        original(point, record)

    store.write_point = crash_on_third
    with pytest.raises(Crash):
        run(store, url, firmware)
    resumed = RawStore.open_for_resume(tmp_path / "raw.zarr", plan)
    assert resumed.first_uncaptured() == 2
    result = run(resumed, url, firmware)
    assert result.resumed_at == 2 and result.points == 4
    resumed.finalize()
    assert bool(open_raw(tmp_path / "raw.zarr").captured.all())


def test_finished_store_runs_nothing(tmp_path, bench):
    url, firmware = bench
    plan = pd.DataFrame({"x_mm": [0.0], "y_mm": [0.0], "depth_mm": [1.0], "frames": [1]})
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 1, {})
    run(store, url, firmware)
    executed = len(firmware.executed)
    result = run(store, url, firmware)
    assert result.points == 0
    assert len(firmware.executed) - executed <= 4  # handshake only: no motion
