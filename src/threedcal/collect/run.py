"""The collection run: home, blank frames, then for every plan point lift → travel → press → wait →
settle → flush → capture → label → store. Crash-safe: a captured point is committed to the store
within a second (FLUSH_EVERY_S; on a printer, before the next point starts), and a rerun resumes at
the first point not captured.

Timing is synchronised, not guessed: a press is captured only after Marlin reports the queued moves
done (M400), and the travel to the next point is queued right after the capture, so the printer
moves while the store writes. The path is short: the probe lifts only to the clearance height above
the gel and rows are serpentine-ordered.

Stopping is safe: on SIGINT (Ctrl-C), SIGTERM or any error the probe is lifted to the sensor's
clearance height, the move is waited for and the steppers are released as the printer profile's
`safe_stop.release` says; an error that leaves the printer untrustworthy (halted, reset, gone
silent or disconnected) sends M112 instead. A signal that arrives while a G-code line is in flight
takes effect once that line is settled, so host and firmware stay in step; a second one stops at once.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.collect.plan import clearance_z, dome_sag_mm, plan_area_mm, plan_to_printer
from threedcal.collect.quick_plan import continued_presses
from threedcal.collect.store import PointRecord, RawStore, StoreError
from threedcal.errors import ConfigError
from threedcal.hardware.clock import Clock, WallClock
from threedcal.hardware.printer import (
    PrinterDisconnected,
    PrinterHalted,
    PrinterReset,
    PrinterTimeout,
)

# Captured points are written to the store together, once FLUSH_EVERY_S has passed since the last
# write or FLUSH_MAX_POINTS wait: a zarr write costs about a millisecond whatever its size, ten
# per point, most of a simulated collection's time if written one by one. A printer takes over a
# second a point, so on hardware every point is still written as it is captured. A kill loses only
# what waits: those points are not `captured` and the next run probes them again.
FLUSH_EVERY_S = 1.0
FLUSH_MAX_POINTS = 256


class FrameSource(Protocol):
    """What the run needs of a camera (threedcal.hardware.camera or the simulated bench)."""

    def flush(self) -> None: ...

    def capture(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """`count` fresh frames (count, H, W, 3) uint8 RGB and their time stamps (s)."""
        ...


class TouchDecider(Protocol):
    """Decides the depth of each touch row from the presses before it
    (threedcal.dataset.touch.PlanTouchSearch): rows counted in plan order, from 0."""

    def begin(self, blank_frames: np.ndarray) -> None: ...

    def depth(self, k: int) -> float: ...

    def observe(self, k: int, depth_mm: float, frames: np.ndarray) -> Any: ...


class CollectionInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a collection (raised after the probe was made safe)."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"{signal.Signals(signum).name} during collection")


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
    replayed: bool = False  # the run went through the plan from its start (see `collect`)
    stopped_at: int | None = None  # the boundary at which `at_boundary` ended the run


@contextlib.contextmanager
def stop_on_signals(printer) -> Iterator[None]:
    """SIGINT and SIGTERM raise CollectionInterrupted — between printer exchanges, never inside one
    (the host defers it until the line in flight is settled); a second signal raises at once.
    Outside the main thread (where Python cannot install handlers) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def handle(signum, frame) -> None:
        received.append(signum)
        error = CollectionInterrupted(signum)
        defer = getattr(printer, "interrupt_after_exchange", None)
        if len(received) == 1 and defer is not None and defer(error):
            return
        raise error

    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, handle) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def unrecoverable(error: BaseException) -> bool:
    """A printer fault after which no G-code can be trusted to run: halted, reset, silent, gone."""
    return isinstance(error, PrinterHalted | PrinterReset | PrinterTimeout | PrinterDisconnected)


def make_safe(printer, safe_z: float, feed_mm_s: float, cause: BaseException | None) -> str:
    """Lift to `safe_z`, wait for the move, release the steppers (printer profile); M112 when the
    printer cannot be trusted or the lift itself fails. Returns what was done, for the log."""
    if cause is not None and unrecoverable(cause):
        _emergency_stop(printer)
        return "emergency stop (M112): the printer could not be trusted to move"
    if not getattr(printer, "homed", True):
        return "nothing to lift: the printer was not homed"
    try:
        printer.move_to(z=safe_z, feed_mm_s=feed_mm_s)
        printer.wait_until_idle()
        _release_motors(printer)
    except BaseException as exc:  # noqa: BLE001 - a failed lift (or a second Ctrl-C): stop hard
        _emergency_stop(printer)
        return f"emergency stop (M112): lifting failed ({type(exc).__name__}: {exc})"
    return f"probe lifted to Z={safe_z:g} mm, steppers released as the printer profile says"


def _keep_what_was_captured(run: _Run) -> None:
    """After a stop, write the points captured but not yet flushed (a store that fails to take
    them leaves them uncaptured: the next run probes them again)."""
    try:
        run.flush()
    except BaseException as exc:  # noqa: BLE001 - the first error (or signal) is the one to report
        logging.getLogger("threedcal").warning(
            "%d captured point(s) could not be written after the stop (%s); the next run probes "
            "them again",
            len(run.pending),
            exc,
        )


def _release_motors(printer) -> None:
    """Release the steppers, where the printer can (as its profile's `safe_stop.release` says)."""
    release = getattr(printer, "release_motors", None)
    if release is not None:
        release()


def _emergency_stop(printer) -> None:
    stop = getattr(printer, "emergency_stop", None)
    if stop is not None:
        try:
            stop()
        except Exception:  # noqa: BLE001 - M112 is the last resort; nothing more can be done
            pass


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
    replay: bool = False,
    boundaries: Sequence[int] = (),
    at_boundary: Callable[[int], bool] | None = None,
    on_row: Callable[[int, np.ndarray | None, tuple], None] | None = None,
    touch_search: TouchDecider | None = None,
) -> RunResult:
    """Probe every point the store has not captured.

    `on_row(rows, samples, xyz)` is called once each plan row's samples are taken (rows: how many
    rows are done; samples: None for a row passed over on a replay; xyz: where the printer
    reported the head), the lift already queued: a watcher's progress (`threedcal rig`). What it
    raises stops the run as Ctrl-C does.

    `touch_search` decides the depth of each `touch` row of the plan as the run reaches it, from
    the frames of those before (a bisecting first-contact search); the plan's depth of such a row
    is the deepest it may be given, and the depth chosen is stored with its frames.

    `at_boundary(n)` is called once the first n plan rows are stored, for every n in `boundaries`
    (a quick calibration's rounds), the probe held lifted over the gel: it returns whether to go
    on. False ends the run as if the plan ended there (lifted, steppers released); the rows after
    it stay uncaptured. One run homes once, however many rounds it takes.

    `replay` (the simulated bench): go through the whole plan from its start — blank included —
    moving and sampling as an uninterrupted run would, writing only what is missing and checking
    that the rest comes out as stored. The simulated sensor then sees the same timeline as an
    uninterrupted run, so a resumed store is byte-identical to one collected in one go.
    """
    clock = clock or WallClock()
    run = _Run(store, sensor, printer, camera, settings, clock, hardware_clock or clock.now, replay)
    run.boundaries, run.at_boundary = set(int(b) for b in boundaries), at_boundary
    run.on_row = on_row or (lambda rows, samples, xyz: None)
    run.touch_search = touch_search
    if run.start is None:
        return RunResult(0, 0, 0.0, 0.0, len(store.plan))
    run.record(new=True)
    bar = tqdm(
        total=len(store.plan),
        initial=run.start,
        desc="collect",
        unit="pt",
        disable=not progress,
        dynamic_ncols=True,
    )
    with stop_on_signals(printer):
        try:
            printer.home()
            printer.hold_motors()
            if attach_probe is not None:
                attach_probe()
            run.blank()
            if touch_search is not None:
                touch_search.begin(store.read_blank())
            run.probe(bar)
            printer.move_to(z=run.safe_z, feed_mm_s=settings.plunge_feed_mm_s)
            printer.wait_until_idle()
            _release_motors(printer)
        except BaseException as exc:
            outcome = make_safe(printer, run.safe_z, settings.plunge_feed_mm_s, exc)
            _keep_what_was_captured(run)
            run.record(stopped=f"{type(exc).__name__}: {exc}".strip(": "), safe_stop=outcome)
            bar.close()
            logging.getLogger("threedcal").warning(
                "collection stopped (%s); %s", type(exc).__name__, outcome
            )
            raise
    bar.close()
    run.record(**({} if run.stopped_at is None else {"ended_at_row": run.stopped_at}))
    return run.result()


class _Run:
    """One collection run's state: where it started, what it has written, its clocks."""

    def __init__(self, store, sensor, printer, camera, settings, clock, hardware_clock, replay):
        self.store, self.sensor, self.printer, self.camera = store, sensor, printer, camera
        self.settings, self.clock, self.hardware_clock, self.replay = (
            settings,
            clock,
            hardware_clock,
            replay,
        )
        self.plan: pd.DataFrame = store.plan
        self.start = store.first_uncaptured()
        self.started_wall = time.monotonic()
        self.started_clock, self.started_hw = clock.now(), hardware_clock()
        self.done = np.asarray(store.captured, dtype=bool)
        self.safe_z = clearance_z(sensor)
        self.points = self.frames = 0
        # captured points not yet written (consecutive, from `pending_from`): see FLUSH_EVERY_S
        self.pending: list[PointRecord] = []
        self.pending_from = 0
        self.flushed_at = time.monotonic()
        self.boundaries: set[int] = set()
        self.at_boundary: Callable[[int], bool] | None = None
        self.on_row: Callable[[int, np.ndarray | None, tuple], None] = lambda *row: None
        self.stopped_at: int | None = None
        self.touch_search: TouchDecider | None = None

    def record(self, new: bool = False, **extra: Any) -> None:
        """Keep this run's record in the store up to date (a killed run still counts)."""
        self.store.record_run(
            {
                "resumed_at": self.start,
                "replayed": self.replay or self.start == 0,
                "points": self.points,
                "frames": self.frames,
                "duration_s": round(time.monotonic() - self.started_wall, 3),
                "hardware_s": round(self.hardware_clock() - self.started_hw, 3),
                **extra,
            },
            new=new,
        )

    def result(self) -> RunResult:
        return RunResult(
            points=self.points,
            frames=self.frames,
            duration_s=time.monotonic() - self.started_wall,
            hardware_s=self.hardware_clock() - self.started_hw,
            resumed_at=self.start,
            replayed=self.replay,
            stopped_at=self.stopped_at,
        )

    def blank(self) -> None:
        """No-contact frames at the clearance height over the plan's centre (passed over when
        stored already, on a replay)."""
        store, settings, printer = self.store, self.settings, self.printer
        if not (self.replay or not store.has_blank()):
            return
        cx, cy = (v / 2 for v in plan_area_mm(self.sensor))
        x, y, _ = plan_to_printer(self.sensor, cx, cy, 0.0)
        printer.move_to(z=self.safe_z, feed_mm_s=settings.plunge_feed_mm_s)
        printer.move_to(x=x, y=y, feed_mm_s=settings.travel_feed_mm_s)
        printer.wait_until_idle()
        self.clock.sleep(settings.settle_s)
        self.camera.flush()
        if store.has_blank():
            _pass_over(self.camera, settings.n_blank)
        else:
            blank, _ = self.camera.capture(settings.n_blank)
            store.write_blank(blank)

    def probe(self, bar) -> None:
        store, sensor, printer, settings, plan = (
            self.store,
            self.sensor,
            self.printer,
            self.settings,
            self.plan,
        )
        offsets = store.offsets
        first = 0 if self.replay else self.start
        # Hop height between two points: `hop_mm` above the higher of their gel surfaces (a domed
        # gel sits lower away from its apex), never above the clearance height.
        surface_z = sensor["mount"]["z_touch_mm"] - dome_sag_mm(sensor, plan["x_mm"], plan["y_mm"])
        touch_rows = self._touch_rows(first)
        # a row that goes on with the one before as one press (a quick press after its pause to
        # register): the probe stays down and goes deeper
        continued = continued_presses(plan)
        for point in range(first, len(plan)):
            row = plan.iloc[point]
            depth, chosen = row.depth_mm, touch_rows.get(point)
            if chosen is not None:
                depth = self._touch_depth(point, chosen, row.depth_mm)
            target = plan_to_printer(sensor, row.x_mm, row.y_mm, depth)
            going_on = bool(continued[point]) and point > first
            if not going_on:
                previous = surface_z[point - 1] if point > first else np.inf
                hop_z = min(self.safe_z, max(previous, surface_z[point]) + settings.hop_mm)
                printer.move_to(z=hop_z, feed_mm_s=settings.plunge_feed_mm_s)
                printer.move_to(x=target[0], y=target[1], feed_mm_s=settings.travel_feed_mm_s)
            printer.move_to(z=target[2], feed_mm_s=settings.plunge_feed_mm_s)
            printer.wait_until_idle()
            self.clock.sleep(settings.settle_s)
            reported = tuple(printer.position())
            self.camera.flush()
            count = int(offsets[point + 1] - offsets[point])
            if self.done[point]:
                samples = _pass_over(self.camera, count)
            else:
                frames, stamps = self.camera.capture(count)
            hw_now = self.hardware_clock() - self.started_hw
            if point + 1 >= len(plan) or not continued[point + 1]:
                lift_to = surface_z[point + 1] if point + 1 < len(plan) else np.inf
                lift_z = min(self.safe_z, max(surface_z[point], lift_to) + settings.hop_mm)
                printer.move_to(z=lift_z, feed_mm_s=settings.plunge_feed_mm_s)  # lift, then store
            if self.done[point]:
                self._replayed(point, samples, (chosen, depth), reported, bar)
                if not self.round_done(point + 1, bar):
                    return
                continue
            if chosen is not None:
                self.touch_search.observe(chosen, depth, frames)
            if not self.pending:
                self.pending_from = point
            self.pending.append(
                PointRecord(
                    frames=frames,
                    cmd_xyz=target,
                    reported_xyz=reported,
                    t_s=np.asarray(stamps, dtype=float) - self.started_clock,
                    hardware_s=np.full(count, hw_now),
                    depth_mm=None if chosen is None else float(depth),
                )
            )
            if (
                len(self.pending) >= FLUSH_MAX_POINTS
                or time.monotonic() - self.flushed_at >= FLUSH_EVERY_S
            ):
                self.flush(bar)
            self.on_row(point + 1, frames, reported)
            if not self.round_done(point + 1, bar):
                return
        self.flush(bar)

    def _touch_rows(self, first: int) -> dict[int, int]:
        """{plan row: its index among the touch rows} of a searching run, the search told what
        the rows before `first` pressed (a resumed search goes on from there); {} without one."""
        plan, store = self.plan, self.store
        if self.touch_search is None or "phase" not in plan:
            return {}
        rows = np.flatnonzero(plan["phase"].to_numpy() == "touch")
        touch_rows = {int(row): k for k, row in enumerate(rows)}
        for row in rows[rows < first]:
            self.touch_search.observe(
                touch_rows[int(row)], store.read_depth(row), store.read_point(row)
            )
        return touch_rows

    def _replayed(self, point: int, samples, search: tuple, reported, bar) -> None:
        """A stored point passed over on a replay: what waits is written first (it ends before
        this point), the samples checked against the stored ones, the search told what the press
        showed. `search`: (its index among the touch rows or None, its depth)."""
        store = self.store
        self.flush(bar)
        if samples is not None and not np.array_equal(samples, store.read_point(point)):
            raise StoreError(
                f"{store.path}: replaying point {point} of the simulated bench did not "
                "give the samples stored for it (was the simulator changed since?); move "
                "the store away to collect it anew"
            )
        chosen, depth = search
        if chosen is not None:
            self.touch_search.observe(chosen, depth, store.read_point(point))
        self.on_row(point + 1, None, reported)

    def _touch_depth(self, point: int, k: int, deepest: float) -> float:
        """A searching row's depth: the one stored (a replayed press), or the search's next,
        refused before any motion if it lies deeper than the plan allowed there."""
        if self.done[point]:
            return self.store.read_depth(point)
        depth = float(self.touch_search.depth(k))
        if not depth <= deepest + 1e-9:
            raise ConfigError(
                f"touch search row {point}: the search asked for {depth:g} mm, deeper than the "
                f"plan's {deepest:g} mm there; not pressed"
            )
        return depth

    def round_done(self, rows: int, bar) -> bool:
        """At a boundary: store what waits, let the lift finish, ask `at_boundary` whether to go
        on. False when the run is to end here."""
        if rows not in self.boundaries or self.at_boundary is None:
            return True
        self.flush(bar)
        self.printer.wait_until_idle()
        if self.at_boundary(rows):
            return True
        self.stopped_at = rows
        return False

    def flush(self, bar=None) -> None:
        """Write the points captured since the last flush, then the run's record."""
        if not self.pending:
            return
        records = self.pending
        self.store.write_points(self.pending_from, records)
        self.pending = []
        self.points += len(records)
        self.frames += sum(len(r.frames) for r in records)
        self.flushed_at = time.monotonic()
        self.record()
        if bar is not None:
            bar.update(len(records))


def _pass_over(camera, count: int):
    """Sample `count` times without keeping anything; returns the samples when the source could
    only be read (to check), None when it skipped them (the simulated camera skips rendering)."""
    skip = getattr(camera, "skip", None)
    if skip is not None:
        skip(count)
        return None
    samples, _ = camera.capture(count)
    return samples
