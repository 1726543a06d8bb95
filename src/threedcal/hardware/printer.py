"""A Marlin G-code host over pyserial that knows when a command is really done.

Every command goes out as a numbered, checksummed line and the host waits for its ``ok`` before the
next (one line in flight). Line numbers make retransmission safe: Marlin executes only line
``last + 1``, so a line sent twice (after a lost ``ok``) is refused with ``Resend: <next>`` instead
of being run twice, and ``Resend: n`` always tells exactly which line to send next. Timeouts are
kept in the port's clock (the real one, or a simulated printer's virtual clock) and stretch by the
motion-time model's estimate for commands that wait on motion (G0/G1 with a full planner, G28,
M400); every ``busy: processing`` keepalive extends them. Known limit: a reply that arrives *later*
than the reply timeout costs extra retransmissions (never a lost or repeated command).
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.hardware.gcode import Reply, classify, format_line, parse_m114, parse_m115
from threedcal.hardware.motion import AXES, MotionModel

# Packages searched for pyserial URL handlers (``simmarlin://`` lives in threedcal.sim). A name,
# not an import: the hardware layer does not depend on the simulator.
URL_HANDLER_PACKAGES = ("threedcal.sim",)
MOTION_MARGIN = 1.5  # allow this multiple of the modelled motion time before calling it silence


class PrinterError(ThreedcalError):
    """The printer did something the host cannot recover from on its own."""


class PrinterTimeout(PrinterError):
    pass


class PrinterReset(PrinterError):
    pass


class PrinterHalted(PrinterError):
    pass


class PrinterDisconnected(PrinterError):
    pass


class CommandRejected(PrinterError):
    pass


class OutOfTravel(ConfigError):
    """A target outside the printer profile's travel: refused before anything is sent."""


def printer_profile(ref: str | Path | Mapping[str, Any]) -> dict[str, Any]:
    """A validated printer profile with the schema's defaults filled in (name, path or dict)."""
    from threedcal.config import _fill_defaults, load_yaml, schema_errors
    from threedcal.profiles import _ROOT, load_profile

    schema = load_yaml(_ROOT / "schemas" / "printer.schema.yaml")
    if isinstance(ref, Mapping):
        profile = copy.deepcopy(dict(ref))
        problems = schema_errors(profile, schema)
        if problems:
            where = profile.get("source", "printer profile")
            raise ConfigError(f"{where}: invalid printer profile\n  " + "\n  ".join(problems))
    else:
        profile = load_profile("printer", ref)
    _fill_defaults(profile, schema, schema)
    return profile


def register_url_handlers() -> None:
    import serial

    for package in URL_HANDLER_PACKAGES:
        if package not in serial.protocol_handler_packages:
            serial.protocol_handler_packages.append(package)


def open_port(port: str, baudrate: int = 115200):
    """Open a device path (``/dev/ttyUSB0``, ``COM3``) or a pyserial URL (``simmarlin://x``)."""
    import serial

    register_url_handlers()
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=0.1, write_timeout=5)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise PrinterDisconnected(f"cannot open printer port {port!r}: {exc}") from exc


def list_ports() -> list[tuple[str, str, str]]:
    """(device, description, hardware id) of every serial port the OS reports."""
    from serial.tools import list_ports as lp

    return [(p.device, p.description, p.hwid) for p in sorted(lp.comports())]


@dataclass(frozen=True)
class Position:
    """M114: the firmware's commanded position (mm) and, when reported, the stepper counts (mm)."""

    x: float
    y: float
    z: float
    steps_mm: tuple[float, float, float] | None = None

    def __iter__(self):
        return iter((self.x, self.y, self.z))


@dataclass
class HostStats:
    lines: int = 0  # distinct numbered lines acknowledged
    writes: int = 0  # line transmissions, retransmissions included
    resends: int = 0  # Resend requests honoured
    timeouts: int = 0  # silences that led to a retransmission
    busy: int = 0
    temperature_reports: int = 0
    ignored: int = 0  # unparseable lines (noise)


class MarlinHost:
    """Talk to one Marlin printer. Use as a context manager; all coordinates in mm, feeds in mm/s."""

    def __init__(
        self,
        port: str,
        profile: str | Path | Mapping[str, Any] = "ender3",
        *,
        reply_timeout_s: float | None = None,
        boot_timeout_s: float | None = None,
        retries: int | None = None,
        log: Callable[[str], None] | None = None,
    ):
        self.profile = printer_profile(profile)
        self.model = MotionModel(self.profile)
        timeouts = self.profile["timeouts_s"]
        self.reply_timeout_s = float(reply_timeout_s or timeouts["reply"])
        self.boot_timeout_s = float(boot_timeout_s or timeouts["boot"])
        self.retries = int(timeouts["retries"] if retries is None else retries)
        self.port_name = port
        self.stats = HostStats()
        self.acked: list[tuple[int, str]] = []  # (line number, command) in acknowledgement order
        self.firmware_info: dict[str, str] = {}
        self.homed = False
        self.commanded: tuple[float, float, float] | None = None
        self._log = log or (lambda text: None)
        self._history: dict[int, str] = {}
        self._next = 0
        self._buf = b""
        self._motion_done_at = 0.0
        self._closed = False
        self._port = open_port(port, int(self.profile["baudrate"]))
        self._now: Callable[[], float] = getattr(self._port, "threedcal_clock", time.monotonic)
        # Real ports: wake up twice a second to re-check the deadline. A simulated port's clock only
        # moves while we wait on it, so one read may cover the whole wait.
        self._read_slice = math.inf if hasattr(self._port, "threedcal_clock") else 0.5
        try:
            self._handshake()
        except BaseException:
            self.close()
            raise

    # ---- context manager -----------------------------------------------------------------
    def __enter__(self) -> MarlinHost:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._port.close()
            except Exception:  # noqa: BLE001 - closing a dead port must not mask the real error
                pass

    # ---- wire ----------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        import serial

        try:
            self._port.write(data)
            self.stats.writes += 1
        except (serial.SerialException, OSError) as exc:
            raise PrinterDisconnected(
                f"{self.port_name}: write failed ({exc}); is the printer still connected?"
            ) from exc

    def _readline(self, deadline: float) -> str | None:
        """The next non-empty line, or None once `deadline` (port clock) passes first."""
        import serial

        while True:
            while b"\n" not in self._buf:
                remaining = deadline - self._now()
                if remaining <= 0:
                    return None
                try:
                    self._port.timeout = min(remaining, self._read_slice)
                    chunk = self._port.read(max(1, self._port.in_waiting))
                except (serial.SerialException, OSError) as exc:
                    raise PrinterDisconnected(
                        f"{self.port_name}: the printer disconnected ({exc}); check the USB cable and power"
                    ) from exc
                self._buf += chunk
            raw, self._buf = self._buf.split(b"\n", 1)
            text = raw.decode("ascii", errors="replace").strip()
            if text:
                self._log(f"<< {text}")
                return text

    # ---- protocol ------------------------------------------------------------------------
    def _handshake(self) -> None:
        if self.profile["reset_on_open"]:
            deadline = self._now() + self.boot_timeout_s
            while (text := self._readline(deadline)) is not None:
                if classify(text).kind is Reply.START:
                    break
        self._next = 0
        self.send("M110 N0")
        self.firmware_info = parse_m115(self.send("M115"))
        self.send("G90")

    def _remaining_motion(self) -> float:
        return max(0.0, self._motion_done_at - self._now())

    def send(self, command: str, motion_s: float = 0.0) -> list[str]:
        """Send one command as the next numbered line; return its output lines once it is acknowledged.

        `motion_s`: modelled seconds of motion the command may wait for (stretches the timeout).
        """
        if self._closed:
            raise PrinterError(f"{self.port_name}: the connection is closed")
        n = self._next
        self._history[n] = command.strip()
        self._next = n + 1
        line = n
        while True:
            status, value = self._exchange(line, motion_s if line == n else 0.0)
            if status == "ack":
                self.acked.append((line, self._history[line]))
                self.stats.lines += 1
                if line == n:
                    return value
                line += 1
            else:  # the firmware lost lines we thought delivered: go back to the one it asks for
                line = value

    def _exchange(self, n: int, motion_s: float) -> tuple[str, Any]:
        command = self._history[n]
        data = format_line(n, command)
        allowance = self.reply_timeout_s + MOTION_MARGIN * (self._remaining_motion() + motion_s)
        self._log(f">> {data.decode().strip()}")
        self._write(data)
        deadline = self._now() + allowance
        output: list[str] = []
        rejected: str | None = None
        resend: int | None = None
        retries = resends = 0
        while True:
            text = self._readline(deadline)
            if text is None:
                if retries >= self.retries:
                    raise PrinterTimeout(
                        f"{self.port_name}: no reply to line N{n} {command!r} after "
                        f"{retries} retransmission(s) and {allowance:.1f} s each; is the printer "
                        "on, at the profile's baud rate, and running Marlin?"
                    )
                retries += 1
                self.stats.timeouts += 1
                self._write(data)  # safe: Marlin refuses a line number it has already run
                deadline = self._now() + allowance
                continue
            if "\ufffd" in text or not text.isprintable():
                self.stats.ignored += 1  # line noise: a garbled line is no message at all
                continue
            reply = classify(text)
            kind = reply.kind
            if kind is Reply.OK:
                if resend is None:
                    if rejected:
                        raise CommandRejected(f"printer refused {command!r}: {rejected}")
                    return "ack", output
                target, resend = resend, None
                sync = command.upper().startswith("M110")
                if target == n + 1 and not sync:
                    return "ack", output  # we had sent a line it had already run: all is well
                self.stats.resends += 1
                resends += 1
                if resends > max(10, 4 * self.retries):
                    raise PrinterError(
                        f"{self.port_name}: line N{n} {command!r} was refused {resends} times in a "
                        "row; the serial link is too noisy (cable, USB hub, baud rate?)"
                    )
                if target < n:
                    return "rewind", target
                if target > n + 1 and not sync:
                    raise PrinterError(
                        f"{self.port_name}: the printer expects line {target} but the host has sent "
                        f"only up to {n}; is another program talking to the printer?"
                    )
                self._write(data)  # line n itself (or the M110 handshake) again
                deadline = self._now() + allowance
                output, rejected = [], None
            elif kind is Reply.RESEND:
                resend = reply.number
            elif kind is Reply.BUSY:
                self.stats.busy += 1
                deadline = max(deadline, self._now() + self.reply_timeout_s)
            elif kind is Reply.LINE_ERROR:
                pass  # its Resend follows
            elif kind is Reply.FATAL:
                self._closed_after(
                    PrinterHalted,
                    f"the printer halted during {command!r}: {text} "
                    "(needs a reset: power-cycle or reconnect, then home again)",
                )
            elif kind is Reply.START:
                self.homed = False
                self._closed_after(
                    PrinterReset,
                    f"the printer reset itself during line N{n} {command!r} "
                    "(it printed 'start'); its position is lost: stop, reconnect and home again",
                )
            elif kind is Reply.UNKNOWN_COMMAND:
                rejected = text
            elif kind is Reply.ERROR:
                rejected = text
            elif kind is Reply.TEMPERATURE:
                self.stats.temperature_reports += 1
            else:
                output.append(text)

    def _closed_after(self, error: type[PrinterError], message: str) -> None:
        self.close()
        raise error(f"{self.port_name}: {message}")

    # ---- motion --------------------------------------------------------------------------
    def home(self) -> None:
        """G28: home all axes; returns when homing has finished (Marlin acknowledges G28 at the end)."""
        start = None if not self.homed else self.commanded
        self.send("G28", motion_s=self.model.home_time(start))
        self.commanded = tuple(float(self.profile["home_mm"][a]) for a in AXES)
        self.homed = True
        self._motion_done_at = self._now()

    def check_target(
        self, x: float | None, y: float | None, z: float | None
    ) -> tuple[float, float, float]:
        """The full target after filling unspecified axes; OutOfTravel if any axis is outside [0, travel]."""
        base = self.commanded or (0.0, 0.0, 0.0)
        target = []
        for axis, value, current in zip(AXES, (x, y, z), base, strict=True):
            value = current if value is None else float(value)
            limit = float(self.profile["travel_mm"][axis])
            if not math.isfinite(value) or not 0.0 <= value <= limit:
                raise OutOfTravel(
                    f"{self.profile['name']}: target {axis.upper()}={value} mm is outside the travel "
                    f"[0, {limit:g}] mm (printer profile {self.profile.get('source', self.profile['name'])}, "
                    f"travel_mm.{axis}); nothing was sent"
                )
            target.append(value)
        return tuple(target)

    def move_to(
        self,
        x: float | None = None,
        y: float | None = None,
        z: float | None = None,
        feed_mm_s: float | None = None,
    ) -> None:
        """Queue a straight move (G1). Returns when Marlin has *queued* it; see wait_until_idle()."""
        target = self.check_target(x, y, z)
        feed = float(self.profile["default_feed_mm_s"] if feed_mm_s is None else feed_mm_s)
        if not math.isfinite(feed) or feed <= 0:
            raise ConfigError(f"feed_mm_s must be a positive number of mm/s, got {feed_mm_s!r}")
        if not self.homed:
            raise PrinterError("move_to() before home(): the printer does not know where it is")
        words = [
            f"{a.upper()}{v:.3f}"
            for a, v, given in zip(AXES, target, (x, y, z), strict=True)
            if given is not None
        ]
        if not words:
            return
        duration = self.model.move_time(self.commanded, target, feed)
        self.send("G1 " + " ".join(words) + f" F{feed * 60:.1f}")
        self._motion_done_at = max(self._motion_done_at, self._now()) + duration
        self.commanded = target

    def wait_until_idle(self) -> None:
        """M400: returns once every queued move has finished (the head is at rest)."""
        self.send("M400")
        self._motion_done_at = self._now()

    def position(self) -> Position:
        """M114. x, y, z are where the firmware has been told to go; `steps_mm` is where the
        steppers are now. After wait_until_idle() both agree (to one step)."""
        for line in self.send("M114"):
            parsed = parse_m114(line)
            if parsed:
                xyz, counts = parsed
                steps = None
                if counts is not None:
                    per_mm = [float(self.profile["steps_per_mm"][a]) for a in AXES]
                    steps = tuple(c / s for c, s in zip(counts, per_mm, strict=True))
                return Position(*xyz, steps_mm=steps)
        raise PrinterError(f"{self.port_name}: M114 gave no position line")

    def hold_motors(self) -> None:
        """Enable the steppers and switch off their idle timeout for the rest of the run."""
        self.send("M17")
        self.send("M84 S0")

    def emergency_stop(self) -> None:
        """M112, unnumbered so Marlin's emergency parser acts at once; then close. Needs a reset."""
        if self._closed:
            return
        try:
            self._port.write(b"M112\n")
            self._port.flush()
        finally:
            self.homed = False
            self.close()
