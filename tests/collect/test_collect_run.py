"""The collection loop against the fake Marlin firmware, with a camera that draws the head position."""

import os
import signal

import numpy as np
import pandas as pd
import pytest

from threedcal.collect.plan import clearance_z, grid_plan, plan_to_printer
from threedcal.collect.run import CollectionInterrupted, MotionSettings, collect
from threedcal.collect.store import RawStore
from threedcal.collect.store_read import open_raw
from threedcal.errors import ConfigError
from threedcal.hardware.printer import MarlinHost, PrinterTimeout, printer_profile
from threedcal.sim.marlin import SimMarlin

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
def bench(sim_firmware):
    return sim_firmware


def run(store, url, firmware, **kwargs):
    with MarlinHost(url) as host:
        return run_on(host, store, firmware, **kwargs)


def run_on(host, store, firmware, camera=None, **kwargs):
    """collect() on an open host, on the firmware's clock, with a camera that sees the head."""
    return collect(
        store,
        SENSOR,
        host,
        camera or PositionCamera(firmware),
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

    original = store.write_points

    def crash_on_third(first, records):
        """The store fails at point 2 (a full disk), whether it comes alone or with others."""
        good = max(0, min(len(records), 2 - first))
        original(first, records[:good])
        if good < len(records):
            raise Crash

    store.write_points = crash_on_third
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


# ---- issue 22: the printer always stops safe ----------------------------------------------


class InterruptingCamera(PositionCamera):
    """Raises `error` (or sends `signum` to this process) during the `at`-th capture: while the
    probe is pressed into the gel."""

    def __init__(self, firmware, at=2, error=None, signum=None):
        super().__init__(firmware)
        self.at, self.error, self.signum, self.calls = at, error, signum, 0
        self.pressed_z = None

    def capture(self, count):
        self.calls += 1
        if self.calls == self.at:
            self.pressed_z = self.firmware.position()[2]
            if self.signum is not None:
                os.kill(os.getpid(), self.signum)
            if self.error is not None:
                raise self.error
        return super().capture(count)


def numbered_log(firmware):
    return [(n, c) for n, c in firmware.executed if n is not None and n >= 1]


@pytest.mark.parametrize(
    "error, signum",
    [
        (KeyboardInterrupt(), None),
        (None, signal.SIGINT),
        (None, signal.SIGTERM),
        (OSError("usb"), None),
    ],
    ids=["keyboard-interrupt", "sigint", "sigterm", "camera-error"],
)
def test_stop_while_pressed_lifts_to_the_safe_height_and_releases(tmp_path, bench, error, signum):
    """Repro: Ctrl-C (or any error) while pressed left the probe 1.4 mm in the gel, steppers held."""
    url, firmware = bench
    plan = grid_plan(SENSOR, 1.0, 1.5, frames=1)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    camera = InterruptingCamera(firmware, at=3, error=error, signum=signum)
    expected = (
        OSError
        if error is not None and not isinstance(error, KeyboardInterrupt)
        else KeyboardInterrupt
    )
    with MarlinHost(url) as host, pytest.raises(expected):
        run_on(host, store, firmware, camera)
    assert camera.pressed_z == pytest.approx(20.0 - 1.5, abs=0.01)  # it was pressed
    assert firmware.position()[2] == pytest.approx(clearance_z(SENSOR))  # now at the safe height
    assert firmware.executed_commands()[-3:] == ["G1 Z22.000 F300.0", "M400", "M84"]
    assert not firmware.motors_on and not firmware.halted
    assert store.first_uncaptured() == 1  # the point before the stop is kept: a rerun resumes
    assert store.runs[-1]["stopped"]


def test_a_signal_during_an_exchange_waits_for_the_line_to_settle(tmp_path, bench):
    url, firmware = bench
    plan = grid_plan(SENSOR, 1.0, 1.5, frames=1)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    with MarlinHost(url) as host:
        original, sent = host._readline, {"done": False}

        def readline(deadline):
            if (
                host._history[host._next - 1] == "M400"
                and not sent["done"]
                and store.captured.any()
            ):
                sent["done"] = True
                os.kill(os.getpid(), signal.SIGINT)  # arrives while M400's reply is awaited
            return original(deadline)

        host._readline = readline
        with pytest.raises(CollectionInterrupted):
            run_on(host, store, firmware, PositionCamera(firmware))
        acked = [(n, c) for n, c in host.acked if n >= 1]
    assert sent["done"]
    assert acked == numbered_log(firmware)  # host and firmware in step: each line once, in order
    assert firmware.position()[2] == pytest.approx(clearance_z(SENSOR))


def test_an_unrecoverable_printer_error_sends_m112(tmp_path, bench):
    url, firmware = bench
    plan = grid_plan(SENSOR, 1.0, 1.5, frames=1)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})

    class SilencingCamera(PositionCamera):
        points = 0

        def capture(self, count):
            self.points += 1
            if self.points == 4:  # the blank, two points, then silence at the third
                firmware.kinds, firmware.rate = ("drop_line",), 1.0
            return super().capture(count)

    with MarlinHost(url, retries=1) as host, pytest.raises(PrinterTimeout):
        run_on(host, store, firmware, SilencingCamera(firmware))
    assert firmware.halted and firmware.executed[-1] == (None, "M112")


def test_the_end_of_a_run_releases_as_the_profile_says(tmp_path, bench):
    url, firmware = bench
    plan = grid_plan(SENSOR, 2.0, 1.5, frames=1)
    profile = printer_profile("ender3")
    profile["safe_stop"] = {"release": "idle_timeout", "idle_timeout_s": 60}
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    with MarlinHost(url, profile) as host:
        run_on(host, store, firmware, PositionCamera(firmware))
    assert firmware.executed_commands()[-1] == "M84 S60" and firmware.idle_timeout_s == 60
    assert firmware.position()[2] == pytest.approx(clearance_z(SENSOR))


class ScriptedSearch:
    """A touch-search decider that asks for the depths it is given, in turn, and keeps what it saw."""

    def __init__(self, depths):
        self.depths, self.seen, self.blank = list(depths), [], None

    def begin(self, blank_frames):
        self.blank = blank_frames

    def depth(self, k):
        return self.depths[k]

    def observe(self, k, depth_mm, frames):
        self.seen.append((k, depth_mm, frames[:, 0, 0, 2].astype(float) / 10))


def z_moves(firmware) -> list[float]:
    return [
        float(word[1:])
        for _, command in numbered_log(firmware)
        if command.split()[0] in ("G0", "G1")
        for word in command.split()[1:]
        if word.startswith("Z")
    ]


def searched_plan(touch_depths) -> pd.DataFrame:
    """Touch rows at the centre (their depth the deepest allowed), then one quick press pausing
    0.25 mm deep on its way down to 1.0 mm."""
    rows = [(1.0, 0.5, max(touch_depths), 2, "touch")] * len(touch_depths)
    rows += [(0.5, 0.5, 0.25, 1, "register"), (0.5, 0.5, 1.0, 1, "grid")]
    return pd.DataFrame(rows, columns=["x_mm", "y_mm", "depth_mm", "frames", "phase"])


def test_a_search_decides_each_touch_rows_depth_and_a_press_pauses_without_lifting(tmp_path, bench):
    url, firmware = bench
    chosen = [0.3, 0.05, -0.075, 0.1125]
    plan = searched_plan(chosen)
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    search = ScriptedSearch(chosen)
    run(store, url, firmware, touch_search=search)
    store.finalize()
    ds = open_raw(tmp_path / "raw.zarr")
    # each touch row pressed where the search said, stored with its frames, seen by the search
    touch = ds.point.values < len(chosen)
    np.testing.assert_allclose(ds.depth_mm.values[touch], np.repeat(chosen, 2))
    np.testing.assert_allclose(ds.cmd_z_mm.values[touch], 20.0 - np.repeat(chosen, 2))
    assert [k for k, _, _ in search.seen] == [0, 1, 2, 3] and search.blank.shape == (2, 4, 4, 3)
    for k, depth, z in search.seen:
        assert depth == chosen[k] and z == pytest.approx([20.0 - depth] * 2, abs=0.1)
    # the pause at 0.25 mm goes straight on down to 1.0 mm: no hop between the two rows
    moves = z_moves(firmware)
    paused = moves.index(19.75)
    assert moves[paused + 1] == 19.0
    assert ds.depth_mm.values[~touch].tolist() == [0.25, 1.0]  # the plan's own depths


def test_a_search_asking_deeper_than_the_plan_allows_is_refused_before_that_press(tmp_path, bench):
    url, firmware = bench
    plan = searched_plan([0.3, 0.3])
    store = RawStore.create(tmp_path / "raw.zarr", plan, (4, 4, 3), 2, {})
    with pytest.raises(ConfigError, match="deeper than the plan's 0.3 mm there; not pressed"):
        run(store, url, firmware, touch_search=ScriptedSearch([0.3, 0.45]))
    assert min(z_moves(firmware)) == pytest.approx(19.7)  # 0.3 mm deep at most
    assert store.captured.tolist() == [True, False, False, False]
