"""The rig: a printer and a tactile sensor, simulated or real, opened and closed together.

Collection (threedcal.study.session), the test objects' presses (threedcal.evaluate.object_presses)
and `threedcal live` (its camera alone) open what they drive here. A scene whose `port` is `sim`
gets the simulated bench: a fake Marlin behind a real serial path, and the gel camera or the ReSkin
board coupled to its head. Any other port gets the Marlin printer there and the sensor's camera
(`OpenCVCamera`: a flushed buffer, dropped, black and late frames raised as errors) or ReSkin board.

Where a person must act on a real rig (attach the probe, mount an object) the rig asks through the
`ask` callback its caller passes: the command line's waits for Enter. The library never reads the
terminal itself, and a real rig without `ask` refuses the step instead of hanging.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.hardware.camera import OpenCVCamera
from threedcal.hardware.clock import Clock, WallClock
from threedcal.hardware.printer import MarlinHost
from threedcal.hardware.reskin import ReSkinReader
from threedcal.profiles import load_profile

# Asks a person to do what the message says and returns once they have (e.g. pressed Enter).
Ask = Callable[[str], None]


class RigError(ThreedcalError):
    """The rig cannot do what was asked of it (a step needs a person and nobody can be asked)."""


class BenchClock:
    """The simulated bench's time: its firmware's virtual clock, which a wait advances."""

    def __init__(self, firmware):
        self.firmware = firmware

    def now(self) -> float:
        return self.firmware.clock.now()

    def sleep(self, seconds: float) -> None:
        self.firmware.clock.advance(seconds)


@dataclass
class Rig:
    """An opened printer and sensor, and the clocks a run keeps time by."""

    printer: Any  # threedcal.hardware.printer.MarlinHost
    sensor: Any  # flush() and capture(n): camera frames, or ReSkin readings
    clock: Clock  # settling waits: a real rig sleeps, the bench advances its clock
    hardware_clock: Callable[[], float]  # the printer's time (the bench's motion model)
    bench: Any = None  # the simulated bench and its hidden truth; None on a real rig
    ask: Ask | None = None

    @property
    def simulated(self) -> bool:
        return self.bench is not None

    def prompt(self, message: str) -> None:
        """Wait until a person has done what `message` says; the bench needs nobody."""
        if self.simulated:
            return
        if self.ask is None:
            raise RigError(
                f"this step needs a person at the rig ({message}) and nobody can be asked: pass "
                "ask= (`threedcal collect` and the workflow's rules ask at the terminal)"
            )
        self.ask(message)


@dataclass(frozen=True)
class RigSettings:
    """Which rig a scene runs on, as the study layer parsed it (threedcal.study.scene.rig_settings)."""

    sensor_ref: str  # the sensor profile's name or path: the bench seats the sensor as it says
    probe_radius_mm: float
    seed: int  # the simulated bench's draws
    bench: Mapping = field(default_factory=dict)  # the simulated bench's settings
    port: str = "sim"  # "sim": the simulated bench; else the printer's serial device
    camera: int | str = "sim"  # the sensor's video device on a real rig
    reader: str = "sim"  # a ReSkin board's serial device on a real rig

    @property
    def simulated(self) -> bool:
        return self.port == "sim"


def is_magnetic(sensor: Mapping) -> bool:
    """Magnetic sensors (ReSkin) stream readings over serial instead of camera frames."""
    return sensor.get("type") == "magnetic"


def camera_device(spec: int | str) -> int | str:
    """A camera as a scene or the command line names it: an index ("0") or a device path."""
    return int(spec) if isinstance(spec, str) and spec.isdigit() else spec


def check_devices(settings: RigSettings, sensor: Mapping, source: str = "scene") -> None:
    """A real printer needs a real sensor: its camera or its ReSkin board, named in the scene."""
    if settings.simulated:
        return
    key = "reader" if is_magnetic(sensor) else "camera"
    if str(getattr(settings, key)) == "sim":
        device = (
            "set the scene's `reader` to the ReSkin board's serial device (e.g. /dev/ttyACM0)"
            if is_magnetic(sensor)
            else "give the sensor's video device (index or /dev/v4l/by-id path)"
        )
        raise ConfigError(
            f"{source}.{key}: port {settings.port!r} is a real printer but {key} is 'sim': {device}, "
            "or use port: sim"
        )


def bench_sensor(settings: RigSettings, sensor: Mapping) -> dict:
    """The sensor as the simulated bench seats it: in the base its profile describes (the
    profile's `mount`, give or take the bench's hidden seating). A scene's own `mount`
    (threedcal.mount) is what its user measured of the rig, not where the bench put the sensor."""
    return {**sensor, "mount": load_profile("sensor", settings.sensor_ref)["mount"]}


def open_camera(sensor: Mapping, device: int | str | None):
    """The sensor's camera (not yet opened: use it as a context manager)."""
    return OpenCVCamera(sensor, None if device is None else camera_device(device))


@contextlib.contextmanager
def open_rig(
    settings: RigSettings, sensor: Mapping, printer: Mapping, *, ask: Ask | None = None
) -> Iterator[Rig]:
    """The scene's rig, opened: the simulated bench (`port: sim`, seated by the scene's `seed` and
    `bench` settings) or the printer at `port` with the sensor at `camera` / `reader`."""
    if settings.simulated:
        with _bench_rig(settings, sensor, printer) as rig:
            yield rig
        return

    if is_magnetic(sensor):
        reader = ReSkinReader(sensor, str(settings.reader))
    else:
        reader = open_camera(sensor, settings.camera)
    with reader as reading, MarlinHost(settings.port, printer) as host:
        clock = WallClock()
        yield Rig(host, reading, clock, clock.now, ask=ask)


@contextlib.contextmanager
def _bench_rig(rig: RigSettings, sensor: Mapping, printer: Mapping) -> Iterator[Rig]:
    """The fake printer and the simulated sensor, coupled through the head pose: the gel camera,
    or the ReSkin board behind its own serial URL."""
    # local: the config check imports this module; a simulator loads when its bench opens
    if is_magnetic(sensor):
        from threedcal.sim.reskin import ReSkinBench as Bench
    else:
        from threedcal.sim.bench import SimBench as Bench
    settings = rig.bench
    with contextlib.ExitStack() as stack:
        bench = stack.enter_context(
            Bench(
                bench_sensor(rig, sensor),
                rig.probe_radius_mm,
                settings,
                rig.seed,
                printer=printer,
                faults=settings.get("faults", ""),
                fault_rate=settings.get("fault_rate", 0.0),
            )
        )
        host = stack.enter_context(MarlinHost(bench.url, printer))
        if is_magnetic(sensor):
            reading = stack.enter_context(ReSkinReader(sensor, bench.sensor_url))
        else:
            reading = bench.camera
        firmware = bench.firmware
        yield Rig(host, reading, BenchClock(firmware), firmware.clock.now, bench=bench)
