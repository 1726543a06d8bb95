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

import math
import re
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.hardware.gcode import Reply, classify, format_line, parse_m114, parse_m115
from threedcal.hardware.motion import AXES, MotionModel
from threedcal.profiles import load_profile

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
    return load_profile("printer", ref, defaults=True)


def register_url_handlers() -> None:
    import serial  # optional (hardware extra); printer_profile needs none

    for package in URL_HANDLER_PACKAGES:
        if package not in serial.protocol_handler_packages:
            serial.protocol_handler_packages.append(package)


def open_port(port: str, baudrate: int = 115200):
    """Open a device path (``/dev/ttyUSB0``, ``COM3``) or a pyserial URL (``simmarlin://x``)."""
    import serial  # optional (hardware extra); printer_profile needs none

    register_url_handlers()
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=0.1, write_timeout=5)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise PrinterDisconnected(f"cannot open printer port {port!r}: {exc}") from exc


def list_ports() -> list[tuple[str, str, str]]:
    """(device, description, hardware id) of every serial port the OS reports."""
    from serial.tools import list_ports as lp  # optional (hardware extra)

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


_ADVANCED_OK = re.compile(r"(?:N\d+\s*)?(?:P\d+\s*)?(?:B\d+\s*)?")
_LAST_LINE = re.compile(r"Last Line:\s*(\d+)", re.IGNORECASE)


@dataclass
class _Answer:
    """What arrived since the last `ok`: the parts of the firmware's answer to one line."""

    resend: int | None = None  # Resend: k
    error: str | None = None  # a line error (checksum, line number)
    refusal: str | None = None  # Unknown command / other Error: the line ran but was refused

    def __bool__(self) -> bool:
        """True when the answer is a refusal of the line (it did not run)."""
        return self.resend is not None or self.error is not None

    def wanted(self) -> int | None:
        """The line the firmware wants next: Resend's number, else the error's Last Line + 1."""
        if self.resend is not None:
            return self.resend
        match = _LAST_LINE.search(self.error or "")
        return int(match.group(1)) + 1 if match else None

    def is_checksum_error(self) -> bool:
        text = (self.error or "").lower()
        return "checksum" in text and "line number" not in text


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
        self.ack_times: dict[int, float] = {}  # port-clock time each line was known to have run
        self.transmissions: Counter[int] = Counter()  # how often each line number was sent
        self.firmware_info: dict[str, str] = {}
        self.homed = False
        self.commanded: tuple[float, float, float] | None = None
        self._log = log or (lambda text: None)
        self._history: dict[int, str] = {}
        self._next = 0
        self._buf = b""
        self._motion_done_at = 0.0
        self._closed = False
        self._unanswered: deque[int] = deque()  # line of each transmission whose answer is owed
        self._unsettled: int | None = None  # a line whose exchange an interrupt cut off
        self._sync_lines: set[int] = set()  # lines that were M110 (a repeat of one runs again)
        self._in_exchange = False
        self._interrupt: BaseException | None = None
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
        import serial  # optional (hardware extra); printer_profile needs none

        try:
            self._port.write(data)
            self.stats.writes += 1
        except (serial.SerialException, OSError) as exc:
            raise PrinterDisconnected(
                f"{self.port_name}: write failed ({exc}); is the printer still connected?"
            ) from exc

    def _readline(self, deadline: float) -> str | None:
        """The next non-empty line, or None once `deadline` (port clock) passes first."""
        import serial  # optional (hardware extra); printer_profile needs none

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

    @property
    def in_exchange(self) -> bool:
        """True while a line is on its way (sent, its fate not yet known)."""
        return self._in_exchange

    def interrupt_after_exchange(self, error: BaseException) -> bool:
        """Raise `error` once the line now in flight is settled (True), or refuse (False: no line
        in flight, or one interrupt is already waiting) so the caller raises it at once."""
        if not self._in_exchange or self._interrupt is not None:
            return False
        self._interrupt = error
        return True

    def send(self, command: str, motion_s: float = 0.0) -> list[str]:
        """Send one command as the next numbered line; return its output lines once it has run.

        `motion_s`: modelled seconds of motion the command may wait for (stretches the timeout).
        """
        if self._closed:
            raise PrinterError(f"{self.port_name}: the connection is closed")
        if self._unsettled is not None:
            # An earlier exchange was cut off (an interrupt): settle that line first. Safe: the
            # firmware runs it at most once, and only lines in order.
            n, self._unsettled = self._unsettled, None
            self._finish(n, self._deliver(n, 0.0))
        n = self._next
        self._history[n] = command.strip()
        self._next = n + 1
        if self._history[n].upper().startswith("M110"):
            self._sync_lines.add(n)
        return self._finish(n, self._deliver(n, motion_s))

    def _finish(self, n: int, output: list[str]) -> list[str]:
        self.acked.append((n, self._history[n]))
        self.ack_times[n] = self._now()
        self.stats.lines += 1
        if self._interrupt is not None:
            error, self._interrupt = self._interrupt, None
            raise error
        return output

    def _transmit(self, n: int, data: bytes) -> None:
        self._log(f">> {data.decode().strip()}")
        self._write(data)
        self._unanswered.append(n)
        self.transmissions[n] += 1

    def _deliver(self, n: int, motion_s: float) -> list[str]:
        """Transmit line `n` until the firmware has run it; its output lines.

        Marlin answers every line it receives with one `ok`, preceded by an error and `Resend: k`
        when it refused the line (k = its last line + 1). It runs only line last + 1, so sending
        a line again is always safe. What is known for certain, and used: an `ok` with no error
        before it means the line now in flight ran (every earlier one had); `Resend: k` (or an
        error's `Last Line: k-1`) with k > n means it ran. `Resend: n` means it had not run when
        that answer was written: a refusal of this line, or a stale answer to an extra copy of
        the previous line (sent after a timeout), told apart by the error (a checksum error can
        only be about the line in flight) and by the count of answers still owed.
        """
        self._in_exchange = True
        try:
            return self._deliver_line(n, motion_s)
        except CommandRejected:
            raise  # the line was read and answered: settled
        except BaseException:
            if not self._closed:
                self._unsettled = n  # settled first by the next send()
            self._interrupt = None  # the exception that ended the exchange is what propagates
            raise
        finally:
            self._in_exchange = False

    def _deliver_line(self, n: int, motion_s: float) -> list[str]:
        command = self._history[n]
        data = format_line(n, command)
        allowance = self.reply_timeout_s + MOTION_MARGIN * (self._remaining_motion() + motion_s)
        self._transmit(n, data)
        deadline = self._now() + allowance
        output: list[str] = []
        answer = _Answer()
        retries = refusals = 0
        printed = False  # output lines since the last `ok`
        while True:
            text = self._readline(deadline)
            if text is None:
                if answer:  # an error (and maybe Resend) whose `ok` was lost: it is the answer
                    outcome, answer = self._settle(n, answer), _Answer()
                else:
                    retries = self._retransmit_after_silence(n, data, retries, allowance)
                    deadline = self._now() + allowance
                    continue
            elif "\ufffd" in text or not text.isprintable():
                self.stats.ignored += 1  # line noise: a garbled line is no message at all
                continue
            else:
                reply = classify(text)
                kind = reply.kind
                if kind is Reply.OK:
                    extra = text[2:].strip(" :")
                    if extra and not _ADVANCED_OK.fullmatch(extra):
                        output.append(extra)  # a report on the ok line (`ok X:1 Y:2 Z:3`)
                    outcome, answer = self._settle(n, answer, printed), _Answer()
                    printed = False
                elif kind is Reply.RESEND:
                    answer.resend = reply.number
                    continue
                elif kind is Reply.LINE_ERROR:
                    answer.error = text
                    continue
                elif kind is Reply.BUSY:
                    self.stats.busy += 1
                    deadline = max(deadline, self._now() + self.reply_timeout_s)
                    continue
                elif kind in (Reply.FATAL, Reply.START):
                    self._stopped(kind, text, n)
                elif kind in (Reply.UNKNOWN_COMMAND, Reply.ERROR):
                    answer.refusal = text
                    continue
                elif kind is Reply.TEMPERATURE:
                    self.stats.temperature_reports += 1
                    continue
                else:
                    if answer:
                        # Output after a refusal: the refusal's `ok` was lost and a copy of line n
                        # is running now (a refused line prints nothing). Settle the refusal for
                        # the count of owed answers; the running copy's `ok` answers for line n.
                        outcome, answer = self._settle(n, answer), _Answer()
                        if outcome == "ran":
                            return output
                    output.append(text)
                    printed = True
                    continue
            # one whole answer has arrived: act on what it says about line n
            if outcome == "ran":
                return output
            if outcome == "refused":
                refusals = self._resend_refused(n, data, refusals)
                deadline = self._now() + allowance
            # "stale": an answer owed to an earlier copy; keep waiting for this line's own

    def _retransmit_after_silence(self, n: int, data: bytes, retries: int, allowance: float) -> int:
        """Send line n again after no reply in time (safe: Marlin refuses a line number it has
        run); a PrinterTimeout once the profile's retries are spent. Returns the retries made."""
        if retries >= self.retries:
            raise PrinterTimeout(
                f"{self.port_name}: no reply to line N{n} {self._history[n]!r} after "
                f"{retries} retransmission(s) and {allowance:.1f} s each; is the printer "
                "on, at the profile's baud rate, and running Marlin?"
            )
        self.stats.timeouts += 1
        self._transmit(n, data)
        return retries + 1

    def _resend_refused(self, n: int, data: bytes, refusals: int) -> int:
        """Send a refused line n again (a checksum error or a Resend); a link that refuses it over
        and over is too noisy to go on. Returns the refusals so far."""
        self.stats.resends += 1
        refusals += 1
        if refusals > max(10, 4 * self.retries):
            raise PrinterError(
                f"{self.port_name}: line N{n} {self._history[n]!r} was refused {refusals} times "
                "in a row; the serial link is too noisy (cable, USB hub, baud rate?)"
            )
        self._transmit(n, data)
        return refusals

    def _stopped(self, kind, text: str, n: int) -> None:
        """The printer halted (a fatal error) or reset itself during line n: it cannot go on."""
        self.homed = False
        command = self._history[n]
        if kind is Reply.FATAL:
            raise PrinterHalted(
                f"{self.port_name}: the printer halted during {command!r}: {text} "
                "(needs a reset: power-cycle or reconnect, then home again)"
            )
        raise PrinterReset(
            f"{self.port_name}: the printer reset itself during line N{n} {command!r} "
            "(it printed 'start'); its position is lost: stop, reconnect and home again"
        )

    def _settle(self, n: int, answer: _Answer, printed: bool = False) -> str:
        """What one complete answer says about line n: "ran", "refused" or "stale".

        `printed`: output lines came with it (only a line that runs prints anything)."""
        oldest = self._unanswered.popleft() if self._unanswered else n
        command = self._history[n]
        if not answer:
            if oldest in self._sync_lines and oldest != n and not printed:
                return "stale"  # a repeated M110 runs again (it is exempt from the line check)
            # accepted and run; only line n can have been (every earlier line had run already)
            while self._unanswered and self._unanswered[0] < n:
                self._unanswered.popleft()  # answers that were lost on the way
            if answer.refusal:
                raise CommandRejected(f"printer refused {command!r}: {answer.refusal}")
            return "ran"
        if command.upper().startswith("M110"):
            return "refused"  # M110 is exempt from the line check: any error means it did not run
        wanted = answer.wanted()
        if wanted is None:
            # an error with neither Resend nor Last Line: a refusal, of this copy or an earlier one
            return "stale" if oldest < n and not answer.is_checksum_error() else "refused"
        if wanted > n + 1:
            raise PrinterError(
                f"{self.port_name}: the printer expects line {wanted} but the host has sent only "
                f"up to {n}; is another program talking to the printer?"
            )
        if wanted == n + 1:
            return "ran"  # it had run line n; this copy was refused as a repeat
        if wanted < n:
            raise PrinterError(
                f"{self.port_name}: the printer asks for line {wanted} again after confirming it "
                f"(host at line {n}); it lost lines it had acknowledged: stop, reconnect and home"
            )
        if answer.is_checksum_error() or oldest >= n:
            while self._unanswered and self._unanswered[0] < n:
                self._unanswered.popleft()  # owed answers that will never come
            return "refused"
        return "stale"  # "Resend: n" owed to a repeat of line n - 1, sent before line n

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

    def release_motors(self) -> None:
        """After a run or a safe stop, what the profile's `safe_stop.release` says: `steppers_off`
        (M84: the head can be moved by hand; the position is lost), `idle_timeout` (M84 S<s>:
        Marlin releases them after that long idle) or `hold` (keep them energised)."""
        settings = self.profile["safe_stop"]
        mode = settings["release"]
        if mode == "steppers_off":
            self.send("M84")
            self.homed = False
        elif mode == "idle_timeout":
            self.send(f"M84 S{int(round(float(settings['idle_timeout_s'])))}")

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
