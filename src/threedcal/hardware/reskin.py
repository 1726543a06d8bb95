"""The ReSkin board over serial: one tab-separated line of floats per reading, read through pyserial.

The board streams continuously (`serial.rate_hz` lines per second, bx, by, bz in uT and t in deg C
per magnetometer, in the profile's `magnetometers.channels` order). Like the camera, a capture must
show the present: `flush()` drops every line buffered by the OS and the partial line that follows
it, so the readings after a press are taken after the press. A line that does not parse, or no
complete line within `serial.timeout_s`, raises a `ReSkinError` naming the port and the line —
never a silently wrong reading. `ReSkinReader` is a `FrameSource` for the collection loop:
`capture(n)` returns (n, values) float32 readings and their time stamps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.hardware.printer import register_url_handlers
from threedcal.profiles import load_profile

MAX_LINE_BYTES = 4096  # a "line" longer than this is noise on the wire, not a reading


class ReSkinError(ThreedcalError):
    """A fault of the ReSkin board or its serial link at run time."""


class ReSkinTimeout(ReSkinError):
    pass


class MalformedReading(ReSkinError):
    pass


def reskin_profile(profile: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of a magnetic sensor profile with the schema's defaults filled in."""
    if profile.get("type") != "magnetic":
        raise ConfigError(
            f"sensor {profile.get('name')!r} is of type {profile.get('type')!r}; "
            "a serial reader needs a magnetic sensor profile (e.g. reskin)"
        )
    return load_profile("sensor", profile, defaults=True)


def value_names(profile: Mapping[str, Any]) -> list[str]:
    """Names of the values on one line, in stream order: bx0, by0, bz0, t0, bx1, ..."""
    channels = profile["magnetometers"]["channels"]
    count = len(profile["magnetometers"]["positions_mm"])
    return [f"{channel}{chip}" for chip in range(count) for channel in channels]


def field_indices(profile: Mapping[str, Any]) -> np.ndarray:
    """Indices of the magnetic-field values (bx, by, bz of every chip) among a line's values."""
    return np.array(
        [i for i, name in enumerate(value_names(profile)) if name.startswith("b")], dtype=int
    )


def parse_line(raw: bytes, n_values: int, separator: str, where: str = "ReSkin") -> np.ndarray:
    """One line (without its ending) → (n_values,) float32; anything else is a `MalformedReading`."""
    try:
        text = raw.decode("ascii").strip()
    except UnicodeDecodeError:
        raise MalformedReading(
            f"{where}: malformed line {raw!r}: not ASCII text (wrong baud rate or noise on the wire?)"
        ) from None
    fields = text.split(separator) if text else []
    if len(fields) != n_values:
        raise MalformedReading(
            f"{where}: malformed line {text!r}: expected {n_values} numbers separated by "
            f"{separator!r}, got {len(fields)} field(s) (check the profile's magnetometers.channels "
            "and serial.separator against the board's firmware)"
        )
    values = np.empty(n_values, dtype=np.float32)
    for i, field in enumerate(fields):
        try:
            value = float(field)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise MalformedReading(
                f"{where}: malformed line {text!r}: value {i + 1} ({field!r}) is not a finite number"
            )
        values[i] = value
    return values


def open_serial(port: str, baudrate: int, timeout_s: float):
    """A device path (``/dev/ttyACM0``) or a pyserial URL (``simreskin://x``, ``loop://``)."""
    import serial  # optional (hardware extra); reskin_profile needs none

    register_url_handlers()
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise ReSkinError(f"cannot open ReSkin port {port!r}: {exc}") from exc


class ReSkinReader:
    """Readings from a ReSkin board on `port` (a path, a pyserial URL, or an open serial object)."""

    def __init__(self, profile: Mapping[str, Any], port, *, read_timeout_s: float = 0.05):
        self.profile = reskin_profile(profile)
        serial_cfg = self.profile["serial"]
        self.separator = serial_cfg["separator"]
        self.timeout_s = float(serial_cfg["timeout_s"])
        self.names = value_names(self.profile)
        self._port_arg = port
        self._read_timeout = min(read_timeout_s, self.timeout_s)
        self.port = None if isinstance(port, str) else port
        self.name = port if isinstance(port, str) else getattr(port, "port", None) or "ReSkin"
        self._buffer = b""
        self._drop_partial = False

    # ---- lifecycle -----------------------------------------------------------------------
    def open(self) -> ReSkinReader:
        if self.port is None:
            self.port = open_serial(
                self._port_arg, int(self.profile["serial"]["baudrate"]), self._read_timeout
            )
        return self

    def close(self) -> None:
        if self.port is not None and isinstance(self._port_arg, str):
            self.port.close()
            self.port = None

    def __enter__(self) -> ReSkinReader:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def n_values(self) -> int:
        return len(self.names)

    def _now(self) -> float:
        # The simulated port keeps time on the fake printer's clock; a real one on the CPU's.
        clock = getattr(self.port, "threedcal_clock", None)
        return clock() if clock is not None else time.monotonic()

    # ---- FrameSource -----------------------------------------------------------------------
    def flush(self) -> None:
        """Forget every buffered line: the next reading is one the board sends from now on."""
        self._require_open()
        self.port.reset_input_buffer()
        self._buffer = b""
        self._drop_partial = True  # the line in flight may have lost its head in the reset

    def capture(self, count: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """`count` consecutive readings (count, n_values) float32 and their arrival times (s)."""
        self._require_open()
        readings = np.empty((count, self.n_values), dtype=np.float32)
        stamps = np.empty(count)
        for i in range(count):
            line = self._read_line()
            readings[i] = parse_line(line, self.n_values, self.separator, where=str(self.name))
            stamps[i] = self._now()
        return readings, stamps

    # ---- lines ---------------------------------------------------------------------------------
    def _require_open(self) -> None:
        if self.port is None:
            raise ReSkinError(f"{self.name}: the ReSkin port is not open (use `with reader:`)")

    def _read_line(self) -> bytes:
        deadline = self._now() + self.timeout_s
        while True:
            if b"\n" in self._buffer:
                line, self._buffer = self._buffer.split(b"\n", 1)
                if self._drop_partial:
                    self._drop_partial = False
                    continue
                if line.strip():
                    return line
                continue  # an empty line between readings carries nothing
            if len(self._buffer) > MAX_LINE_BYTES:
                raise MalformedReading(
                    f"{self.name}: malformed line {self._buffer[:80]!r}...: {len(self._buffer)} bytes "
                    "without a line ending (wrong baud rate?)"
                )
            if self._now() >= deadline:
                partial = f" (incomplete line so far: {self._buffer!r})" if self._buffer else ""
                raise ReSkinTimeout(
                    f"{self.name}: no complete ReSkin reading within {self.timeout_s:g} s{partial}; "
                    "is the board powered, streaming, and at "
                    f"{self.profile['serial']['baudrate']} baud?"
                )
            try:
                waiting = self.port.in_waiting
                self._buffer += self.port.read(max(1, waiting))
            except OSError as exc:  # serial.SerialException is an OSError
                raise ReSkinError(f"{self.name}: serial link lost: {exc}") from exc
