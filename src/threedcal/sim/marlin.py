"""A fake Marlin firmware: the host protocol, a motion-time model on a virtual clock, seeded faults.

Open it through pyserial exactly like a printer::

    MarlinHost("simmarlin://bench?seed=1&faults=checksum,drop_ok&rate=0.05&speedup=1000", profile)

The URL names a firmware in this module's registry; the first open creates it from the URL's
options (``printer``, ``seed``, ``faults``, ``rate``, ``speedup``, ``reset_on_open``), later opens of
the same name reach the same object. A bench can also build one itself and ``register`` it before
the host opens the URL. Either way ``FIRMWARES.get(name)`` returns the object, whose
``position()`` (physical head position now), ``clock.now()`` (simulated seconds),
``motion_time_s`` (modelled seconds of motion and homing) and ``executed`` (the command log)
are what the simulated bench and the tests read.

Faults are decided per received numbered line, from a seeded generator (same seed and same host
traffic → same faults). Recoverable kinds: ``checksum`` (line corrupted on the way in → Error +
Resend), ``drop_line`` (line lost on the way in), ``drop_ok`` (executed, ``ok`` lost on the way
out), ``busy`` (extra ``echo:busy: processing`` keepalives), ``slow`` (reply delayed 0.5–2.5 s),
``noise`` (a garbage line), ``temp`` (an interleaved temperature report), ``drop_resend_ok``
(line corrupted; its ``Resend:`` arrives but the ``ok`` after it is lost), ``drop_resend`` (line
corrupted; only ``Error:...`` and ``ok`` arrive, the ``Resend:`` is lost), ``late`` (the board
stalls: the reply comes 1.2–2× the profile's reply timeout after it was due, with no ``busy:``
keepalive) and ``ok_report`` (an M114 answered on the ok line, ``ok X:.. Y:.. Z:..``, as some
firmwares do; counted only on M114 lines). Fatal kinds, only when named explicitly or scheduled
with ``schedule_fault``: ``reset`` (the board reboots: ``start``), ``disconnect`` (the port
vanishes), ``halt`` (``Error:Printer halted. kill() called!``).

For the soak test the board keeps the ground truth: ``executed`` (number, command) with
``done_at`` (when each finished: queued for a move, at rest for M400), ``received`` (how often
each line number arrived) and ``fault_log`` (line number and kind of every injected fault).
"""

from __future__ import annotations

import math
import random
import re
import uuid
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

from threedcal.errors import ConfigError
from threedcal.hardware.gcode import parse_host_line
from threedcal.hardware.motion import MotionModel, Trapezoid
from threedcal.hardware.printer import printer_profile
from threedcal.sim.clock import VirtualClock
from threedcal.sim.devices import DeviceRegistry

RECOVERABLE_FAULTS = (
    "checksum",
    "drop_line",
    "drop_ok",
    "busy",
    "slow",
    "noise",
    "temp",
    "drop_resend_ok",
    "drop_resend",
    "late",
    "ok_report",
)
CORRUPTING_FAULTS = ("checksum", "drop_resend_ok", "drop_resend")
FATAL_FAULTS = ("reset", "disconnect", "halt")
FAULT_KINDS = RECOVERABLE_FAULTS + FATAL_FAULTS
BOOT_S = 1.5  # simulated seconds from reset to `start` (bootloader + init)
BANNER = (
    "start",
    "echo:Marlin 2.1.2.1 (threedcal simulated firmware)",
    "echo: Last Updated: 2023-07-13 | Author: (threedcal)",
    "echo:Compiled: Jul 13 2023",
    "echo: Free Memory: 2861  PlannerBufferBytes: 1344",
)


@dataclass
class _Move:
    t_start: float
    t_end: float
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    profile: Trapezoid | None  # None: homing, interpolated linearly in time

    def position(self, t: float) -> tuple[float, float, float]:
        if t <= self.t_start:
            return self.p0
        if t >= self.t_end:
            return self.p1
        if self.profile is None:
            frac = (t - self.t_start) / (self.t_end - self.t_start)
        else:
            frac = self.profile.distance_at(t - self.t_start) / self.profile.distance
        return tuple(a + (b - a) * frac for a, b in zip(self.p0, self.p1, strict=True))


def parse_faults(text: str | None) -> tuple[str, ...]:
    """``"checksum,drop_ok"`` / ``"all"`` (every recoverable kind) / ``""`` → fault kinds."""
    if not text:
        return ()
    if text == "all":
        return RECOVERABLE_FAULTS
    if not isinstance(text, str):
        raise ConfigError(f"faults must be a comma-separated text, got {text!r}")
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in FAULT_KINDS]
    if bad:
        raise ConfigError(
            f"unknown fault kind(s) {', '.join(map(repr, bad))} "
            f"(allowed: all, {', '.join(FAULT_KINDS)})"
        )
    return kinds


class SimMarlin:
    """One simulated printer board: serial protocol, planner, steppers, clock and fault injector."""

    def __init__(
        self,
        profile: str | Mapping = "ender3",
        *,
        seed: int = 0,
        faults: str | tuple[str, ...] = (),
        rate: float = 0.0,
        speedup: float = 1.0,
        reset_on_open: bool | None = None,
    ):
        self.profile = printer_profile(profile)
        self.model = MotionModel(self.profile)
        self.clock = VirtualClock(speedup)
        self.kinds = parse_faults(faults) if isinstance(faults, str) else tuple(faults)
        parse_faults(",".join(self.kinds))
        if not 0.0 <= rate <= 1.0:  # False for nan too
            raise ConfigError(f"fault rate must be in [0, 1], got {float(rate)}")
        self.rate = float(rate) if self.kinds else 0.0
        self.seed = int(seed)
        self._rng = random.Random(self.seed)
        self.reset_on_open = (
            self.profile["reset_on_open"] if reset_on_open is None else bool(reset_on_open)
        )
        self.keepalive_s = float(self.profile["keepalive_s"])
        self.baud = int(self.profile["baudrate"])
        self.reply_timeout_s = float(self.profile["timeouts_s"]["reply"])
        self.executed: list[tuple[int | None, str]] = []
        self.done_at: list[float] = []  # when each executed command finished (parallel list)
        self.received: Counter[int] = Counter()  # numbered lines, by how often each arrived
        self.fault_log: list[tuple[int | None, str]] = []
        self.faults_injected: Counter[str] = Counter()
        self.clamped = 0  # moves clipped by the soft endstops
        self.motion_time_s = 0.0
        self.connected = False
        self.disconnected = False
        self.url_query: str | None = None
        self._scheduled: deque[str] = deque()
        self._out: deque[tuple[float, bytes]] = deque()
        self._last_due = 0.0
        self._rx = b""
        self._rest = tuple(float(v) for v in self.model.home)  # head position when no move runs
        self._power_on(0.0)

    # ---- state -----------------------------------------------------------------------------
    def _power_on(self, t: float) -> None:
        self._rest = self.position(t) if hasattr(self, "_moves") else self._rest
        self._moves: deque[_Move] = deque()
        self.last_line = 0
        self.homed = False
        self.halted = False
        self.absolute = True
        self.feed = float(self.profile["default_feed_mm_s"])
        self.commanded = self._rest
        self.motors_on = False
        self.idle_timeout_s = 120.0
        self._ready = t  # the firmware can start the next command at this time
        self._planned_end = t
        self.boots = getattr(self, "boots", 0) + 1

    def position(self, t: float | None = None) -> tuple[float, float, float]:
        """Physical head position (mm, quantised to whole steps) at simulated time `t` (default now)."""
        t = self.clock.now() if t is None else t
        for move in self._moves:
            if t < move.t_end:
                return self.model.quantise(move.position(t))
        return self.model.quantise(self._moves[-1].p1 if self._moves else self._rest)

    def busy_until(self) -> float:
        """Simulated time at which every queued move has finished."""
        return self._planned_end

    def executed_commands(self) -> list[str]:
        return [command for _, command in self.executed]

    def schedule_fault(self, kind: str) -> None:
        """Inject `kind` on the next numbered line received (any kind, fatal ones included)."""
        parse_faults(kind)
        self._scheduled.append(kind)

    def _prune(self, t: float) -> None:
        while self._moves and self._moves[0].t_end <= t:
            self._rest = self._moves.popleft().p1

    # ---- the serial side (used by the pyserial handler) --------------------------------------
    def open(self) -> None:
        self.connected = True
        self._out.clear()
        self._rx = b""
        if self.reset_on_open:
            self._reboot(self.clock.now())

    def close(self) -> None:
        self.connected = False

    def _reboot(self, t: float) -> None:
        self._out.clear()
        self._last_due = t
        self._power_on(t)
        self._ready = t + BOOT_S
        for line in BANNER:
            self._emit(t + BOOT_S, line)

    def _emit(self, t: float, text: str | bytes) -> None:
        data = text if isinstance(text, bytes) else text.encode("ascii")
        due = max(t, self._last_due)
        self._last_due = due
        self._out.append((due, data + b"\n"))

    def next_due(self, now: float) -> float | None:
        """When the next queued output will have reached the host; None when nothing is queued."""
        return self._out[0][0] if self._out else None

    def reset_input(self, now: float) -> None:
        """Drop the output that has reached the host by `now`."""
        self.take(1 << 30, now)

    def waiting(self, now: float) -> int:
        return sum(len(data) for due, data in self._out if due <= now)

    def take(self, size: int, now: float) -> bytes:
        """Up to `size` bytes of output that has reached the host by `now`."""
        chunks = []
        while self._out and size > 0 and self._out[0][0] <= now:
            due, data = self._out.popleft()
            if len(data) > size:
                self._out.appendleft((due, data[size:]))
                data = data[:size]
            chunks.append(data)
            size -= len(data)
        return b"".join(chunks)

    def receive(self, data: bytes) -> None:
        """Bytes from the host; complete lines are handled at their arrival time (115200 baud)."""
        now = self.clock.now()
        self._rx += data
        arrival = now + 10.0 * len(data) / self.baud
        while b"\n" in self._rx:
            raw, self._rx = self._rx.split(b"\n", 1)
            text = raw.decode("ascii", errors="replace").strip()
            if text:
                self._handle_line(text, arrival)

    # ---- protocol ----------------------------------------------------------------------------
    def _pick_fault(self, kinds_allowed: tuple[str, ...]) -> str | None:
        if self._scheduled:
            return self._scheduled.popleft()
        if self.rate and self._rng.random() < self.rate:
            return self._rng.choice(kinds_allowed)
        return None

    def _handle_line(self, text: str, arrival: float) -> None:
        if self.halted:
            return
        line = parse_host_line(text)
        if line.command.upper().startswith("M112"):  # the emergency parser acts on arrival
            self._halt(arrival, "Error:Printer halted. kill() called!")
            self.executed.append((line.number, "M112"))
            self.done_at.append(arrival)
            return
        fault = self._pick_fault(self.kinds) if line.number is not None else None
        if fault == "ok_report" and not line.command.upper().startswith("M114"):
            fault = None  # only an M114 has a report to put on its ok line
        if fault:
            self.faults_injected[fault] += 1
            self.fault_log.append((line.number, fault))
        t = max(arrival, self._ready)
        if fault == "drop_line":
            return
        if line.number is not None:
            self.received[line.number] += 1
        if fault == "reset":
            self._reboot(arrival)
            return
        if fault == "disconnect":
            self.disconnected = True
            return
        if fault == "halt":
            self._halt(t, "Error:Printer halted. kill() called!")
            return
        if line.number is not None:
            error = self._line_error(line, fault in CORRUPTING_FAULTS)
            if error:
                self._emit(t, f"Error:{error}, Last Line: {self.last_line}")
                if fault != "drop_resend":
                    self._emit(t, f"Resend: {self.last_line + 1}")
                if fault != "drop_resend_ok":
                    self._emit(t, "ok")
                return
            self.last_line = line.number
        replies, done = self._execute(line.command, t)
        self.executed.append((line.number, line.command))
        self.done_at.append(done)
        self._ready = done
        if fault == "slow":
            done += self._rng.uniform(0.5, 2.5)
        if fault == "late":  # the board stalls past the host's timeout, with no keepalive
            done += self.reply_timeout_s * self._rng.uniform(1.2, 2.0) + (done - arrival)
            self._ready = done
        if fault == "busy":
            for _ in range(self._rng.randint(1, 3)):
                done += self.keepalive_s
                replies.append((done, "echo:busy: processing"))
        if fault == "noise":
            junk = bytes([self._rng.randrange(0x80, 0x100)]) + bytes(
                self._rng.choice([*range(0x20, 0x7F), *range(0x80, 0x100)])
                for _ in range(self._rng.randint(2, 24))
            )
            self._emit(t, junk)
        if fault == "temp":
            self._emit(t, "T:24.87 /0.00 B:24.12 /0.00 @:0 B@:0")
        if fault == "ok_report":
            report = " ".join(text for _, text in replies)
            replies = []
            self._emit(done, f"ok {report}")
        for when, reply in replies:
            self._emit(when, reply)
        if fault not in ("drop_ok", "ok_report"):
            self._emit(done, "ok")

    def _line_error(self, line, corrupted: bool) -> str | None:
        is_m110 = re.match(r"^M110\b", line.command, re.IGNORECASE) is not None
        if line.number != self.last_line + 1 and not is_m110:
            return "Line Number is not Last Line Number+1"
        if line.checksum_ok is None:
            return "No Checksum with line number"
        if corrupted or not line.checksum_ok:
            return "checksum mismatch"
        return None

    def _halt(self, t: float, message: str) -> None:
        self._prune(t)
        self._rest = self.position(t)
        self._moves.clear()
        self._planned_end = t
        self.halted = True
        self._emit(t, message)

    def _keepalives(self, start: float, end: float) -> list[tuple[float, str]]:
        n = int(math.floor((end - start) / self.keepalive_s - 1e-9))
        return [(start + (i + 1) * self.keepalive_s, "echo:busy: processing") for i in range(n)]

    def _execute(self, command: str, t: float) -> tuple[list[tuple[float, str]], float]:
        """Run one command received at `t`; return its output lines and when its `ok` is due."""
        self._prune(t)
        words = command.split()
        code = words[0].upper() if words else ""
        args: dict[str, float | None] = {}
        for word in words[1:]:
            try:
                args[word[0].upper()] = float(word[1:]) if len(word) > 1 else None
            except ValueError:
                return [(t, f'echo:Unknown command: "{command}"')], t
        if code in ("G0", "G1"):
            return self._linear_move(args, t)
        if code == "G28":
            start = max(t, self._planned_end)
            here = self.position(start)
            duration = self.model.home_time(here)  # the real head knows where it is
            home = tuple(float(v) for v in self.model.home)
            self._moves.append(_Move(start, start + duration, here, home, None))
            self.motion_time_s += duration
            self._planned_end = start + duration
            self.commanded, self.homed, self.motors_on = home, True, True
            return self._keepalives(t, self._planned_end), self._planned_end
        if code == "M400":
            done = max(t, self._planned_end)
            return self._keepalives(t, done), done
        if code == "G4":
            wait = (args.get("S") or 0.0) + (args.get("P") or 0.0) / 1000.0
            done = max(t, self._planned_end) + wait
            self._planned_end = done
            return self._keepalives(t, done), done
        if code == "M114":
            x, y, z = self.commanded
            cx, cy, cz = self.model.steps(self.position(t))
            text = f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:0.00 Count X:{cx} Y:{cy} Z:{cz}"
            return [(t, text)], t
        if code == "M115":
            return [
                (
                    t,
                    "FIRMWARE_NAME:Marlin 2.1.2.1 (threedcal sim) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
                    "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender-3 (simulated) EXTRUDER_COUNT:1 "
                    "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff",
                ),
                (t, "Cap:EMERGENCY_PARSER:1"),
                (t, "Cap:AUTOREPORT_TEMP:1"),
            ], t
        if code == "M110":
            if args.get("N") is not None:
                self.last_line = int(args["N"])
            return [], t
        if code == "M105":
            return [(t, "T:24.87 /0.00 B:24.12 /0.00 @:0 B@:0")], t
        if code == "M17":
            self.motors_on = True
            return [], t
        if code in ("M18", "M84"):
            if "S" in args:
                self.idle_timeout_s = args["S"] or 0.0
            else:
                self.motors_on = False
                self.homed = False  # Marlin forgets the position when the steppers are released
            return [], t
        if code == "G90":
            self.absolute = True
            return [], t
        if code == "G91":
            self.absolute = False
            return [], t
        if code in ("M155", "M82", "M83", "M106", "M107"):
            return [], t
        return [(t, f'echo:Unknown command: "{command}"')], t

    def _linear_move(self, args: Mapping[str, Any], t: float) -> tuple[list, float]:
        if args.get("F") is not None:
            if args["F"] <= 0:
                return [(t, "echo:Invalid feedrate")], t
            self.feed = args["F"] / 60.0
        target = list(self.commanded)
        for i, axis in enumerate("XYZ"):
            if args.get(axis) is not None:
                target[i] = args[axis] if self.absolute else target[i] + args[axis]
        if self.homed:  # soft endstops clip silently, as Marlin does
            for i, limit in enumerate(self.model.travel):
                clipped = min(max(target[i], 0.0), limit)
                if clipped != target[i]:
                    self.clamped += 1
                    target[i] = clipped
        target = tuple(target)
        # A full planner blocks the command (and so its `ok`) until the oldest move finishes.
        ends = sorted(m.t_end for m in self._moves if m.t_end > t)
        slots = int(self.profile["planner_slots"])
        queued = t if len(ends) < slots else ends[len(ends) - slots]
        start = max(queued, self._planned_end)
        profile = self.model.move(self.commanded, target, self.feed)
        if profile.distance > 0:
            self._moves.append(
                _Move(start, start + profile.duration, self.commanded, target, profile)
            )
            self._planned_end = start + profile.duration
            self.motion_time_s += profile.duration
        self.commanded = target
        self.motors_on = True
        return self._keepalives(t, queued), queued


# How the pyserial handler and the bench find the same firmware.
FIRMWARES: DeviceRegistry[SimMarlin] = DeviceRegistry(
    "simmarlin", "simulated firmware", "open simmarlin://NAME first"
)


def url(name: str, **options: Any) -> str:
    """``simmarlin://name?k=v&...`` for the given options (faults as a comma list)."""
    query = "&".join(
        f"{k}={','.join(v) if isinstance(v, tuple | list) else v}" for k, v in options.items()
    )
    return f"simmarlin://{name}" + (f"?{query}" if query else "")


_URL_OPTIONS = ("printer", "seed", "faults", "rate", "speedup", "reset_on_open")


def firmware_for_url(port_url: str) -> SimMarlin:
    """The registered firmware named by the URL, created from its options on first use."""
    parts = urlsplit(port_url)
    if parts.scheme.lower() != "simmarlin" or not parts.netloc:
        raise ConfigError(f"expected simmarlin://NAME[?options], got {port_url!r}")
    name = parts.netloc
    options = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    unknown = sorted(set(options) - set(_URL_OPTIONS))
    if unknown:
        raise ConfigError(
            f"{port_url}: unknown option(s) {', '.join(unknown)} (allowed: {', '.join(_URL_OPTIONS)})"
        )
    if name in FIRMWARES:
        firmware = FIRMWARES.get(name)
        if parts.query and firmware.url_query is not None and parts.query != firmware.url_query:
            raise ConfigError(
                f"{port_url}: simulated firmware {name!r} exists with other options "
                f"({firmware.url_query!r}); open it without options or withdraw it first"
            )
        return firmware
    try:
        firmware = SimMarlin(
            options.get("printer", "ender3"),
            seed=int(options.get("seed", 0)),
            faults=options.get("faults", ""),
            rate=float(options.get("rate", 0.0)),
            speedup=float(options.get("speedup", 1.0)),
            reset_on_open=(
                None
                if "reset_on_open" not in options
                else options["reset_on_open"].lower() in ("1", "true", "yes")
            ),
        )
    except ValueError as exc:
        raise ConfigError(f"{port_url}: {exc}") from exc
    firmware.url_query = parts.query
    return FIRMWARES.serve(name, firmware)


class FirmwareBench:
    """A SimMarlin registered under a fresh name, reachable at `url`; `close` (or `with`) forgets it.

    The simulated benches (gel camera, ReSkin board) build on it: each adds its sensor.
    """

    def __init__(
        self,
        prefix: str,
        printer: str | Mapping = "ender3",
        *,
        seed: int,
        faults: str = "",
        fault_rate: float = 0.0,
        speedup: float = math.inf,
    ):
        self.firmware = SimMarlin(
            printer, seed=seed, faults=faults, rate=fault_rate, speedup=speedup
        )
        self.name = f"{prefix}-{uuid.uuid4().hex[:10]}"
        FIRMWARES.serve(self.name, self.firmware)
        self.url = f"simmarlin://{self.name}"

    def close(self) -> None:
        FIRMWARES.withdraw(self.name)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
