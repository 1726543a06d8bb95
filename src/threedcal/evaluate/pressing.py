"""Test objects pressed by the printer, then scored as the printer placed them (Sec. IV, Table II).

The paper pressed its test objects by hand and aligned the ground truth to each prediction. Here
the object takes the ball's place on the print head (`pressing.mount`: where its press-frame origin
sits relative to the probe tip, and how it is turned) and the printer presses it at planned poses,
so the ground truth can be placed where the printer says: x, y through the scene's registration,
depth = the registered gel surface − where the commanded Z puts the object's lowest point.

Two sessions, each its own seed stream (`pressing.seed`, apart from the calibration's): `tuning`
presses, which settings may be chosen on, and `reporting` presses, which are only ever reported. A
session on the simulated bench is a later session on the same, still seated sensor: the same gel
and paint, fresh camera noise, a lighting drift and a blank captured at its start; each object is
mounted anew (its true mount off the `pressing.mount` key by hidden errors). See docs/objects.md.

`press_objects` runs the presses (bench or real rig) and keeps one frame per press;
`evaluate_objects` scores every model's depth under both protocols (`printer`, `paper`).
"""

from __future__ import annotations

import functools
import json
import logging
import math
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.config import mount_problem
from threedcal.dataset.trainset import pool_to
from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import HeightMap, dome_rise, surface_height
from threedcal.evaluate.objects import load_object as _load_object
from threedcal.evaluate.objects import object_label
from threedcal.lens import RadialLens, rectify_if

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


def scene_mount(scene: Mapping, source: str = "scene") -> Mount:
    """`pressing.mount`; on the simulated bench it defaults to `SIM_MOUNT`, a real rig must say."""
    problem = mount_problem(scene)
    if problem:
        raise ConfigError(f"{source}.{problem}")
    mount = scene.get("pressing", {}).get("mount") or SIM_MOUNT
    return Mount(**{k: float(mount.get(k, 0.0)) for k in asdict(Mount())})


def pressing_seed(scene: Mapping) -> int:
    """`pressing.seed`, else the scene's: either way drawn through the pressing streams only."""
    return int(scene.get("pressing", {}).get("seed", scene["seed"]))


@functools.lru_cache(maxsize=16)
def load_object(ref: str):
    """The object's mesh, built (or read) once per process: planning, the bench and the scoring
    all need it."""
    return _load_object(ref)


def _rng(seed: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), _TAG, *keys]))


def _key(name: str) -> int:
    return zlib.crc32(str(name).encode())


@dataclass(frozen=True)
class Press:
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
                    Press(
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

    def target(self, press: Press) -> tuple[float, float, float]:
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
    presses: Sequence[Press],
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
        xy = load_object(ref).vertices[:, :2] @ turn.T
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


# ---------------------------------------------------------------------------------- the presses
def relief_indenter(mesh, px_per_mm: float, rotation_deg: float = 0.0):
    """The mesh as the simulator's height-map indenter: protrusion toward the gel (mm), NaN outside."""
    from threedcal.sim.indenters import HeightMap as Relief

    extent = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    size = int(math.ceil(extent * math.sqrt(2) * px_per_mm)) + 5
    surface = surface_height(
        mesh, (size, size), px_per_mm, ((size - 1) / 2, (size - 1) / 2), rotation_deg
    )
    relief = np.where(surface.covered, -surface.height_mm, np.nan)
    return Relief(relief, px_per_mm)


@dataclass
class SessionResult:
    blank: np.ndarray  # float32 (H, W, 3): mean of the session's blank frames
    frames: list  # one uint8 frame per press
    records: list  # per press: commanded and reported head position (+ bench truth)
    printer_s: float  # the printer's clock over the session


def run_session(
    host,
    camera,
    clock,
    presses: Sequence[Press],
    frame: PrinterFrame,
    settings,
    *,
    mount_object: Callable[[str], None],
    truth: Callable[[], dict] | None = None,
    hardware_clock: Callable[[], float] | None = None,
    progress: bool = True,
) -> SessionResult:
    """Home, capture the session's blank, then object by object: mount it, press it at each of its
    poses (lift → travel → plunge → wait → settle → flush → one frame), lift."""
    from tqdm import tqdm

    hardware_clock = hardware_clock or clock.now
    started = hardware_clock()
    safe_z = frame.clearance_z()
    host.home()
    host.hold_motors()
    width, height = (float(v) for v in frame.sensor["probing"]["plan_area_mm"])
    cx, cy = frame.origin_printer(width / 2, height / 2)
    host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
    host.move_to(x=cx, y=cy, feed_mm_s=settings.travel_feed_mm_s)
    host.wait_until_idle()
    clock.sleep(settings.settle_s)
    camera.flush()
    blank, _ = camera.capture(settings.n_blank)
    frames, records = [], []
    mounted = None
    for press in tqdm(presses, desc="presses", unit="press", disable=not progress):
        if press.object != mounted:
            host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
            host.wait_until_idle()
            mount_object(press.object)
            mounted = press.object
        x, y, z = frame.target(press)
        host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
        host.move_to(x=x, y=y, feed_mm_s=settings.travel_feed_mm_s)
        host.move_to(z=z, feed_mm_s=settings.plunge_feed_mm_s)
        host.wait_until_idle()
        clock.sleep(settings.settle_s)
        reported = host.position()
        camera.flush()
        shot, _ = camera.capture(1)
        frames.append(np.asarray(shot[0]))
        # where the steppers are (M114 counts): the commanded pose to within half a step
        steps = reported.steps_mm or (math.nan,) * 3
        record = {"cmd_x_mm": x, "cmd_y_mm": y, "cmd_z_mm": z}
        for axis, at, step in zip("xyz", reported, steps, strict=True):
            record[f"reported_{axis}_mm"] = at
            record[f"steps_{axis}_mm"] = step
        if truth is not None:
            record["truth"] = truth()
        records.append(record)
    host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
    host.wait_until_idle()
    blank = np.asarray(blank, dtype=np.float32).mean(axis=0)
    return SessionResult(blank, frames, records, hardware_clock() - started)


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


def press_objects(
    scene: Mapping,
    registration_path: str | Path,
    out_dir: str | Path,
    *,
    name: str = "scene",
    progress: bool = True,
) -> dict:
    """The `object_presses` rule: both sessions of presses, on the bench (port sim) or a real rig.

    Writes `frames.npz` (frames, one per press, and each session's blank), `plan.csv` (each press:
    object, set, plan pose, commanded and reported head position), `truth.json` (what the bench
    really did, for reporting only; `{"simulated": false}` on a real rig) and `summary.json` (cost).
    """
    from threedcal.collect.run import MotionSettings
    from threedcal.profiles import load_profile

    source = f"scenes.{name}"
    sensor = load_profile("sensor", scene["sensor"])
    if sensor.get("type") != "vision":
        raise ConfigError(f"{source}: test objects need a vision sensor, not {sensor['name']!r}")
    printer = load_profile("printer", scene["printer"])
    mount = scene_mount(scene, source)
    if scene.get("port", "sim") != "sim" and str(scene.get("camera", "sim")) == "sim":
        raise ConfigError(
            f"{source}.camera: port {scene['port']!r} is a real printer but camera is 'sim': give "
            "the sensor's video device (index or /dev/v4l/by-id path), or use port: sim"
        )
    frame = PrinterFrame(sensor, read_registration(registration_path), mount)
    seed = pressing_seed(scene)
    presses = plan_presses(scene["objects"], sensor, scene["pressing"], seed)
    check_presses(presses, frame, sensor, printer, source)  # before anything moves
    settings = MotionSettings.from_profile(sensor)
    started = time.perf_counter()
    if scene.get("port", "sim") == "sim":
        results, truth = _press_on_bench(scene, sensor, printer, frame, presses, seed, progress)
    else:
        results, truth = _press_on_rig(scene, sensor, printer, frame, presses, settings, progress)
    seconds = time.perf_counter() - started
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    frames = []
    for press, (record, image) in zip(
        presses,
        [(r, f) for s in SETS for r, f in zip(results[s].records, results[s].frames, strict=True)],
        strict=True,
    ):
        rows.append(
            {
                "frame": len(frames),
                "object": press.object,
                "label": object_label(press.object),
                "set": press.set,
                "press": press.number,
                "x_mm": press.x_mm,
                "y_mm": press.y_mm,
                "depth_mm": press.depth_mm,
                **{k: v for k, v in record.items() if k != "truth"},
            }
        )
        frames.append(image)
    np.savez_compressed(
        out / "frames.npz",
        frames=np.stack(frames),
        blanks=np.stack([results[s].blank for s in SETS]),
        sets=np.array(SETS),
    )
    pd.DataFrame(rows).to_csv(out / "plan.csv", index=False)
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    summary = {
        "presses": len(presses),
        "seconds": round(seconds, 3),
        "seconds_per_press": round(seconds / max(len(presses), 1), 4),
        "printer_s": {s: round(results[s].printer_s, 1) for s in SETS},
        "printer_s_per_press": round(
            sum(results[s].printer_s for s in SETS) / max(len(presses), 1), 2
        ),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _press_on_bench(scene, sensor, printer, frame, presses, seed, progress):
    """The simulated bench, seated as in the calibration (same seed and bench settings)."""
    from threedcal.collect.run import MotionSettings
    from threedcal.hardware.printer import MarlinHost
    from threedcal.sim.bench import MountedObject, SimBench

    settings = MotionSettings.from_profile(sensor)
    hidden = scene["pressing"]["bench"]
    results, truth = {}, {"simulated": True, "sessions": {}, "presses": []}
    bench_settings = scene["bench"]
    with SimBench(
        sensor,
        scene["probe"]["radius_mm"],
        bench_settings,
        scene["seed"],
        printer=printer,
        faults=bench_settings.get("faults", ""),
        fault_rate=bench_settings.get("fault_rate", 0.0),
    ) as bench:
        reliefs = {}
        for set_index, name in enumerate(SETS):
            noise_seed, gain = session_draws(seed, set_index, hidden["lighting_drift"])
            bench.start_session(noise_seed, gain)
            mounts = {}

            def mount_object(ref, set_index=set_index, mounts=mounts):
                if ref not in reliefs:
                    reliefs[ref] = relief_indenter(load_object(ref), bench.gel.px_per_mm)
                real = true_mount(frame.mount, hidden, seed, set_index, ref)
                mounts[object_label(ref)] = asdict(real)
                bench.mount(MountedObject(reliefs[ref], real.offset_mm, real.rotation_deg))

            with MarlinHost(bench.url, printer) as host:
                results[name] = run_session(
                    host,
                    bench.camera,
                    bench.firmware.clock,
                    [p for p in presses if p.set == name],
                    frame,
                    settings,
                    mount_object=mount_object,
                    truth=lambda: dict(bench.last_render),
                    hardware_clock=bench.firmware.clock.now,
                    progress=progress,
                )
            bench.mount(None)
            truth["sessions"][name] = {"lighting_gain_rgb": gain, "mounts": mounts}
            truth["presses"] += [
                {
                    "center_px": list(r["truth"]["center_px"]),
                    "rotation_deg": r["truth"]["rotation_deg"],
                    "depth_mm": r["truth"]["depth_mm"],
                }
                for r in results[name].records
            ]
    return results, truth


def _press_on_rig(scene, sensor, printer, frame, presses, settings, progress):
    """A real printer and camera: the user mounts each object when asked."""
    from threedcal.collect.run import WallClock
    from threedcal.hardware.camera import OpenCVCamera
    from threedcal.hardware.printer import MarlinHost

    device = scene["camera"]
    if isinstance(device, str) and device.isdigit():
        device = int(device)
    mount = frame.mount

    def mount_object(ref: str) -> None:
        input(
            f"Mount {object_label(ref)} on the print head in place of the ball (origin at "
            f"{mount.x_mm:+.2f}, {mount.y_mm:+.2f}, {mount.z_mm:+.2f} mm from the probe tip, turned "
            f"{mount.rotation_deg:g} deg), then press Enter... "
        )

    results = {}
    with OpenCVCamera(sensor, device) as camera, MarlinHost(scene["port"], printer) as host:
        for name in SETS:
            results[name] = run_session(
                host,
                camera,
                WallClock(),
                [p for p in presses if p.set == name],
                frame,
                settings,
                mount_object=mount_object,
                progress=progress,
            )
    return results, {"simulated": False}


# ------------------------------------------------------------------------------------ scoring
def _checkpoint_estimator(model: str | Path, blank: np.ndarray):
    from threedcal.model.checkpoint import read_checkpoint
    from threedcal.model.inference import DepthEstimator

    checkpoint = read_checkpoint(model)
    shape = tuple(checkpoint.get("image_shape") or np.asarray(checkpoint["blank"]).shape[:2])
    return DepthEstimator(checkpoint, device="cpu", blank=pool_to(blank, shape))


def read_presses(pressing_dir: str | Path) -> tuple[pd.DataFrame, np.ndarray, dict, dict]:
    """The object_presses outputs: plan table, frames, a blank per session, the bench truth."""
    pressing_dir = Path(pressing_dir)
    plan = pd.read_csv(pressing_dir / "plan.csv")
    with np.load(pressing_dir / "frames.npz") as data:
        frames = data["frames"]
        blanks = dict(zip(data["sets"].tolist(), data["blanks"], strict=True))
    truth = json.loads((pressing_dir / "truth.json").read_text())
    return plan, frames, blanks, truth


def evaluate_objects(
    scene: Mapping,
    models: Mapping[int, object | Sequence[object]],
    pressing_dir: str | Path,
    registration_path: str | Path,
    out_dir: str | Path,
    *,
    estimator: Callable = _checkpoint_estimator,
    plots: bool = True,
    progress: bool = True,
) -> pd.DataFrame:
    """Score every model's depth of every press under both protocols; write tables and figures.

    `models[p]` is one model or a list of them, one per ablation replicate (list position =
    replicate). `estimator(model, session_blank)` gives an object with `px_per_mm`, `image_shape`
    and `depth(frame, method=)` (a DepthEstimator by default). `plots=False` skips the figures
    (drawn from replicate 0). Every press is rendered once (by the object_presses rule); the
    printer protocol's ground truth is rasterised once per press and frame size. errors.csv:
    reporting presses only, per object, P and protocol, the mean over presses and replicates with
    its 95 % interval (`summarise`); tuning.csv: the same over the tuning presses, under the
    printer protocol only (the one settings are chosen on).
    """
    from tqdm import tqdm

    from threedcal.evaluate.object_errors import pixel_errors_um
    from threedcal.evaluate.object_figures import plot_depth_sections, plot_error_violins
    from threedcal.profiles import load_profile

    started = time.perf_counter()
    out_dir = Path(out_dir)
    figures = out_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    sensor = load_profile("sensor", scene["sensor"])
    limit = float(sensor["gel"]["max_penetration_mm"])
    dome = sensor["gel"].get("dome")  # the truth is the depth below the undeformed gel
    frame_map = PrinterFrame(
        sensor, read_registration(registration_path), scene_mount(scene, "scene")
    )
    plan, frames, blanks, truth = read_presses(pressing_dir)
    # into the ideal frame the models were trained in, through the lens the registration fitted
    lens = RadialLens.from_record(read_registration(registration_path).get("lens"))
    frames = rectify_if(lens, frames)
    blanks = {name: rectify_if(lens, blank) for name, blank in blanks.items()}
    true_presses = truth.get("presses") if truth.get("simulated") else None
    integrators = list(scene["integrators"])
    replicates = {p: list(m) if isinstance(m, (list, tuple)) else [m] for p, m in models.items()}
    fractions = sorted(replicates)
    full = fractions[-1]
    drawn = ", replicate 0" if any(len(v) > 1 for v in replicates.values()) else ""
    estimators = {
        (p, r, s): estimator(model, blanks[s])
        for p in fractions
        for r, model in enumerate(replicates[p])
        for s in SETS
        if s in blanks
    }
    meshes: dict[str, object] = {}
    truths: dict[tuple[int, tuple], HeightMap] = {}
    rows, comparison, pixel_tables = [], [], []
    pill_maps: dict[int, np.ndarray] = {}
    first_reporting = plan[plan["set"] == "reporting"].groupby("object")["frame"].min().to_dict()
    for press in tqdm(
        plan.itertuples(index=False), total=len(plan), desc="objects", disable=not progress
    ):
        mesh = meshes.setdefault(press.object, load_object(press.object))
        placed = frame_map.placement(head_position(press))
        facts = _press_facts(
            press, placed, None if true_presses is None else true_presses[press.frame]
        )
        image_full = frames[press.frame]
        for p, r in [(q, r) for q in fractions for r in range(len(replicates[q]))]:
            est = estimators[(p, r, press.set)]
            factor = image_full.shape[0] / est.image_shape[0]
            image = pool_to(image_full, est.image_shape)
            pose = placed.at_scale(factor)
            key = (press.frame, tuple(est.image_shape))
            if key not in truths:
                truths[key] = surface_height(
                    mesh,
                    est.image_shape,
                    1.0,
                    pose.center_px,
                    0.0,
                    pose.linear_px_per_mm,
                    dome=dome,
                )
            for k, method in enumerate(integrators if p == full else integrators[:1]):
                depth = est.depth(image, method=method)
                results = score_press(
                    depth,
                    mesh,
                    pose,
                    truths[key],
                    px_per_mm=est.px_per_mm,
                    max_penetration_mm=limit,
                    dome=dome,
                    # the paper's protocol for comparison on the reporting presses; the
                    # integrators are compared, and settings chosen, under the printer protocol
                    paper=k == 0 and press.set == "reporting",
                )
                for protocol, result in results.items():
                    row = {
                        "object": object_label(press.object),
                        "set": press.set,
                        "press": press.press,
                        "P": p,
                        "replicate": r,
                        "protocol": protocol,
                        **{m: result.errors[m] for m in SUMMARY_METRICS},
                        "depth_mm": result.indentation_mm,
                        "depth_ratio": result.indentation_mm / facts["true_depth_mm"]
                        if facts["true_depth_mm"] > 0
                        else float("nan"),
                        "shift_x_px": result.shift_px[0] * factor,
                        "shift_y_px": result.shift_px[1] * factor,
                        **facts,
                    }
                    if protocol == "printer":
                        comparison.append({**row, "integrator": method})
                    if k == 0:
                        rows.append(row)
                if k > 0 or r > 0 or press.set != "reporting" or not plots:
                    continue
                label = object_label(press.object)
                if p == full:
                    pixel_tables.append(pixel_errors_um(label, depth, results["printer"].gt_mm))
                    if press.frame == first_reporting[press.object]:
                        plot_depth_sections(
                            depth,
                            results["printer"].gt_mm,
                            figures / f"{label}_sections.png",
                            px_per_mm=est.px_per_mm,
                            title=f"{label}: P = {p} %{drawn}, {method}, printer protocol",
                        )
                if label == "pill" and press.frame == first_reporting[press.object]:
                    pill_maps[p] = depth
    per_press = pd.DataFrame(rows)
    per_press.to_csv(out_dir / "presses.csv", index=False)
    errors = summarise(per_press[per_press["set"] == "reporting"])
    errors.to_csv(out_dir / "errors.csv", index=False)
    summarise(per_press[per_press["set"] == "tuning"]).to_csv(out_dir / "tuning.csv", index=False)
    pd.DataFrame(comparison).to_csv(out_dir / "integrators.csv", index=False)
    if pixel_tables:
        plot_error_violins(
            pd.concat(pixel_tables),
            out_dir / "violins.png",
            title=f"pixelwise depth errors, P = {full} %{drawn}, printer protocol, "
            "reporting presses",
        )
    if pill_maps:
        pill_figure(pill_maps, figures / "pill_by_P.png")
    seconds = time.perf_counter() - started
    n_models = sum(len(v) for v in replicates.values())
    logging.getLogger("threedcal").info(
        "objects: %d presses x %d models scored under both protocols in %.1f s "
        "(%.2f s per press, %.3f s per press and model, figures included)",
        len(plan),
        n_models,
        seconds,
        seconds / max(len(plan), 1),
        seconds / max(len(plan) * n_models, 1),
    )
    return errors


def score_press(
    depth: np.ndarray,
    mesh,
    pose: Placement,
    surface: HeightMap,
    *,
    px_per_mm: float,
    max_penetration_mm: float,
    paper: bool = True,
    dome: Mapping | None = None,
) -> dict:
    """One predicted depth map under each protocol: {"printer": ..., "paper": ...}.

    `pose` and `surface`: where the printer put the object, on the prediction's pixel grid
    (`surface` measured from the gel's `dome` when it has one, as the paper protocol's rasters)."""
    from threedcal.evaluate.object_errors import evaluate_press, printer_press

    results = {
        "printer": printer_press(
            depth, surface, pose.depth_mm, max_penetration_mm=max_penetration_mm
        )
    }
    if paper:
        results["paper"] = evaluate_press(
            depth,
            mesh,
            px_per_mm=px_per_mm,
            nominal_indentation_mm=min(max(pose.depth_mm, 0.0), max_penetration_mm),
            max_penetration_mm=max_penetration_mm,
            center_px=pose.center_px,
            linear_px_per_mm=pose.linear_px_per_mm,
            surface=surface,
            dome=dome,
        )
    return results


def head_position(press) -> tuple[float, float, float]:
    """Where the printer says its head was: the stepper counts when M114 gave them, else the
    commanded position."""
    steps = (press.steps_x_mm, press.steps_y_mm, press.steps_z_mm)
    if all(math.isfinite(v) for v in steps):
        return steps
    return press.cmd_x_mm, press.cmd_y_mm, press.cmd_z_mm


def _press_facts(press, placed: Placement, true: Mapping | None) -> dict:
    """Registered (printer) pose of a press, and the bench's true one where there is a bench."""
    facts = {
        "registered_x_px": placed.center_px[0],
        "registered_y_px": placed.center_px[1],
        "registered_rotation_deg": placed.rotation_deg,
        "registered_depth_mm": placed.depth_mm,
        "true_x_px": float("nan"),
        "true_y_px": float("nan"),
        "true_rotation_deg": float("nan"),
        "true_depth_mm": float("nan"),
    }
    if true is not None:
        facts.update(
            true_x_px=float(true["center_px"][0]),
            true_y_px=float(true["center_px"][1]),
            true_rotation_deg=float(true["rotation_deg"]),
            true_depth_mm=float(true["depth_mm"]),
        )
    return facts


class TruthGradients:
    """A perfect model, for checking the protocols (never used by the stage): the exact gradients
    of the true surface of every rendered press — the CAD mesh where the bench's truth.json says
    it put it, differentiated at the pixel centres — integrated as a model's would be. It reads
    the simulator's hidden truth, so it can only diagnose, never be reported as a model."""

    def __init__(
        self,
        pressing_dir: str | Path,
        px_per_mm: float,
        step_px: float = 0.05,
        lens: RadialLens | None = None,
        dome: Mapping | None = None,
    ):
        """`lens`: the registration's (registration.json), through which `evaluate_objects`
        rectifies each frame before it asks for its depth; `dome`: the sensor's gel.dome, which
        the depth is measured from."""
        self.dome = dome
        plan, frames, _, truth = read_presses(pressing_dir)
        frames = rectify_if(lens, frames)
        if not truth.get("simulated"):
            raise ConfigError(f"{pressing_dir}: no bench truth (a real rig's presses)")
        self.px_per_mm = float(px_per_mm)
        self.image_shape = tuple(frames.shape[1:3])
        self._gradients = {}
        for row, frame, true in zip(plan.itertuples(), frames, truth["presses"], strict=True):
            mesh = load_object(row.object)
            # central differences well inside every facet: the gradient at the pixel centre
            at = [self._depth(mesh, true, d) for d in ((step_px, 0), (-step_px, 0))]
            at += [self._depth(mesh, true, d) for d in ((0, step_px), (0, -step_px))]
            scale = self.px_per_mm / (2 * step_px)
            self._gradients[frame.tobytes()] = ((at[0] - at[1]) * scale, (at[2] - at[3]) * scale)

    def _depth(self, mesh, true: Mapping, shift: tuple[float, float]) -> np.ndarray:
        """The true depth map sampled at (x, y) + `shift` px (the object moved by -shift; the dome,
        which stays put, sampled at the shifted points)."""
        cx, cy = true["center_px"]
        surface = surface_height(
            mesh,
            self.image_shape,
            self.px_per_mm,
            (cx - shift[0], cy - shift[1]),
            true["rotation_deg"],
        )
        height = surface.height_mm
        if self.dome:
            height = height + dome_rise(
                self.dome, (cx, cy), self.image_shape, self.px_per_mm, shift
            )
        return np.maximum(true["depth_mm"] - height, 0.0)

    def depth(self, frame: np.ndarray, method: str = "poisson_dst") -> np.ndarray:
        from threedcal.depth import integrate

        gx, gy = self._gradients[np.asarray(frame).tobytes()]
        return integrate(gx, gy, method=method, px_per_mm=self.px_per_mm)


SUMMARY_METRICS = ("overall_um", "type1_um", "type2_um")


def summarise(per_press: pd.DataFrame) -> pd.DataFrame:
    """Per object, P and protocol: the number of presses and replicate models, each metric's mean
    over both with its 95 % interval (`_lo`, `_hi`; `crossed_mean_interval`: presses and models
    both random, a t interval over presses when there is one replicate), and the mean depth ratio
    (protocol depth / true)."""
    from threedcal.evaluate.object_errors import PROTOCOLS, crossed_mean_interval

    columns = ["object", "P", "protocol", "presses", "replicates"]
    columns += [f"{m}{s}" for m in SUMMARY_METRICS for s in ("", "_lo", "_hi")] + ["depth_ratio"]
    out = []
    for (name, p, protocol), group in per_press.groupby(["object", "P", "protocol"], sort=False):
        row = {
            "object": name,
            "P": p,
            "protocol": protocol,
            "presses": group["press"].nunique(),
            "replicates": group["replicate"].nunique(),
        }
        for m in SUMMARY_METRICS:
            cells = group.pivot(index="replicate", columns="press", values=m)
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = crossed_mean_interval(cells.to_numpy())
        row["depth_ratio"] = float(group["depth_ratio"].mean())
        out.append(row)
    table = pd.DataFrame(out, columns=columns)
    if table.empty:
        return table
    ranks = {
        "protocol": {p: i for i, p in enumerate(PROTOCOLS)},
        "object": {o: i for i, o in enumerate(dict.fromkeys(table["object"]))},
    }
    table = table.sort_values(
        ["protocol", "object", "P"], key=lambda c: c.map(ranks[c.name]) if c.name in ranks else c
    )
    return table.reset_index(drop=True)


def pill_figure(maps: Mapping[int, np.ndarray], path: str | Path) -> None:
    """Fig. 3C: the pill's predicted depth for every training fraction P."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fractions = sorted(maps)
    vmax = max(float(np.nanmax(m)) for m in maps.values()) or 1.0
    fig, axes = plt.subplots(
        1, len(fractions), figsize=(2.2 * len(fractions), 3.0), dpi=110, squeeze=False
    )
    for ax, p in zip(axes[0], fractions, strict=True):
        shown = ax.imshow(maps[p], cmap="viridis", vmin=0, vmax=vmax)
        ax.set_title(f"P = {p} %", fontsize=9)
        ax.axis("off")
    fig.colorbar(shown, ax=axes[0].tolist(), shrink=0.8, label="depth (mm)")
    fig.suptitle("pill: predicted depth by training fraction (first reporting press)")
    fig.savefig(path)
    plt.close(fig)
