"""Find the gel: where the sensor sits under the probe, from presses alone.

From wherever the user left the ball (over the gel, not touching it): blank frames there; down in
coarse steps until the image changes (ChangeDetector, the touch search's own noise model); a
press, its contact located (threedcal.dataset.contacts) and the head moved until the contact lies
at the image centre, which the probe area's centre is imaged at; then the touch search at that
centre, bisecting (threedcal.dataset.touch.TouchBisection: `presses` presses a place, 8 by
default, whatever method the scene's collection uses; called in `touch_search_at` alone). The
answer is a Mount: the probe area's origin and the first-touch Z. Every press stays above the
floor the sensor profile allows.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from threedcal.collect.plan import plan_to_printer, touch_search_plan, touch_search_range
from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.touch import ChangeDetector, planned_touch_search
from threedcal.errors import ThreedcalError
from threedcal.mount import SensorMount, with_mount

# The descent's step: the ball sinks at most this far past the touch before the change is seen.
COARSE_STEP_MM = 0.1
# Pixels over the change detector's threshold that make a contact (its false alarms are ~1e-6 a pixel).
CONTACT_PIXELS = 12
# How deep the centring presses go past the first change: a contact of about 1.4 mm radius with
# a 2 mm ball, large enough to locate to a tenth of a pixel, small enough to lie whole in the frame.
CENTRING_DEPTH_MM = 0.5
# Centring stops once a move is shorter than this, or after CENTRING_ROUNDS presses.
CENTRED_MM = 0.01
CENTRING_ROUNDS = 5


class GelNotFound(ThreedcalError):
    """The presses did not find the gel where the user left the probe."""


@dataclass(frozen=True)
class GelFound:
    mount: SensorMount
    contact_px: tuple[float, float]  # the last centring press's contact
    touch_offset_mm: float  # the touch search's δ against the descent's estimate
    presses: int
    touch_presses: int  # of them, the touch search's


@dataclass
class Presser:
    """How the search moves and looks: the printer (threedcal.hardware.printer.MarlinHost), the
    camera (flush, capture), the settling wait, feeds, and hooks for a watcher."""

    printer: object
    camera: object
    sleep: Callable[[float], None]
    plunge_feed_mm_s: float
    travel_feed_mm_s: float
    settle_s: float
    seen: Callable[[np.ndarray, tuple], None] = lambda frame, xyz: None  # each press's last frame
    check_stop: Callable[[], None] = lambda: None  # raises to stop between presses
    presses: int = 0

    def press(self, x: float, y: float, z: float, lift_z: float, frames: int = 1) -> np.ndarray:
        """Lift to `lift_z`, travel to (x, y), press down to `z`, settle; the mean frame."""
        self.check_stop()
        printer = self.printer
        printer.move_to(z=lift_z, feed_mm_s=self.plunge_feed_mm_s)
        printer.move_to(x=x, y=y, feed_mm_s=self.travel_feed_mm_s)
        printer.move_to(z=z, feed_mm_s=self.plunge_feed_mm_s)
        printer.wait_until_idle()
        self.sleep(self.settle_s)
        self.camera.flush()
        taken, _ = self.camera.capture(frames)
        self.presses += 1
        self.seen(taken[-1], (x, y, z))
        return taken.mean(axis=0).astype(np.float32) if frames > 1 else taken[0]


def find_gel(
    presser: Presser,
    sensor: Mapping,
    start_xyz: tuple[float, float, float],
    floor_z: float,
    blank_frames: np.ndarray,
    search: Mapping,
    probe_radius_mm: float,
) -> GelFound:
    """The Mount of the sensor under the probe, which the user left at `start_xyz` above the gel.
    `floor_z`: no press goes lower. `search`: the scene's plan.touch_search (step_mm, beyond_mm,
    frames). `sensor`: its profile (image size, px_per_mm, probe area, clearance)."""
    x, y, z_start = (float(v) for v in start_xyz)
    detector = ChangeDetector.from_blanks(blank_frames)
    blank = np.asarray(blank_frames, dtype=np.float32).mean(axis=0)
    onset = _descend(presser, detector, x, y, z_start, floor_z)
    lift = onset + COARSE_STEP_MM + float(sensor["probing"].get("hop_mm", 0.5))
    press_z = max(onset - CENTRING_DEPTH_MM, floor_z)
    x, y, contact = _centre(presser, sensor, blank, x, y, press_z, lift)
    width, height = sensor["probing"]["plan_area_mm"]
    nominal = SensorMount(
        x - width / 2,
        y - height / 2,
        onset + COARSE_STEP_MM / 2,
        float(sensor["mount"]["z_clearance_mm"]),
    )
    before = presser.presses
    offset = touch_search_at(
        presser,
        with_mount(sensor, nominal.as_dict()),
        search,
        blank_frames,
        probe_radius_mm,
        floor_z,
    )
    found = SensorMount(
        nominal.x_offset_mm,
        nominal.y_offset_mm,
        nominal.z_touch_mm + offset,
        nominal.z_clearance_mm,
    )
    return GelFound(found, contact, offset, presser.presses, presser.presses - before)


def _descend(presser: Presser, detector: ChangeDetector, x, y, z_start, floor_z) -> float:
    """The Z of the first coarse step whose frame shows a contact."""
    z = z_start - COARSE_STEP_MM
    while z >= floor_z - 1e-9:
        frame = presser.press(x, y, z, lift_z=z + COARSE_STEP_MM)
        if int((detector.significance(frame) > detector.threshold).sum()) >= CONTACT_PIXELS:
            return z
        z -= COARSE_STEP_MM
    raise GelNotFound(
        f"no contact down to Z={floor_z:g} mm, the lowest the sensor profile allows here: is the "
        "ball over the gel? Jog it over the gel's middle (or set the scene's mount.z_touch_mm "
        "nearer the truth) and try again"
    )


def _centre(presser, sensor, blank, x, y, press_z, lift_z):
    """Move the press until its contact lies at the image centre; the head's (x, y) then and the
    contact's pixel centre."""
    scale = float(sensor["px_per_mm"])
    centre_col = (sensor["image"]["width_px"] - 1) / 2
    centre_row = (sensor["image"]["height_px"] - 1) / 2
    contact = None
    for _ in range(CENTRING_ROUNDS):
        frame = presser.press(x, y, press_z, lift_z=lift_z, frames=2)
        contact = locate_contact(frame, blank)
        if contact is None:
            raise GelNotFound(
                f"the press at X={x:.2f} Y={y:.2f} mm shows no whole contact: jog the ball nearer "
                "the middle of the image and try again"
            )
        # printer +X runs along the columns, printer +Y up the image (threedcal.sim.bench)
        dx = (contact.x_px - centre_col) / scale
        dy = -(contact.y_px - centre_row) / scale
        x, y = x - dx, y - dy
        if np.hypot(dx, dy) < CENTRED_MM:
            break
    return x, y, (contact.x_px, contact.y_px)


def touch_search_at(
    presser: Presser,
    sensor: Mapping,
    search: Mapping,
    blank_frames: np.ndarray,
    probe_radius_mm: float,
    floor_z: float,
) -> float:
    """δ (true first touch = the sensor's mount.z_touch_mm + δ) from a bisecting touch search
    about the probe area's centre: `search`'s places, presses and frames (the scene's plan.touch_search), each press's depth decided from the frames before
    it, as a quick collection's search is."""
    search = {**search, "method": "bisect", "points": max(int(search.get("points", 1)), 1)}
    rows = touch_search_plan(sensor, search)
    mount = sensor["mount"]
    lift_z = mount["z_touch_mm"] + float(sensor["probing"].get("touch_uncertainty_mm", 0.2)) + 0.5
    deepest = [plan_to_printer(sensor, r.x_mm, r.y_mm, r.depth_mm)[2] for r in rows.itertuples()]
    if min(deepest) < floor_z:
        raise GelNotFound(
            f"the touch search would press below Z={floor_z:g} mm, the lowest the sensor profile "
            "allows: lower plan.touch_search.beyond_mm or probing.touch_uncertainty_mm"
        )
    low, high = touch_search_range(sensor, search)
    xy = rows[["x_mm", "y_mm"]].to_numpy(float)
    bisection = planned_touch_search(
        xy, rows["depth_mm"].to_numpy(float), low, high, float(sensor["px_per_mm"]), probe_radius_mm
    )
    bisection.begin(np.asarray(blank_frames))
    for k, (x_mm, y_mm) in enumerate(xy):
        depth = bisection.depth(k)
        x, y, z = plan_to_printer(sensor, x_mm, y_mm, depth)
        frames = int(rows["frames"].iloc[k])
        frame = presser.press(x, y, z, lift_z=lift_z, frames=frames)
        bisection.observe(k, depth, frame[None])
    return float(bisection.result().offset_mm)
