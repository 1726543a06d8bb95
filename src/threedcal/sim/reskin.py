"""A simulated ReSkin: a magnetised elastomer over five magnetometers, pressed by the printer's ball.

Physics (all constants in the sensor profile's `gel`, `magnetometers` and `magnet` blocks):

- The elastomer is a grid of point dipoles (`magnet.grid_spacing_mm` in plane, `magnet.layers`
  through the thickness), magnetised along +z (away from the board) with remanence
  `magnet.remanence_mt`. A uniformly magnetised sheet has almost no field below its middle; what the
  chips see is the field of its *non-uniformity* — which an indentation creates.
- The ball (radius R) pressed d mm deep deflects the surface as a Hertz contact: inside the contact
  radius a = sqrt(R d) the surface follows the ball (d − r²/2R); outside it falls off like the
  Boussinesq half-space solution, times exp(−(r − a)/`decay_mm`) because a thin layer bonded to a
  rigid board spreads a load less far than a half-space. The deflection decreases linearly to zero
  at the bonded underside; each dipole moves down with its material and its moment tilts with the
  local rotation of the material (ω = ½ curl u), which gives the x/y components a contact signal.
- The field at each chip is the exact sum of the dipole fields. Each chip adds a constant offset
  (Earth's field, hard iron: `magnet.offset_ut`), each channel white noise (`magnet.noise_ut`) and a
  slow sinusoidal baseline drift (`magnet.drift_ut`, periods in `magnet.drift_period_s`); the
  temperature channel swings slowly by `magnet.temperature_swing_c`.

The board streams a line every 1/`serial.rate_hz` simulated seconds on the fake printer's virtual
clock; its bytes arrive at the profile's baud rate, so a flush can cut a line in half, as on a real
port. It reads the probe pose from the SimMarlin firmware it is coupled with (the pose the firmware
reports is the pose that indents the skin), and it is opened through pyserial as
``simreskin://NAME`` (threedcal.sim.protocol_simreskin) — the same reader code path as the board.
Deterministic: the same seed and the same host traffic give the same bytes.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from threedcal.errors import ConfigError
from threedcal.hardware.reskin import reskin_profile
from threedcal.sim.devices import DeviceRegistry
from threedcal.sim.marlin import FirmwareBench

_BUFFER_S = 1.0  # the OS keeps about this much of the stream; older lines are lost (overrun)


def surface_deflection(r_mm, depth_mm: float, radius_mm: float, decay_mm: float):
    """Deflection w(r) ≥ 0 of the skin's surface (mm, into the skin) and dw/dr, for a ball pressed
    `depth_mm` deep: the ball's shape inside a = sqrt(R d), the Hertz/Boussinesq fall-off outside
    (continuous in value and slope at r = a), damped by exp(−(r − a)/decay)."""
    r = np.asarray(r_mm, dtype=float)
    if depth_mm <= 0:
        return np.zeros_like(r), np.zeros_like(r)
    a = math.sqrt(radius_mm * depth_mm)
    inside = r < a
    rho = np.maximum(r / a, 1.0)
    asin = np.arcsin(1.0 / rho)
    root = np.sqrt(rho**2 - 1.0)
    g = ((2.0 - rho**2) * asin + root) / math.pi
    dg = (2.0 / math.pi) * (root / rho - rho * asin)
    damp = np.exp(-(r - a) / decay_mm)
    w_out = depth_mm * g * damp
    dw_out = depth_mm * damp * (dg / a - g / decay_mm)
    w = np.where(inside, depth_mm - r**2 / (2 * radius_mm), w_out)
    dw = np.where(inside, -r / radius_mm, dw_out)
    return w, dw


def dipole_field_ut(
    sensors_mm: np.ndarray, positions_mm: np.ndarray, moments: np.ndarray, scale: float
) -> np.ndarray:
    """Field (µT) at `sensors_mm` (S, 3) of dipoles at `positions_mm` (N, 3) with moments (N, 3).

    B = scale · Σ (3 (m·r̂) r̂ − m) / |r|³ with r in mm; `scale` = Br/(4π) · dipole volume (mm³) for
    a remanence Br in µT and unit moment directions.
    """
    rx, ry, rz = (sensors_mm[:, k, None] - positions_mm[None, :, k] for k in range(3))  # (S, N)
    return _field_sum(rx, ry, rz, rx * rx + ry * ry, moments, scale)


def _field_sum(rx, ry, rz, rxy2, moments, scale) -> np.ndarray:
    mx, my, mz = moments[:, 0], moments[:, 1], moments[:, 2]
    inv2 = 1.0 / (rxy2 + rz * rz)
    inv3 = inv2 * np.sqrt(inv2)
    radial = 3.0 * (rx * mx + ry * my + rz * mz) * inv2
    field = [((radial * r - m) * inv3).sum(axis=1) for r, m in ((rx, mx), (ry, my), (rz, mz))]
    return scale * np.stack(field, axis=1)


class MagneticSkin:
    """The elastomer and the chips: noise-free field (µT) at every chip for a contact (x, y, depth)."""

    def __init__(self, profile: Mapping[str, Any], probe_radius_mm: float):
        self.profile = reskin_profile(profile)
        gel, magnet, mags = (
            self.profile["gel"],
            self.profile["magnet"],
            self.profile["magnetometers"],
        )
        self.radius = float(probe_radius_mm)
        self.thickness = float(gel["thickness_mm"])
        self.decay = float(magnet["decay_mm"])
        step = float(magnet["grid_spacing_mm"])
        xs = _centred_axis(float(gel["width_mm"]), step)
        ys = _centred_axis(float(gel["height_mm"]), step)
        layers = int(magnet["layers"])
        fraction = (np.arange(layers) + 0.5) / layers  # height within the skin / thickness
        gx, gy, gf = np.meshgrid(xs, ys, fraction, indexing="ij")
        self.x, self.y, self.f = gx.ravel(), gy.ravel(), gf.ravel()
        self.z0 = float(mags["gap_mm"]) + self.f * self.thickness
        volume = step * step * self.thickness / layers
        self.scale = float(magnet["remanence_mt"]) * 1000.0 / (4 * math.pi) * volume
        positions = np.asarray(mags["positions_mm"], dtype=float)
        self.sensors = np.column_stack([positions, np.zeros(len(positions))])
        self._rx = self.sensors[:, 0, None] - self.x[None, :]
        self._ry = self.sensors[:, 1, None] - self.y[None, :]
        self._rxy2 = self._rx**2 + self._ry**2
        self._rest = None
        self._rest = self.field(0.0, 0.0, 0.0)

    def field(self, x_mm: float, y_mm: float, depth_mm: float) -> np.ndarray:
        """(chips, 3) bx, by, bz in µT with the ball pressed `depth_mm` deep at (x, y) (mm from the
        skin's centre, printer axes); depth ≤ 0 is no contact."""
        if depth_mm <= 0 and self._rest is not None:
            return self._rest.copy()
        dx, dy = self.x - x_mm, self.y - y_mm
        r = np.hypot(dx, dy)
        w, dw = surface_deflection(r, depth_mm, self.radius, self.decay)
        safe_r = np.where(r > 0, r, 1.0)
        grad_x, grad_y = dw * dx / safe_r, dw * dy / safe_r
        # Material rotation ω = ½ curl u with u = (0, 0, −f w) tilts ẑ by ½ f ∇w.
        moments = np.column_stack([0.5 * self.f * grad_x, 0.5 * self.f * grad_y, np.ones_like(r)])
        moments /= np.linalg.norm(moments, axis=1, keepdims=True)
        # Dipoles move only in z: the in-plane offsets to the chips are fixed (precomputed).
        rz = -(self.z0 - self.f * w)[None, :]
        return _field_sum(self._rx, self._ry, rz, self._rxy2, moments, self.scale)


def _centred_axis(length: float, step: float) -> np.ndarray:
    half = math.floor(length / 2 / step + 1e-9) * step
    return np.arange(-half, half + step / 2, step)


@dataclass(frozen=True)
class ReSkinTruth:
    """What the ReSkin bench hides: how the skin sits in its base and where it is first touched."""

    seating_offset_mm: tuple[float, float]
    seating_rotation_deg: float
    touch_offset_mm: float  # true first-touch Z minus the profile's nominal z_touch_mm

    def write(self, path: str | Path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps({"sensor": "magnetic", **asdict(self)}, indent=2) + "\n")


def draw_reskin_truth(settings: Mapping, seed: int) -> ReSkinTruth:
    rng = np.random.default_rng([int(seed), 0x5E5C])
    offset = rng.uniform(-1, 1, 2) * float(settings.get("seating_offset_mm", 0.0))
    rotation = float(rng.uniform(-1, 1) * float(settings.get("seating_rotation_deg", 0.0)))
    touch = float(rng.uniform(-1, 1) * float(settings.get("touch_offset_mm", 0.0)))
    return ReSkinTruth((float(offset[0]), float(offset[1])), rotation, touch)


class SimReSkin:
    """The simulated board: readings of `MagneticSkin` under the firmware's head, streamed as lines."""

    def __init__(
        self,
        profile: Mapping[str, Any],
        firmware,  # threedcal.sim.marlin.SimMarlin: its clock and head position drive the board
        *,
        probe_radius_mm: float = 2.0,
        seed: int = 0,
        truth: ReSkinTruth | None = None,
    ):
        self.skin = MagneticSkin(profile, probe_radius_mm)
        self.profile = self.skin.profile
        self.firmware = firmware
        self.clock = firmware.clock
        self.seed = int(seed)
        self.truth = truth or ReSkinTruth((0.0, 0.0), 0.0, 0.0)
        serial_cfg, magnet = self.profile["serial"], self.profile["magnet"]
        self.channels = list(self.profile["magnetometers"]["channels"])
        self.n_chips = len(self.skin.sensors)
        self.period = 1.0 / float(serial_cfg["rate_hz"])
        self.byte_s = 10.0 / float(serial_cfg["baudrate"])  # 8N1: ten bits per byte
        self.separator = serial_cfg["separator"]
        self.ending = serial_cfg["line_ending"].encode("ascii")
        self.decimals = int(serial_cfg["decimals"])
        mount = self.profile["mount"]
        width, height = self.profile["probing"]["plan_area_mm"]
        self._centre = (mount["x_offset_mm"] + width / 2, mount["y_offset_mm"] + height / 2)
        self._z_touch = float(mount["z_touch_mm"]) + self.truth.touch_offset_mm
        rng = np.random.default_rng([self.seed, 0x0FF5])
        self.offsets = rng.uniform(-1, 1, (self.n_chips, 3)) * float(magnet["offset_ut"])
        low, high = magnet["drift_period_s"]
        self.drift_amp = rng.uniform(0.5, 1.0, (self.n_chips, 3)) * float(magnet["drift_ut"])
        self.drift_period = rng.uniform(low, high, (self.n_chips, 3))
        self.drift_phase = rng.uniform(0, 2 * math.pi, (self.n_chips, 3))
        self.temp_period = float(rng.uniform(low, high))
        self.temp_phase = float(rng.uniform(0, 2 * math.pi))
        self.noise = np.asarray(magnet["noise_ut"], dtype=float)
        self._lines: dict[int, bytes] = {}
        self._t0 = 0.0
        width_line = len(self.line(0))
        if width_line * self.byte_s * 1.2 > self.period:
            raise ConfigError(
                f"sensor {self.profile.get('name')}: a line of ~{width_line} bytes takes "
                f"{width_line * self.byte_s * 1000:.1f} ms at {serial_cfg['baudrate']} baud, too long "
                f"for {serial_cfg['rate_hz']} readings per second"
            )
        self.connected = False
        self._next = 0  # index of the next line to deliver
        self._offset = 0  # bytes of that line already delivered or dropped
        self._lines = {}

    # ---- the physics side ------------------------------------------------------------------
    def contact(self, printer_xyz: tuple[float, float, float]) -> tuple[float, float, float]:
        """Printer (X, Y, Z) → contact (x, y) mm from the skin's centre in its own axes, and depth."""
        x = printer_xyz[0] - self._centre[0] - self.truth.seating_offset_mm[0]
        y = printer_xyz[1] - self._centre[1] - self.truth.seating_offset_mm[1]
        t = math.radians(self.truth.seating_rotation_deg)
        u = math.cos(t) * x + math.sin(t) * y
        v = -math.sin(t) * x + math.cos(t) * y
        return u, v, self._z_touch - printer_xyz[2]

    def reading(self, t: float, index: int) -> np.ndarray:
        """Values of one line sampled at simulated time `t` (stream order, unrounded)."""
        x, y, depth = self.contact(self.firmware.position(t))
        field = self.skin.field(x, y, depth) + self.offsets
        field += self.drift_amp * np.sin(2 * math.pi * t / self.drift_period + self.drift_phase)
        rng = np.random.default_rng([self.seed, 0x5A3, int(index)])
        field += rng.normal(size=field.shape) * self.noise
        magnet = self.profile["magnet"]
        temperature = magnet["temperature_c"] + magnet["temperature_swing_c"] * math.sin(
            2 * math.pi * t / self.temp_period + self.temp_phase
        )
        temperature += 0.02 * rng.normal(size=self.n_chips)
        per_chip = {"bx": field[:, 0], "by": field[:, 1], "bz": field[:, 2], "t": temperature}
        return np.stack([per_chip[c] for c in self.channels], axis=1).ravel()

    def line(self, index: int) -> bytes:
        if index not in self._lines:
            values = self.reading(self._time(index), index)
            text = self.separator.join(f"{v:.{self.decimals}f}" for v in values)
            self._lines[index] = text.encode("ascii") + self.ending
        return self._lines[index]

    def _time(self, index: int) -> float:
        return self._t0 + index * self.period

    # ---- the serial side (used by the pyserial handler) --------------------------------------
    def open(self) -> None:
        """The board starts streaming; the first line begins one period after the port opens."""
        self.connected = True
        self._t0 = self.clock.now() + self.period
        self._next, self._offset, self._lines = 0, 0, {}

    def close(self) -> None:
        self.connected = False

    # A ReSkin board cannot be unplugged mid-run in the simulation; it ignores what the host sends.
    disconnected = False

    def receive(self, data: bytes) -> None:
        pass

    def _skip_overrun(self, now: float) -> None:
        oldest = math.ceil((now - _BUFFER_S - self._t0) / self.period)
        if oldest > self._next:
            self._next, self._offset = oldest, 0
        for index in [k for k in self._lines if k < self._next]:
            del self._lines[index]

    def _arrived(self, index: int, now: float) -> int:
        """Bytes of line `index` that have reached the host by `now`."""
        start = self._time(index)
        if now < start:
            return 0
        return min(len(self.line(index)), int((now - start) / self.byte_s + 1e-9))

    def take(self, size: int, now: float) -> bytes:
        self._skip_overrun(now)
        chunks = []
        while size > 0:
            available = self._arrived(self._next, now)
            if available <= self._offset:
                break
            line = self.line(self._next)
            chunk = line[self._offset : min(available, self._offset + size)]
            chunks.append(chunk)
            size -= len(chunk)
            self._offset += len(chunk)
            if self._offset < len(line):
                break
            self._next, self._offset = self._next + 1, 0
        return b"".join(chunks)

    def waiting(self, now: float) -> int:
        self._skip_overrun(now)
        total, index, offset = 0, self._next, self._offset
        while True:
            available = self._arrived(index, now)
            total += max(0, available - offset)
            if available < len(self.line(index)):  # in flight or not yet begun
                return total
            index, offset = index + 1, 0

    def reset_input(self, now: float) -> None:
        """Drop what has arrived; the line in flight keeps only its bytes still to come."""
        self._skip_overrun(now)
        index = max(self._next, math.floor((now - self._t0) / self.period))
        if index > self._next:
            self._next, self._offset = index, 0
        available = self._arrived(self._next, now)
        if available >= len(self.line(self._next)):
            self._next, self._offset = self._next + 1, 0
        else:
            self._offset = max(self._offset, available)

    def next_due(self, now: float) -> float:
        """When the line now in flight (or the next one) has fully arrived."""
        index = self._next
        if self._arrived(index, now) >= len(self.line(index)):
            return now
        return self._time(index) + len(self.line(index)) * self.byte_s


# How the pyserial handler and the bench find the same board.
BOARDS: DeviceRegistry[SimReSkin] = DeviceRegistry(
    "simreskin", "simulated ReSkin", "a ReSkinBench serves one"
)


def board_for_url(port_url: str) -> SimReSkin:
    """The registered board named by ``simreskin://NAME`` (it needs its printer, so never made here)."""
    parts = urlsplit(port_url)
    if parts.scheme.lower() != "simreskin" or not parts.netloc:
        raise ConfigError(f"expected simreskin://NAME, got {port_url!r}")
    try:
        return BOARDS.get(parts.netloc)
    except KeyError as exc:
        raise ConfigError(str(exc.args[0])) from None


class ReSkinBench(FirmwareBench):
    """Fake printer + simulated ReSkin + hidden truth: `url` for the printer, `sensor_url` for the board."""

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
        self.truth = draw_reskin_truth(settings, seed)
        super().__init__(
            "reskin-bench",
            printer,
            seed=seed,
            faults=faults,
            fault_rate=fault_rate,
            speedup=speedup,
        )
        self.board = SimReSkin(
            sensor, self.firmware, probe_radius_mm=probe_radius_mm, seed=seed, truth=self.truth
        )
        BOARDS.serve(self.name, self.board)
        self.sensor_url = f"simreskin://{self.name}"

    def close(self) -> None:
        super().close()
        BOARDS.withdraw(self.name)
