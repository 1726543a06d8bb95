"""The simulated bench: the fake Marlin firmware and the gel simulator coupled through the head pose.

The pose the firmware reports is the pose the camera renders: each captured frame reads the
firmware's physical head position at that instant (on its virtual clock) and renders the ball there.
The bench also hides what a real user never knows exactly — the sensor's seating offset and
rotation in its printed base, and the Z at which the probe first touches the gel — drawn from the
seed and written to a truth file that only the *evaluation* of registration reads.

Printer → image, nominally: the centre of the sensor's plan area lies at the image centre, printer +X
runs along image columns and printer +Y (toward the back) up the image, at the profile's px/mm.
The hidden seating rotates and shifts the sensor about the plan centre.

A test object can take the ball's place on the head (`mount`): the bench then renders the object
where the head physically is, turned as mounted. A later session on the same, still seated sensor
(`start_session`) keeps the gel, its paint and the seating but draws fresh camera noise and a
lighting drift. Every rendered frame leaves its true pose in `last_render` (hidden truth, like
`truth`: for reporting only).
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from threedcal.lens import RadialLens
from threedcal.profiles import with_gel_mechanics
from threedcal.sim.camera import make_gel
from threedcal.sim.indenters import Sphere
from threedcal.sim.marlin import FirmwareBench
from threedcal.sim.units import draw_unit


@dataclass(frozen=True)
class BenchTruth:
    """What the bench hides: the true seating and first-touch height."""

    seating_offset_mm: tuple[float, float]
    seating_rotation_deg: float
    touch_offset_mm: float  # true first-touch Z minus the profile's nominal z_touch_mm
    affine_px_per_mm: list[list[float]]  # true printer (X, Y) mm → ideal image (column, row) px
    lens: dict | None = None  # the lens as built (threedcal.lens.RadialLens.record); None: none

    def camera_px(self, xy_mm) -> np.ndarray:
        """Printer (X, Y) mm (N, 2) → where the camera truly images them (column, row) px."""
        affine = np.asarray(self.affine_px_per_mm)
        ideal = np.atleast_2d(np.asarray(xy_mm, dtype=float)) @ affine[:, :2].T + affine[:, 2]
        lens = RadialLens.from_record(self.lens)
        return ideal if lens is None else lens.distort(ideal)

    def write(self, path: str | Path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(asdict(self), indent=2) + "\n")

    @classmethod
    def read(cls, path: str | Path) -> BenchTruth:
        data = json.loads(Path(path).read_text())
        return cls(
            seating_offset_mm=tuple(data["seating_offset_mm"]),
            seating_rotation_deg=data["seating_rotation_deg"],
            touch_offset_mm=data["touch_offset_mm"],
            affine_px_per_mm=data["affine_px_per_mm"],
            lens=data.get("lens"),
        )


def plan_centre_printer_mm(sensor: Mapping) -> tuple[float, float]:
    mount = sensor["mount"]
    width, height = sensor["probing"]["plan_area_mm"]
    return mount["x_offset_mm"] + width / 2, mount["y_offset_mm"] + height / 2


def nominal_affine(sensor: Mapping) -> np.ndarray:
    """(2, 3) printer (X, Y) mm → image (column, row) px for a perfectly seated sensor."""
    s = float(sensor["px_per_mm"])
    cx = (sensor["image"]["width_px"] - 1) / 2
    cy = (sensor["image"]["height_px"] - 1) / 2
    px, py = plan_centre_printer_mm(sensor)
    return np.array([[s, 0.0, cx - s * px], [0.0, -s, cy + s * py]])


# A lens as built is not the profile's nominal one: its principal point sits up to this far from the
# frame's centre, and its distortion coefficients differ by up to this fraction.
LENS_CENTRE_JITTER_PX = 3.0
LENS_K_JITTER = 0.2


def draw_lens(sensor: Mapping, seed: int):
    """The bench camera's lens (threedcal.lens.RadialLens), drawn around the profile's; None: none."""
    nominal = RadialLens.from_profile(sensor)
    if nominal is None:
        return None
    rng = np.random.default_rng([seed, 0x1E45])
    shift = rng.uniform(-1, 1, 2) * LENS_CENTRE_JITTER_PX
    scale = 1 + rng.uniform(-1, 1, 2) * LENS_K_JITTER
    return RadialLens(
        centre_px=(nominal.centre_px[0] + shift[0], nominal.centre_px[1] + shift[1]),
        kappa1=nominal.kappa1 * scale[0],
        kappa2=nominal.kappa2 * scale[1],
        shape=nominal.shape,
    )


def draw_truth(sensor: Mapping, settings: Mapping, seed: int) -> BenchTruth:
    """Seating and touch errors drawn uniformly within the configured magnitudes, and the lens."""
    rng = np.random.default_rng([seed, 0xBE7C])
    offset = rng.uniform(-1, 1, 2) * float(settings["seating_offset_mm"])
    rotation = float(rng.uniform(-1, 1) * float(settings["seating_rotation_deg"]))
    touch = float(rng.uniform(-1, 1) * float(settings["touch_offset_mm"]))
    nominal = nominal_affine(sensor)
    # The sensor is rotated by `rotation` about the plan centre and shifted by `offset`: a printer
    # point p sits at gel position R⁻¹(p − c − offset) + c, which the nominal map sends to pixels.
    t = math.radians(rotation)
    inverse = np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])
    centre = np.array(plan_centre_printer_mm(sensor))
    linear = nominal[:, :2] @ inverse
    translation = nominal[:, :2] @ (centre - inverse @ (centre + offset)) + nominal[:, 2]
    affine = np.column_stack([linear, translation])
    return BenchTruth(
        seating_offset_mm=(float(offset[0]), float(offset[1])),
        seating_rotation_deg=rotation,
        touch_offset_mm=touch,
        affine_px_per_mm=affine.round(12).tolist(),
        lens=None if (lens := draw_lens(sensor, seed)) is None else lens.record(),
    )


@dataclass(frozen=True)
class MountedObject:
    """A test object on the print head instead of the ball, as it truly sits there.

    `offset_mm`: its press-frame origin (x-y centre, lowest point) relative to the probe tip,
    printer X, Y, Z. `rotation_deg`: how it is turned, in the press frame's convention (clockwise as
    the image shows it under the nominal seating). The indenter is the object unturned.
    """

    indenter: object  # threedcal.sim.indenters.Indenter
    offset_mm: tuple[float, float, float]
    rotation_deg: float


class SimCamera:
    """The bench's camera: renders the gel under the ball wherever the firmware's head is."""

    def __init__(self, bench: SimBench):
        self.bench = bench
        self.fps = float(bench.sensor["camera"]["default_fps"])
        self._rep = 0

    def flush(self) -> None:
        self._rep = 0  # a fresh hold: creep and noise restart for the frames that follow

    def skip(self, count: int) -> None:
        """Spend the time of `count` frames without rendering them (a replayed resume: those
        frames are stored already, and a render depends only on the pose and the repetition)."""
        for _ in range(count):
            self.bench.firmware.clock.advance(1.0 / self.fps)
            self._rep += 1

    def capture(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        frames, stamps = [], []
        clock = self.bench.firmware.clock
        for _ in range(count):
            clock.advance(1.0 / self.fps)
            frames.append(self.bench.render_now(self._rep))
            stamps.append(clock.now())
            self._rep += 1
        return np.stack(frames), np.asarray(stamps)


class SimBench(FirmwareBench):
    """Fake printer + simulated sensor + hidden truth, opened at `bench.url` like a serial port."""

    def __init__(
        self,
        sensor: Mapping,
        probe_radius_mm: float,
        settings: Mapping,
        seed: int,
        *,
        printer: str | Mapping = "ender3",
        faults: str = "",
        fault_rate: float = 0.0,
        speedup: float = math.inf,
    ):
        # the unit as built: its constants drawn around the profile's (hidden, like the seating)
        self.sensor = draw_unit(
            with_gel_mechanics(sensor, settings.get("gel_mechanics")), settings.get("unit")
        )
        self.seed = int(seed)
        self.truth = draw_truth(sensor, settings, seed)
        self._affine = np.asarray(self.truth.affine_px_per_mm)
        self._z_touch = float(sensor["mount"]["z_touch_mm"]) + self.truth.touch_offset_mm
        self.lens = RadialLens.from_record(self.truth.lens)
        self.gel = make_gel(self.sensor, seed=seed, lens=self.lens)
        self.ball = Sphere(probe_radius_mm)
        self.tool: MountedObject | None = None
        self.last_render: dict | None = None
        super().__init__(
            "bench", printer, seed=seed, faults=faults, fault_rate=fault_rate, speedup=speedup
        )
        self.camera = SimCamera(self)

    def pose_px(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        col, row = self._affine[:, :2] @ np.array([x_mm, y_mm]) + self._affine[:, 2]
        return float(col), float(row)

    def penetration_mm(self, center_px: tuple[float, float], z_mm: float) -> float:
        """How far the ball's bottom at printer Z sits below the undeformed gel surface under it."""
        u, v = self.gel.axis_mm(center_px)
        return self._z_touch - float(self.gel.sag_mm(u, v)) - z_mm

    def mount(self, tool: MountedObject | None) -> None:
        """Put a test object on the head in place of the ball (None: the ball again)."""
        self.tool = tool

    def start_session(self, noise_seed: int, gain_rgb) -> None:
        """A later session on the same sensor, not reseated: same gel, paint and seating; fresh
        camera noise (`noise_seed`) and the LEDs' brightness scaled by `gain_rgb` per channel."""
        self.gel = make_gel(
            self.sensor, seed=self.seed, lens=self.lens, noise_seed=noise_seed, gain_rgb=gain_rgb
        )

    @property
    def image_rotation_deg(self) -> float:
        """How the true seating turns printer-frame shapes in the image (press-frame convention)."""
        linear = self._affine[:, :2] @ np.diag([1.0, -1.0])
        return math.degrees(math.atan2(linear[1, 0], linear[0, 0]))

    def render_now(self, rep: int) -> np.ndarray:
        x, y, z = self.firmware.position()
        indenter, rotation = self.ball, 0.0
        if self.tool is not None:
            indenter = self.tool.indenter
            rotation = self.image_rotation_deg + self.tool.rotation_deg
            x, y, z = (a + b for a, b in zip((x, y, z), self.tool.offset_mm, strict=True))
        center = self.pose_px(x, y)
        depth = self.penetration_mm(center, z)
        steps = np.round(np.array([x, y, z]) * 1000).astype(np.int64)
        index = zlib.crc32(np.append(steps, rep).tobytes())  # same pose and rep → same noise
        self.last_render = {
            "center_px": center,
            "rotation_deg": rotation,
            "depth_mm": self.gel.effective_depth_mm(max(depth, 0.0), rep),  # with creep
        }
        if depth <= 0:
            return self.gel.blank(frame_index=index)
        return self.gel.render(indenter, center, rotation, depth, frame_index=index, hold_frame=rep)

    @property
    def hardware_s(self) -> float:
        return self.firmware.clock.now()
