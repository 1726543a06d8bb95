"""Soak test of the host against the fake firmware: many injected faults of each class, nothing
lost, repeated, reordered or acknowledged before it ran.

The firmware's logs are the ground truth: every numbered line the host counts as done must appear
in the executed log exactly once, in order, and must have finished (been queued, for a move; the
head at rest, for M400) no later than the host said so. (The M110 line-number reset of the
handshake is excluded: it is exempt from Marlin's line check and harmless to repeat.) Each fault
class runs on its own firmware, so the table says which class costs what; `mixed` injects every
class at once.
"""

from __future__ import annotations

import math
import random
from collections import Counter
from dataclasses import dataclass, field

from tqdm import tqdm

from threedcal.errors import ConfigError
from threedcal.hardware.printer import MarlinHost, PrinterError
from threedcal.sim.marlin import FIRMWARES, RECOVERABLE_FAULTS, SimMarlin, parse_faults

COLUMNS = (
    ("class", 15),
    ("faults", 7),
    ("lines", 7),
    ("lost", 5),
    ("duplicated", 11),
    ("acked_early", 12),
    ("out_of_step", 12),
    ("bad_reports", 12),
)


@dataclass(frozen=True)
class SoakResult:
    kind: str  # the fault class, or "mixed"
    faults: int  # faults injected (of that class; of every class for "mixed")
    sent: int  # distinct numbered lines the host sent
    executed: int
    lost: int  # acknowledged by the host, never run (or run with other content)
    duplicated: int  # run more than once
    early: int  # acknowledged before the firmware had finished running it
    reordered: bool
    out_of_step: int  # lines with no fault of their own that the host had to send again
    bad_reports: int  # M114 answers that did not give the commanded position
    simulated_s: float
    fault_counts: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Nothing lost, repeated, reordered, acknowledged early or misreported. (`out_of_step`
        is reported, not judged: two faults in a row can cost one extra retransmission.)"""
        return not (
            self.lost or self.duplicated or self.early or self.reordered or self.bad_reports
        )

    def line(self) -> str:
        return (
            f"faults={self.faults} sent={self.sent} executed={self.executed} "
            f"lost={self.lost} duplicated={self.duplicated}"
        )

    def row(self) -> str:
        values = (
            self.kind,
            self.faults,
            self.sent,
            self.lost,
            self.duplicated,
            self.early,
            self.out_of_step,
            self.bad_reports,
        )
        return " ".join(
            f"{v:<{w}}" if i == 0 else f"{v:>{w}}"
            for i, (v, (_, w)) in enumerate(zip(values, COLUMNS, strict=True))
        )


def table_header() -> str:
    return " ".join(f"{n:<{w}}" if i == 0 else f"{n:>{w}}" for i, (n, w) in enumerate(COLUMNS))


def compare_logs(
    sent: list[tuple[int, str]], executed: list[tuple[int | None, str]]
) -> tuple[int, int, bool]:
    """(lost, duplicated, reordered) of the executed log against the lines the host sent."""
    counts = Counter(executed)
    lost = sum(1 for item in sent if counts[item] == 0)
    duplicated = sum(c - 1 for c in counts.values() if c > 1)
    seen, order = set(), []
    for item in executed:
        if item not in seen:
            seen.add(item)
            order.append(item)
    known = set(sent)
    reordered = [i for i in order if i in known] != [i for i in sent if counts[i]]
    return lost, duplicated, reordered


def acknowledged_early(
    acked_at: dict[int, float],
    executed: list[tuple[int | None, str]],
    done_at: list[float],
    tolerance_s: float = 1e-9,
) -> int:
    """Lines the host counted as done before the firmware had finished running them."""
    finished: dict[int, float] = {}
    for (number, _), when in zip(executed, done_at, strict=True):
        if number is not None:
            finished.setdefault(number, when)
    return sum(1 for n, t in acked_at.items() if n in finished and t < finished[n] - tolerance_s)


def check_soak_arguments(faults: int, rate: float, speedup: float) -> None:
    if not isinstance(faults, int) or faults < 1:
        raise ConfigError(f"--faults must be a whole number >= 1, got {faults}")
    if not 0.0 < rate <= 1.0:  # also refuses nan
        raise ConfigError(
            f"--rate must be a probability in (0, 1] (with 0 no fault is ever injected and "
            f"the soak never ends), got {rate}"
        )
    if not speedup > 0:  # also refuses nan
        raise ConfigError(
            f"--speedup must be > 0 simulated seconds per real second (or inf), got {speedup}"
        )


def recoverable(kinds) -> tuple[str, ...]:
    """The fault classes, checked: a soak injects only faults the host is meant to survive."""
    kinds = parse_faults(",".join(kinds))
    fatal = [k for k in kinds if k not in RECOVERABLE_FAULTS]
    if fatal or not kinds:
        raise ConfigError(
            f"the soak injects recoverable faults only ({', '.join(RECOVERABLE_FAULTS)}); "
            f"got {', '.join(fatal) or 'none'}"
        )
    return kinds


def _position_reported(host, printer_error) -> bool:
    """M114 gave the commanded position (to the firmware's 0.006 mm), not another or none."""
    try:
        position = host.position()
    except printer_error:
        return False  # "M114 gave no position line"
    return all(
        math.isclose(a, b, abs_tol=0.006) for a, b in zip(position, host.commanded, strict=True)
    )


def run_soak(
    faults: int,
    seed: int = 0,
    *,
    rate: float = 0.2,
    kinds: tuple[str, ...] = RECOVERABLE_FAULTS,
    speedup: float = 1e5,
    progress: bool = True,
    label: str | None = None,
) -> SoakResult:
    """Drive probe-like moves and position queries until `faults` faults have been injected."""
    check_soak_arguments(faults, rate, speedup)
    kinds = recoverable(kinds)
    name = f"soak-{seed}-{id(object())}"
    firmware = FIRMWARES.serve(
        name, SimMarlin("ender3", seed=seed, faults=kinds, rate=rate, speedup=speedup)
    )
    rng = random.Random(seed)
    bad_reports = 0
    try:
        with (
            MarlinHost(f"simmarlin://{name}", "ender3") as host,
            tqdm(
                total=faults,
                desc=f"soak {label or ','.join(kinds)}",
                unit="fault",
                disable=not progress,
                leave=False,
            ) as bar,
        ):
            travel = host.profile["travel_mm"]
            host.home()
            host.hold_motors()
            moves = 0
            while sum(firmware.faults_injected.values()) < faults:
                host.move_to(
                    round(rng.uniform(0, travel["x"]), 3),
                    round(rng.uniform(0, travel["y"]), 3),
                    round(rng.uniform(0, 10.0), 3),
                    rng.choice((5.0, 20.0, 100.0)),
                )
                moves += 1
                if moves % 10 == 0:
                    host.wait_until_idle()
                bad_reports += not _position_reported(host, PrinterError)
                bar.update(sum(firmware.faults_injected.values()) - bar.n)
            host.wait_until_idle()
            sent = [(n, c) for n, c in sorted(host._history.items()) if n >= 1]
            acked_at = {n: t for n, t in host.ack_times.items() if n >= 1}
            sends = host.transmissions
    finally:
        FIRMWARES.withdraw(name)
    executed = [(n, c) for n, c in firmware.executed if n is not None and n >= 1]
    lost, duplicated, reordered = compare_logs(sent, executed)
    faulted = {n for n, _ in firmware.fault_log}
    return SoakResult(
        kind=label or (kinds[0] if len(kinds) == 1 else "mixed"),
        faults=sum(firmware.faults_injected.values()),
        sent=len(sent),
        executed=len(executed),
        lost=lost,
        duplicated=duplicated,
        early=acknowledged_early(acked_at, firmware.executed, firmware.done_at),
        reordered=reordered,
        out_of_step=sum(
            1 for n, count in sends.items() if n >= 1 and count > 1 and n not in faulted
        ),
        bad_reports=bad_reports,
        simulated_s=firmware.clock.now(),
        fault_counts=dict(sorted(firmware.faults_injected.items())),
    )


def soak_table(
    faults: int,
    seed: int = 0,
    *,
    rate: float = 0.2,
    kinds: tuple[str, ...] = RECOVERABLE_FAULTS,
    speedup: float = 1e5,
    mixed: bool = True,
    progress: bool = True,
) -> list[SoakResult]:
    """One soak per fault class (each with `faults` faults of it), then all of them `mixed`."""
    check_soak_arguments(faults, rate, speedup)
    kinds = recoverable(kinds)
    results = [
        run_soak(faults, seed, rate=rate, kinds=(kind,), speedup=speedup, progress=progress)
        for kind in kinds
    ]
    if mixed and len(kinds) > 1:
        results.append(
            run_soak(
                faults * len(kinds),
                seed,
                rate=rate,
                kinds=kinds,
                speedup=speedup,
                progress=progress,
                label="mixed",
            )
        )
    return results
