"""The set-up page's rig: one printer and camera, one user of them at a time, a status that never waits.

`RigControl` opens the scene's rig (threedcal.rig: the simulated bench or the printer and camera)
and does what the page asks: home, jog, take the blank, find the gel (threedcal.page.gel), save
the mount (threedcal.mount), collect (threedcal.study.session), stop. The printer and camera
are used under one lock; the long jobs (finding the gel, a collection) run in a thread of their
own and hold it throughout, so a jog meanwhile is refused, naming who owns the printer. The
status is a snapshot the jobs update: reading it takes no lock and touches no device.

Safety. No move goes below the floor the sensor profile allows (`gel.max_penetration_mm` under
the first touch; while the touch is not measured here, `probing.touch_uncertainty_mm` higher) nor
sideways below the gel's top; both are refused before anything is sent. A stop, or the page going
away, ends a job at its next press and leaves the probe lifted and the steppers released as the
collection's own Ctrl-C does (threedcal.collect.run.make_safe).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from threedcal.collect.run import MotionSettings, make_safe
from threedcal.errors import ConfigError, ThreedcalError
from threedcal.mount import SensorMount, mount_yaml, with_mount, write_mount_file
from threedcal.page.gel import Presser, find_gel
from threedcal.profiles import load_profile
from threedcal.rig import open_rig
from threedcal.study.config import load_config, scene_config
from threedcal.study.scene import rig_settings, scene_mount_values, scene_sensor
from threedcal.study.session import collect_scene, prepare

AXES = ("x", "y", "z")
# The longest single jog the page accepts, mm.
MAX_JOG_MM = 50.0
# How far above the first touch (plus its uncertainty, while unmeasured) a sideways jog is allowed.
SIDEWAYS_CLEARANCE_MM = 0.2
# The long jobs, which hold the printer until they end; a request meanwhile is refused at once.
JOBS = ("find", "collect")
# How long a request waits for a short one (a jog, a frame) to free the printer, s.
SHORT_WAIT_S = 10.0
log = logging.getLogger("threedcal")


class Refused(ThreedcalError):
    """The rig will not do what was asked now (busy, unsafe, not homed); nothing was sent."""


class BadRequest(ThreedcalError):
    """A request the page could not have meant (an unknown axis, a step that is not a number)."""


class StoppedFromPage(KeyboardInterrupt):
    """The page's stop button, or the page gone: handled as the collection's own Ctrl-C."""


@dataclass
class Limits:
    """Z limits in force: no press below `floor_z`; sideways moves only at or above `free_z`;
    stops lift to `safe_z`."""

    floor_z: float
    free_z: float
    safe_z: float


def limits_of(sensor: Mapping, measured: bool) -> Limits:
    """The limits for a sensor seated as its `mount` says; `measured`: its z_touch_mm was found by
    the touch search here (else the gel may sit touch_uncertainty_mm higher than it says)."""
    mount = sensor["mount"]
    touch = float(mount["z_touch_mm"])
    uncertainty = 0.0 if measured else float(sensor["probing"].get("touch_uncertainty_mm", 0.2))
    return Limits(
        floor_z=touch + uncertainty - float(sensor["gel"]["max_penetration_mm"]),
        free_z=touch + uncertainty + SIDEWAYS_CLEARANCE_MM,
        safe_z=touch + uncertainty + float(mount["z_clearance_mm"]),
    )


class RigControl:
    """A scene's rig as the page drives it. Open with `open()` (or as a context manager)."""

    def __init__(
        self,
        config_path: str | Path,
        scene_name: str,
        store: str | Path | None = None,
        open_rig_: Callable | None = None,
    ):
        self.config_path = Path(config_path)
        self.name = scene_name
        self.scene = self._load_scene()
        self.sensor = scene_sensor(self.scene, f"scenes.{scene_name}", missing_ok=True)
        if self.sensor.get("type") != "vision":
            raise ConfigError(
                f"scenes.{scene_name}.sensor: the set-up page shows a camera; "
                f"{self.sensor['name']!r} is not a vision sensor"
            )
        self.store = Path(store or f"results/{scene_name}/raw.zarr")
        self.settings = MotionSettings.from_profile(self.sensor)
        self._open_rig = open_rig_ or open_rig
        self.lock = threading.Lock()  # the printer and the camera
        self._state = threading.Lock()  # the snapshot below
        self._stop = threading.Event()
        self._stack: contextlib.ExitStack | None = None
        self.rig = None
        self.found: SensorMount | None = None
        self.saved: str | None = None  # where the found mount was written
        self.blank: np.ndarray | None = None
        self.frame: np.ndarray | None = None
        self.frame_xyz: tuple | None = None  # where the head was when `frame` was taken
        self.frame_seq = 0
        self.job: threading.Thread | None = None
        self.busy: str | None = None  # what holds the printer: home, jog, find, collect, stop
        self.message = ""
        self.refusal = ""
        self.find_state: dict[str, Any] = {"state": "not run"}
        self.collection: dict[str, Any] = {"state": "not run"}
        self.limits = limits_of(self.sensor, measured=False)

    # ---- opening -------------------------------------------------------------------------
    def _load_scene(self) -> dict:
        return dict(scene_config(load_config(self.config_path, new_mount=True), self.name))

    def open(self) -> RigControl:
        printer = load_profile("printer", self.scene["printer"])
        self._stack = contextlib.ExitStack()
        self.rig = self._stack.enter_context(
            self._open_rig(rig_settings(self.scene), self.sensor, printer, ask=self._tell)
        )
        return self

    def __enter__(self) -> RigControl:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop any job, leave the probe lifted and the steppers released, close the rig."""
        if self.rig is None:
            return
        self._stop.set()
        if self.job is not None:
            self.job.join()
        with self.lock:
            self._make_safe("the page's server stopped")
        self._stack.close()
        self.rig = None

    def _tell(self, message: str) -> None:
        """A real rig's question (threedcal.rig.Rig.prompt) during a collection the page started:
        the probe is on the head already (the gel was found with it), so it is only reported."""
        self._set(message=f"collect: {message} (done: the page found the gel with it)")

    # ---- status --------------------------------------------------------------------------
    def _set(self, **values) -> None:
        with self._state:
            for key, value in values.items():
                setattr(self, key, value)

    def status(self) -> dict[str, Any]:
        """Everything the page shows, from the snapshot: no device is asked, no lock waited on."""
        printer = self.rig.printer if self.rig is not None else None
        position = getattr(printer, "commanded", None)
        mount = SensorMount.of(self.sensor["mount"])
        with self._state:
            collection = dict(self.collection)
            if collection.get("state") == "running":
                done, total = collection["rows_done"], collection["rows_total"]
                elapsed = time.monotonic() - collection["started"]
                collection["elapsed_s"] = round(elapsed, 1)
                collection["left_s"] = round(elapsed / done * (total - done), 1) if done else None
            collection.pop("started", None)
            return {
                "scene": self.name,
                "sensor": self.sensor["name"],
                "printer": self.scene["printer"],
                "port": self.scene["port"],
                "simulated": bool(getattr(self.rig, "simulated", False)),
                "busy": self.busy,
                "homed": bool(getattr(printer, "homed", False)),
                "position_mm": None if position is None else [round(v, 3) for v in position],
                "limits": {k: round(v, 3) for k, v in vars(self.limits).items()},
                "blank": self.blank is not None,
                "frame_seq": self.frame_seq,
                "mount": mount.as_dict(),
                "mount_file": self.scene.get("mount")
                if isinstance(self.scene.get("mount"), str)
                else None,
                "found": None if self.found is None else self.found.as_dict(),
                "found_yaml": None if self.found is None else mount_yaml(self.found, self._about()),
                "saved": self.saved,
                "registered": self.found is not None,
                "find": dict(self.find_state),
                "collection": collection,
                "message": self.message,
                "refusal": self.refusal,
            }

    # ---- the printer, one user at a time ------------------------------------------------
    @contextlib.contextmanager
    def _using(self, what: str):
        """The printer and camera for `what`, or Refused naming who has them."""
        if self.rig is None:
            raise Refused("the rig is not open")
        # a job holds the printer for long: refused at once; a short request (a jog, the live
        # image's frame) is waited for
        if self.busy in JOBS or not self.lock.acquire(timeout=SHORT_WAIT_S):
            owner = self.busy or "another request"
            if owner == "collect":
                raise Refused(
                    f"{what} refused: the collection owns the printer while it runs (stop it "
                    "first, or wait for it to end)"
                )
            raise Refused(f"{what} refused: the printer is busy ({owner}); wait, or stop")
        self._set(busy=what, refusal="")
        try:
            yield self.rig
        finally:
            self._set(busy=None)
            self.lock.release()

    def _refuse(self, error: Exception) -> None:
        self._set(refusal=str(error))

    def home(self) -> None:
        """G28, then up to the clearance height over the mount's centre, where the blank is taken."""
        with self._using("home") as rig:
            self._stop.clear()
            printer = rig.printer
            printer.home()
            centre = SensorMount.of(self.sensor["mount"]).centre_mm(self.sensor)
            printer.move_to(z=self.limits.safe_z, feed_mm_s=self.settings.plunge_feed_mm_s)
            printer.move_to(*centre, feed_mm_s=self.settings.travel_feed_mm_s)
            printer.wait_until_idle()
            self._take_blank(rig)
            self._set(message="homed; the probe waits at the clearance height over the gel")

    def take_blank(self) -> None:
        with self._using("blank") as rig:
            self._take_blank(rig)
            self._set(message="blank taken: nothing may touch the gel while it is taken")

    def _take_blank(self, rig) -> None:
        rig.clock.sleep(self.settings.settle_s)
        rig.sensor.flush()
        frames, _ = rig.sensor.capture(self.settings.n_blank)
        blank = frames.astype(np.float32).mean(axis=0)
        self._set(blank=blank)
        self._see(frames[-1], rig.printer.commanded)

    def jog(self, axis: Any, step_mm: Any) -> None:
        """Move one axis by `step_mm`, within the limits; refused (nothing sent) otherwise."""
        axis = str(axis).lower()
        if axis not in AXES:
            raise BadRequest(f"axis {axis!r}: allowed x, y, z")
        try:
            step = float(step_mm)
        except (TypeError, ValueError):
            raise BadRequest(f"step_mm {step_mm!r}: not a number of mm") from None
        if not math.isfinite(step) or abs(step) > MAX_JOG_MM:
            raise BadRequest(
                f"step_mm {step_mm!r}: a jog is a finite step of at most {MAX_JOG_MM:g} mm"
            )
        with self._using("jog") as rig:
            printer = rig.printer
            if not printer.homed:
                raise Refused("jog refused: home first (the printer does not know where it is)")
            x, y, z = printer.commanded
            target = {"x": x, "y": y, "z": z}
            target[axis] += step
            if target["z"] < self.limits.floor_z - 1e-9:
                raise Refused(
                    f"jog refused: Z={target['z']:.3f} mm is below Z={self.limits.floor_z:.3f} mm, "
                    f"the deepest the {self.sensor['name']} profile allows (gel.max_penetration_mm "
                    f"{self.sensor['gel']['max_penetration_mm']:g} mm under the first touch"
                    + ("" if self.found else ", which is not measured yet: find the gel")
                    + ")"
                )
            if axis != "z" and z < self.limits.free_z - 1e-9:
                raise Refused(
                    f"jog refused: the probe is at Z={z:.3f} mm, on or in the gel; lift it to "
                    f"Z >= {self.limits.free_z:.3f} mm before moving in {axis.upper()} (the ball "
                    "would drag across the gel)"
                )
            printer.check_target(target["x"], target["y"], target["z"])
            feed = self.settings.plunge_feed_mm_s if axis == "z" else self.settings.travel_feed_mm_s
            printer.move_to(**{axis: target[axis]}, feed_mm_s=feed)
            printer.wait_until_idle()
            self._capture(rig)

    # ---- frames --------------------------------------------------------------------------
    def _see(self, frame: np.ndarray, xyz) -> None:
        with self._state:
            self.frame = np.asarray(frame)
            self.frame_xyz = None if xyz is None else tuple(float(v) for v in xyz)
            self.frame_seq += 1

    def _capture(self, rig) -> None:
        frames, _ = rig.sensor.capture(1)
        self._see(frames[0], rig.printer.commanded)

    def latest_frame(self) -> tuple[int, np.ndarray | None, np.ndarray | None, tuple | None]:
        """A frame taken now when the camera is free, else the last one a job took: (its sequence
        number, the frame, the blank, the probe in it: probe_px)."""
        if self.rig is not None and self.busy is None and self.lock.acquire(blocking=False):
            try:
                self._capture(self.rig)
            except ThreedcalError as exc:
                self._refuse(exc)
            finally:
                self.lock.release()
        with self._state:
            return self.frame_seq, self.frame, self.blank, self.probe_px(self.frame_xyz)

    def probe_px(self, xyz) -> tuple[float, float, float] | None:
        """Where the probe at printer `xyz` lies in the image (column, row) and its contact's
        radius in px (0 above the gel), once the page has found the gel; None before."""
        if self.found is None or xyz is None:
            return None
        x, y, z = xyz
        cx, cy = self.found.centre_mm(self.sensor)
        scale = float(self.sensor["px_per_mm"])
        col = (self.sensor["image"]["width_px"] - 1) / 2 + scale * (x - cx)
        row = (self.sensor["image"]["height_px"] - 1) / 2 - scale * (y - cy)
        depth = max(self.found.z_touch_mm - z, 0.0)
        radius = float(self.scene["probe"]["radius_mm"])
        contact = math.sqrt(max(2 * radius * depth - depth * depth, 0.0)) * scale
        return col, row, contact

    # ---- jobs: find the gel, collect -----------------------------------------------------
    def _start(self, kind: str, work: Callable[[Any], None], wait: bool = False) -> None:
        """Run `work(rig)` in a thread that holds the printer until it ends or is stopped;
        `wait`: return when it has ended, raising Refused with its error if it failed."""
        if self.job is not None and self.job.is_alive():
            raise Refused(f"{kind} refused: {self.busy or 'a job'} is running; wait, or stop it")
        context = self._using(kind)
        rig = context.__enter__()  # refused here, in the caller's thread, when busy
        self._stop.clear()

        def run() -> None:
            try:
                work(rig)
            except BaseException as exc:  # noqa: BLE001 - reported on the page; the rig made safe
                self._set(refusal=f"{kind}: {exc}" if str(exc) else f"{kind}: {type(exc).__name__}")
                log.warning("%s stopped: %s", kind, exc)
            finally:
                context.__exit__(None, None, None)

        self.job = threading.Thread(target=run, name=f"threedcal-rig-{kind}", daemon=True)
        self.job.start()
        if wait:
            self.job.join()
            if self.refusal.startswith(f"{kind}: "):
                raise Refused(self.refusal)

    def _check_stop(self) -> None:
        if self._stop.is_set():
            raise StoppedFromPage("stopped from the page")

    def find_gel(self, wait: bool = False) -> None:
        """Start finding the gel from where the probe is (over the gel, not touching it)."""

        def work(rig) -> None:
            printer = rig.printer
            if not printer.homed:
                raise Refused("find the gel refused: home first")
            start = printer.commanded
            self._set(find_state={"state": "running", "presses": 0}, message="finding the gel")
            presser = Presser(
                printer,
                rig.sensor,
                rig.clock.sleep,
                self.settings.plunge_feed_mm_s,
                self.settings.travel_feed_mm_s,
                self.settings.settle_s,
                seen=self._seen_press,
                check_stop=self._check_stop,
            )
            try:
                rig.clock.sleep(self.settings.settle_s)
                rig.sensor.flush()
                blanks, _ = rig.sensor.capture(self.settings.n_blank)
                found = find_gel(
                    presser,
                    self.sensor,
                    start,
                    self.limits.floor_z,
                    blanks,
                    self.scene["plan"]["touch_search"],
                    float(self.scene["probe"]["radius_mm"]),
                )
            except BaseException as exc:
                outcome = self._make_safe(exc)
                self._set(
                    find_state={"state": "failed", "presses": presser.presses, "why": str(exc)},
                    message=f"finding the gel stopped: {outcome}",
                )
                raise
            sensor = with_mount(self.sensor, found.mount.as_dict())
            limits = limits_of(sensor, measured=True)
            printer.move_to(z=limits.safe_z, feed_mm_s=self.settings.plunge_feed_mm_s)
            printer.wait_until_idle()
            self._set(
                found=found.mount,
                saved=None,
                limits=limits,
                blank=blanks.astype(np.float32).mean(axis=0),
                find_state={
                    "state": "found",
                    "presses": found.presses,
                    "touch_presses": found.touch_presses,
                    "contact_px": [round(v, 2) for v in found.contact_px],
                },
                message=f"gel found in {found.presses} presses: save the mount",
            )
            self._capture(rig)

        self._start("find", work, wait)

    def _seen_press(self, frame: np.ndarray, xyz) -> None:
        self._see(frame, xyz)
        with self._state:
            self.find_state = {**self.find_state, "presses": self.find_state.get("presses", 0) + 1}

    def collect(self, wait: bool = False) -> None:
        """Start the scene's collection on this rig (the config as it is on disk now)."""
        scene = self._load_scene()
        if self.found is not None:
            given = scene_mount_values(scene, f"scenes.{self.name}")
            found = self.found.as_dict()
            if any(
                abs(given.get(k, math.inf) - v) > 1e-4
                for k, v in found.items()
                if k != "z_clearance_mm"
            ):
                raise Refused(
                    "collect refused: the scene's mount is not the one found here; save the mount "
                    "(or paste it into the scene) first"
                )
        prepared = prepare(scene, source=f"scenes.{self.name}")  # every check before any motion
        total = len(prepared.plan)

        def on_row(rows: int, samples, xyz) -> None:
            if samples is not None:
                self._see(samples[-1], xyz)
            with self._state:
                self.collection = {**self.collection, "rows_done": rows}
            self._check_stop()

        def work(rig) -> None:
            self._set(
                collection={
                    "state": "running",
                    "rows_done": 0,
                    "rows_total": total,
                    "started": time.monotonic(),
                    "store": str(self.store),
                },
                message=f"collecting {total} plan rows into {self.store}",
            )
            try:
                summary = collect_scene(self.name, scene, self.store, rig=rig, on_row=on_row)
            except BaseException as exc:
                with self._state:
                    self.collection = {
                        **self.collection,
                        "state": "stopped" if isinstance(exc, KeyboardInterrupt) else "failed",
                        "why": str(exc),
                    }
                self.scene, self.sensor = scene, prepared.sensor
                raise
            with self._state:
                self.collection = {
                    **self.collection,
                    "state": "done",
                    "rows_done": total,
                    "summary": {
                        k: summary[k] for k in ("points", "frames", "duration_s") if k in summary
                    },
                }
                self.message = f"collected: {self.store}"
            self.scene, self.sensor = scene, prepared.sensor

        self._start("collect", work, wait)

    # ---- stopping ------------------------------------------------------------------------
    def stop(self, reason: str = "the page's stop button") -> None:
        """End a job at its next press, or make the rig safe now: the probe lifted, the steppers
        released (threedcal.collect.run.make_safe)."""
        self._stop.set()
        self._set(message=f"stopping: {reason}")
        job = self.job
        if job is not None and job.is_alive():
            job.join()  # its own handler has lifted the probe (collect's make_safe, or ours)
            self._set(message=f"stopped ({reason}): the probe is lifted, the steppers released")
            return
        with self.lock:
            self._set(busy="stop")
            try:
                outcome = self._make_safe(StoppedFromPage(reason))
            finally:
                self._set(busy=None)
        self._set(message=f"stopped ({reason}): {outcome}")

    def _make_safe(self, cause: BaseException | str) -> str:
        """Lift and release as a stopped collection does; the caller holds the printer."""
        if self.rig is None:
            return "the rig is closed"
        cause = StoppedFromPage(cause) if isinstance(cause, str) else cause
        return make_safe(
            self.rig.printer, self.limits.safe_z, self.settings.plunge_feed_mm_s, cause
        )

    # ---- the mount -----------------------------------------------------------------------
    def _about(self) -> str:
        return (
            f"mount of sensor {self.sensor['name']} on printer {self.scene['printer']}, found by "
            f"`threedcal rig` (scene {self.name}) on {time.strftime('%Y-%m-%d %H:%M')}"
        )

    def save_mount(self, replace: bool = False) -> dict[str, Any]:
        """Write the found mount where the scene's `mount` names a file; where it names none,
        the YAML to paste into the scene (nothing is written)."""
        if self.found is None:
            raise Refused("save refused: no mount found yet (find the gel first)")
        target = self.scene.get("mount")
        text = mount_yaml(self.found, self._about())
        if not isinstance(target, str):
            self._set(message="paste the mount into the scene (it names no mount file)")
            return {"written": None, "yaml": text}
        try:
            kept = write_mount_file(target, self.found, self._about(), replace=bool(replace))
        except ConfigError as exc:
            raise Refused(f"save refused: {exc}") from None
        sensor = scene_sensor(self.scene, f"scenes.{self.name}")  # the scene now reads this file
        self._set(
            saved=target,
            sensor=sensor,
            message=f"mount saved to {target}" + (f" (the old one kept as {kept})" if kept else ""),
        )
        return {"written": target, "kept": None if kept is None else str(kept), "yaml": text}
