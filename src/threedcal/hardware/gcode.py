"""Marlin's host protocol on the wire: numbered, checksummed lines out; classified replies in.

A host line is ``N<n> <command>*<checksum>`` where the checksum is the XOR of every byte before
``*``. Marlin answers each line it reads with exactly one ``ok`` (unless it is lost on the wire);
before that ``ok`` it may print a line error and ``Resend: <n>``, keepalives, echoes, temperature
reports or the command's own output.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum


def checksum(text: str) -> int:
    """XOR of the bytes of `text` (ASCII), as Marlin computes it."""
    value = 0
    for byte in text.encode("ascii"):
        value ^= byte
    return value


def format_line(number: int, command: str) -> bytes:
    """``N<number> <command>*<checksum>\\n``: the form Marlin checks line numbers and checksums on."""
    if "\n" in command or "*" in command or ";" in command:
        raise ValueError(f"a G-code command may not contain newline, '*' or ';': {command!r}")
    if not command.isascii():
        raise ValueError(f"G-code must be ASCII: {command!r}")
    body = f"N{number} {command.strip()}"
    return f"{body}*{checksum(body)}\n".encode("ascii")


@dataclass(frozen=True)
class ParsedLine:
    """A host line as the firmware reads it: number, command and whether the checksum held."""

    number: int | None
    command: str
    checksum_ok: bool | None  # None: the line carried no checksum


_LINE = re.compile(r"^N(-?\d+)\s*(.*?)\*(\d+)\s*$")


def parse_host_line(raw: str) -> ParsedLine:
    raw = raw.strip()
    match = _LINE.match(raw)
    if match:
        body = raw[: raw.rindex("*")]
        return ParsedLine(
            int(match.group(1)), match.group(2).strip(), checksum(body) == int(match.group(3))
        )
    numbered = re.match(r"^N(-?\d+)\s*(.*)$", raw)
    if numbered:
        return ParsedLine(int(numbered.group(1)), numbered.group(2).strip(), None)
    return ParsedLine(None, raw.split("*", 1)[0].strip(), None)


class Reply(Enum):
    OK = "ok"
    RESEND = "resend"
    BUSY = "busy"
    LINE_ERROR = "line_error"  # recoverable: a Resend follows
    FATAL = "fatal"  # the firmware halted; only a reset recovers
    ERROR = "error"  # any other Error: line
    UNKNOWN_COMMAND = "unknown_command"
    TEMPERATURE = "temperature"
    START = "start"  # the firmware (re)booted
    ECHO = "echo"
    INFO = "info"  # anything else: command output (M114, M115), banners, noise


@dataclass(frozen=True)
class Classified:
    kind: Reply
    text: str
    number: int | None = None  # the line asked for by Resend


_FATAL = re.compile(r"halted|kill\(\)|stopped|M999|MINTEMP|MAXTEMP|thermal runaway", re.IGNORECASE)
_LINE_ERRORS = re.compile(r"checksum|line number|last line", re.IGNORECASE)
_TEMPERATURE = re.compile(r"^(ok\s+)?T\d?:\s*-?\d")


def classify(line: str) -> Classified:
    """What a firmware line means to the host (Marlin 1.1/2.x wording)."""
    text = line.strip()
    low = text.lower()
    if low == "ok" or low.startswith("ok ") or low.startswith("ok:"):
        return Classified(Reply.OK, text)
    match = re.match(r"^(?:resend:|rs)\s*N?(\d+)", text, re.IGNORECASE)
    if match:
        return Classified(Reply.RESEND, text, int(match.group(1)))
    if low.startswith("error:") or low.startswith("!!"):
        if _FATAL.search(text):
            return Classified(Reply.FATAL, text)
        if _LINE_ERRORS.search(text):
            return Classified(Reply.LINE_ERROR, text)
        return Classified(Reply.ERROR, text)
    if "busy:" in low:
        return Classified(Reply.BUSY, text)
    if low.startswith("echo:unknown command") or low.startswith("unknown command"):
        return Classified(Reply.UNKNOWN_COMMAND, text)
    if low == "start":
        return Classified(Reply.START, text)
    if _TEMPERATURE.match(text):
        return Classified(Reply.TEMPERATURE, text)
    if low.startswith("echo:"):
        return Classified(Reply.ECHO, text)
    return Classified(Reply.INFO, text)


_M114 = re.compile(
    r"X:\s*(-?[\d.]+)\s+Y:\s*(-?[\d.]+)\s+Z:\s*(-?[\d.]+)"
    r"(?:.*?Count\s+X:\s*(-?\d+)\s+Y:\s*(-?\d+)\s+Z:\s*(-?\d+))?"
)


def parse_m114(line: str) -> tuple[tuple[float, float, float], tuple[int, int, int] | None] | None:
    """``X:10.00 Y:0.00 Z:5.00 E:0.00 Count X:800 Y:0 Z:2000`` → ((x, y, z) mm, step counts)."""
    match = _M114.search(line)
    if not match:
        return None
    xyz = (float(match.group(1)), float(match.group(2)), float(match.group(3)))
    counts = None
    if match.group(4) is not None:
        counts = (int(match.group(4)), int(match.group(5)), int(match.group(6)))
    return xyz, counts


def parse_m115(lines: list[str]) -> dict[str, str]:
    """``FIRMWARE_NAME:Marlin 2.1.2 SOURCE_CODE_URL:... MACHINE_TYPE:Ender-3`` → a dict; ``Cap:`` lines too."""
    info: dict[str, str] = {}
    keys = (
        "FIRMWARE_NAME",
        "SOURCE_CODE_URL",
        "PROTOCOL_VERSION",
        "MACHINE_TYPE",
        "EXTRUDER_COUNT",
        "UUID",
    )
    for line in lines:
        if line.startswith("Cap:"):
            name, _, value = line[4:].partition(":")
            info[f"Cap:{name}"] = value.strip()
            continue
        positions = sorted((line.find(f"{k}:"), k) for k in keys if f"{k}:" in line)
        for i, (start, key) in enumerate(positions):
            end = positions[i + 1][0] if i + 1 < len(positions) else len(line)
            info[key] = line[start + len(key) + 1 : end].strip()
    return info
