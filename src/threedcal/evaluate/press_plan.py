"""Test objects pressed by the printer: what is pressed where, and where that lands in the image.

The paper pressed its test objects by hand and aligned the ground truth to each prediction. Here
the object takes the ball's place on the print head (`pressing.mount`: where its press-frame origin
sits relative to the probe tip, and how it is turned) and the printer presses it at planned poses,
so the ground truth can be placed where the printer says: x, y through the scene's registration,
depth = the registered gel surface − where the commanded Z puts the object's lowest point
(`PrinterFrame`).

Two sessions, each its own seed stream (`pressing.seed`, apart from the calibration's): `tuning`
presses, which settings may be chosen on, and `reporting` presses, which are only ever reported.
Every draw of the pressing streams is made here: the plan, and on the simulated bench each
session's camera noise and lighting and each object's true mount. See docs/explanation/objects.md.
"""

from __future__ import annotations

import functools
import json
import math
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from threedcal.errors import ConfigError
from threedcal.evaluate.objects import load_object, object_label
from threedcal.rig import RigSettings

SETS = ("tuning", "reporting")  # settings may be chosen on the first, never on the second
# The simulated bench's default mount: the object's origin exactly where the ball's tip was.
SIM_MOUNT = {"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0, "rotation_deg": 0.0}
_TAG = 0x0B1EC7  # every pressing draw: SeedSequence([pressing seed, _TAG, set, what, ...])
_PLAN, _MOUNT, _SESSION = 1, 2, 3
_FLIP_Y = np.diag([1.0, -1.0])  # press frame (x, y down as the image shows) → printer (X, Y up)


@dataclass(frozen=True)
class Mount:
    """How an object sits on the head: its press-frame origin relative to the probe tip (printer
    X, Y, Z in mm) and its turn in the press frame's convention (clockwise as the image shows it
    under the nominal seating)."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    z_mm: float = 0.0
    rotation_deg: float = 0.0

    @property
    def offset_mm(self) -> tuple[float, float, float]:
        return (self.x_mm, self.y_mm, self.z_mm)


@dataclass(frozen=True)
class ObjectsSetup:
    """What pressing and scoring a scene's test objects read of it, as the study layer parsed it
    (threedcal.study.scene.objects_setup)."""

    sensor: Mapping  # the sensor profile, seated as the scene's mount says
    printer: Mapping | None  # the printer profile (the presses need it, the scoring not)
    mount: Mount  # where an object sits on the head
    seed: int  # the pressing streams' seed
    objects: tuple[str, ...]  # built-in names or mesh files
    pressing: Mapping  # the scene's `pressing` section
    integrators: tuple[str, ...]  # the depth integrators scored
    rig: RigSettings  # the rig the presses run on


@functools.lru_cache(maxsize=16)
def object_mesh(ref: str):
    """The object's mesh, built (or read) once per process: planning, the bench and the scoring
    all need it."""
    return load_object(ref)


def _rng(seed: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), _TAG, *keys]))


def _key(name: str) -> int:
    return zlib.crc32(str(name).encode())


@dataclass(frozen=True)
class ObjectPress:
    """One planned press: where the object's origin goes (plan mm) and how deep (mm) it is meant."""

    object: str  # built-in name or STL path
    set: str  # tuning | reporting
    number: int  # the object's n-th press of its set (0 first)
    x_mm: float
    y_mm: float
    depth_mm: float


def plan_presses(objects: Sequence[str], sensor: Mapping, pressing: Mapping, seed: int) -> list:
    """Every object pressed `tuning_presses` then `presses` times, each its own draw.

    The origin lands within `offset_fraction` of the camera's field of view (profile image size
    over px_per_mm) from the probe area's centre, at `depth_mm` · (1 ± `depth_jitter`). Each press
    is drawn from (seed, set, object, number) alone: more presses or objects keep the earlier
    ones, and the sets share no draw.
    """
    width, height = (float(v) for v in sensor["probing"]["plan_area_mm"])
    view = np.array([sensor["image"]["width_px"], sensor["image"]["height_px"]], dtype=float)
    view /= float(sensor["px_per_mm"])
    presses = []
    for set_index, name in enumerate(SETS):
        count = int(pressing["tuning_presses" if name == "tuning" else "presses"])
        for ref in objects:
            for number in range(count):
                rng = _rng(seed, set_index, _PLAN, _key(ref), number)
                dx, dy = rng.uniform(-1, 1, 2) * float(pressing["offset_fraction"]) * view
                jitter = float(rng.uniform(-1, 1)) * float(pressing["depth_jitter"])
                presses.append(
                    ObjectPress(
                        object=str(ref),
                        set=name,
                        number=number,
                        x_mm=float(np.clip(width / 2 + dx, 0.0, width)),
                        y_mm=float(np.clip(height / 2 + dy, 0.0, height)),
                        depth_mm=float(pressing["depth_mm"]) * (1 + jitter),
                    )
                )
    return presses


def read_registration(path: str | Path) -> dict:
    """registration.json of the dataset stage: the affine and the first-touch height it needs."""
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot read the registration ({exc})") from exc
    affine = np.asarray(record.get("affine_px_per_mm", []), dtype=float)
    if affine.shape != (2, 3) or not np.all(np.isfinite(affine)):
        raise ConfigError(f"{path}: affine_px_per_mm must be a finite 2 x 3 matrix")
    if "contact_z_mm" not in record and "touch_offset_mm" not in record:
        raise ConfigError(f"{path}: needs contact_z_mm or touch_offset_mm (first-touch height)")
    return record


@dataclass(frozen=True)
class Placement:
    """Where the printer says the object is: image pose (frame pixels) and depth below the gel."""

    center_px: tuple[float, float]
    linear_px_per_mm: np.ndarray  # object press-frame mm → frame pixels
    depth_mm: float

    @property
    def rotation_deg(self) -> float:
        return math.degrees(math.atan2(self.linear_px_per_mm[1, 0], self.linear_px_per_mm[0, 0]))

    def at_scale(self, factor: float) -> Placement:
        """The same pose on a frame average-pooled by `factor` (pixel-centre convention)."""
        cx, cy = ((c + 0.5) / factor - 0.5 for c in self.center_px)
        return Placement((cx, cy), self.linear_px_per_mm / factor, self.depth_mm)


class PrinterFrame:
    """Plan ↔ printer ↔ image for a mounted object, from what a user knows: the sensor profile,
    the registration (affine, first-touch height) and the mount key."""

    def __init__(self, sensor: Mapping, registration: Mapping, mount: Mount):
        self.sensor = sensor
        self.mount = mount
        self.affine = np.asarray(registration["affine_px_per_mm"], dtype=float)
        touch = registration.get("contact_z_mm")
        if touch is None:
            touch = float(sensor["mount"]["z_touch_mm"]) + float(registration["touch_offset_mm"])
        self.contact_z_mm = float(touch)  # where the gel's apex is first touched (printer Z)
        self.px_per_mm = math.sqrt(abs(np.linalg.det(self.affine[:, :2])))
        c, s = (
            math.cos(math.radians(mount.rotation_deg)),
            math.sin(math.radians(mount.rotation_deg)),
        )
        # object press frame → printer offsets (the mount), then → image pixels (the registration)
        self.linear = self.affine[:, :2] @ _FLIP_Y @ np.array([[c, -s], [s, c]])

    def image_px(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        col, row = self.affine[:, :2] @ np.array([x_mm, y_mm]) + self.affine[:, 2]
        return float(col), float(row)

    def sag_mm(self, col: float, row: float) -> float:
        """How far the undeformed gel at image (col, row) lies below its apex (profile `gel.dome`)."""
        dome = self.sensor["gel"].get("dome")
        if not dome:
            return 0.0
        image = self.sensor["image"]
        u = (col - (image["width_px"] - 1) / 2) / self.px_per_mm - dome.get("apex_x_mm", 0.0)
        v = (row - (image["height_px"] - 1) / 2) / self.px_per_mm - dome.get("apex_y_mm", 0.0)
        return float(dome["kx_per_mm"] * u * u + dome["ky_per_mm"] * v * v)

    def origin_printer(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """Plan-relative x, y → printer X, Y (the sensor profile's mount offsets)."""
        mount = self.sensor["mount"]
        return float(mount["x_offset_mm"]) + x_mm, float(mount["y_offset_mm"]) + y_mm

    def target(self, press: ObjectPress) -> tuple[float, float, float]:
        """Head X, Y, Z that put the object's origin over the plan point, `depth_mm` into the gel
        (to the micrometre, as the G-code carries it)."""
        x, y = self.origin_printer(press.x_mm, press.y_mm)
        surface = self.contact_z_mm - self.sag_mm(*self.image_px(x, y))
        head = (
            x - self.mount.x_mm,
            y - self.mount.y_mm,
            surface - press.depth_mm - self.mount.z_mm,
        )
        return tuple(round(v, 3) for v in head)

    def clearance_z(self) -> float:
        """Head Z with the object's lowest point `z_clearance_mm` above the gel's apex."""
        return self.contact_z_mm + float(self.sensor["mount"]["z_clearance_mm"]) - self.mount.z_mm

    def placement(self, head_mm: Sequence[float]) -> Placement:
        """The printer protocol's ground-truth pose for the head at `head_mm` (commanded X, Y, Z)."""
        x, y, z = (float(v) for v in head_mm)
        center = self.image_px(x + self.mount.x_mm, y + self.mount.y_mm)
        depth = self.contact_z_mm - self.sag_mm(*center) - (z + self.mount.z_mm)
        return Placement(center, self.linear, depth)


def check_presses(
    presses: Sequence[ObjectPress],
    frame: PrinterFrame,
    sensor: Mapping,
    printer: Mapping | None,
    source: str = "scene",
) -> None:
    """Everything that can be wrong before the printer moves; each error names its key."""
    gel_w, gel_h = float(sensor["gel"]["width_mm"]), float(sensor["gel"]["height_mm"])
    theta = math.radians(frame.mount.rotation_deg)
    turn = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    for ref in dict.fromkeys(p.object for p in presses):
        xy = object_mesh(ref).vertices[:, :2] @ turn.T
        span_x, span_y = np.ptp(xy, axis=0)
        if span_x > gel_w or span_y > gel_h:
            raise ConfigError(
                f"{source}.objects: {object_label(ref)} spans {span_x:.2f} x {span_y:.2f} mm as "
                f"mounted (pressing.mount.rotation_deg {frame.mount.rotation_deg:g}), larger than "
                f"the gel of sensor {sensor['name']!r} ({gel_w:g} x {gel_h:g} mm: gel.width_mm x "
                "gel.height_mm)"
            )
    limit = float(sensor["gel"]["max_penetration_mm"])
    for press in presses:
        if not (math.isfinite(press.depth_mm) and 0 < press.depth_mm <= limit):
            raise ConfigError(
                f"{source}.pressing.depth_mm: {press.object} {press.set} press {press.number} goes "
                f"{press.depth_mm:.3f} mm deep (depth_mm x (1 + depth_jitter)), beyond the "
                f"maximum penetration {limit:g} mm of sensor {sensor['name']!r} "
                "(gel.max_penetration_mm)"
            )
    if printer is None:
        return
    travel = printer["travel_mm"]
    targets = [frame.target(p) for p in presses]
    targets.append((targets[0][0], targets[0][1], frame.clearance_z()))
    for target in targets:
        for axis, value in zip("xyz", target, strict=True):
            if not 0.0 <= value <= float(travel[axis]):
                raise ConfigError(
                    f"{source}.pressing: head {axis.upper()}={value:.3f} mm lies outside the "
                    f"travel 0..{travel[axis]:g} mm of printer {printer['name']!r} (check "
                    "pressing.mount and the sensor's mount offsets)"
                )


def session_draws(seed: int, set_index: int, lighting_drift: float) -> tuple[int, list[float]]:
    """A session's camera-noise seed and its per-channel lighting gain (1 ± `lighting_drift`)."""
    rng = _rng(seed, set_index, _SESSION)
    noise_seed = int(rng.integers(2**31))
    gain = (1.0 + rng.uniform(-1, 1, 3) * float(lighting_drift)).tolist()
    return noise_seed, gain


def true_mount(mount: Mount, errors: Mapping, seed: int, set_index: int, ref: str) -> Mount:
    """Where the bench really holds the object this session: the key's mount off by hidden draws
    within `pressing.bench`'s magnitudes (each mounting its own draw)."""
    rng = _rng(seed, set_index, _MOUNT, _key(ref))
    dx, dy = rng.uniform(-1, 1, 2) * float(errors["mount_offset_mm"])
    dz = float(rng.uniform(-1, 1)) * float(errors["mount_z_mm"])
    dr = float(rng.uniform(-1, 1)) * float(errors["mount_rotation_deg"])
    return Mount(mount.x_mm + dx, mount.y_mm + dy, mount.z_mm + dz, mount.rotation_deg + dr)
