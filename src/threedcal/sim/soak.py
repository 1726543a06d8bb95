"""Soak test of the host against the fake firmware: many injected faults, nothing lost or repeated.

The firmware's executed-command log is the ground truth: every numbered line the host had
acknowledged must appear in it exactly once, in order. (The M110 line-number reset of the
handshake is excluded: it is exempt from Marlin's line check and harmless to repeat.)
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass

from threedcal.sim.marlin import RECOVERABLE_FAULTS, SimMarlin, forget, register


@dataclass(frozen=True)
class SoakResult:
    faults: int
    sent: int
    executed: int
    lost: int
    duplicated: int
    reordered: bool
    simulated_s: float
    fault_counts: dict[str, int]

    @property
    def ok(self) -> bool:
        return self.lost == 0 and self.duplicated == 0 and not self.reordered

    def line(self) -> str:
        return (
            f"faults={self.faults} sent={self.sent} executed={self.executed} "
            f"lost={self.lost} duplicated={self.duplicated}"
        )


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
    reordered = [i for i in order if i in set(sent)] != [i for i in sent if counts[i]]
    return lost, duplicated, reordered


def run_soak(
    faults: int,
    seed: int = 0,
    *,
    rate: float = 0.2,
    kinds: tuple[str, ...] = RECOVERABLE_FAULTS,
    speedup: float = 1e5,
    progress: bool = True,
) -> SoakResult:
    """Drive random probe-like moves until `faults` faults have been injected, then compare logs."""
    from tqdm import tqdm

    from threedcal.hardware.printer import MarlinHost

    name = f"soak-{seed}-{id(object())}"
    firmware = register(
        name, SimMarlin("ender3", seed=seed, faults=kinds, rate=rate, speedup=speedup)
    )
    rng = random.Random(seed)
    try:
        with (
            MarlinHost(f"simmarlin://{name}", "ender3") as host,
            tqdm(total=faults, desc="soak", unit="fault", disable=not progress) as bar,
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
                if moves % 25 == 0:
                    host.wait_until_idle()
                    host.position()
                bar.update(sum(firmware.faults_injected.values()) - bar.n)
            host.wait_until_idle()
            sent = [(n, c) for n, c in sorted(host._history.items()) if n >= 1]
    finally:
        forget(name)
    executed = [(n, c) for n, c in firmware.executed if n is not None and n >= 1]
    lost, duplicated, reordered = compare_logs(sent, executed)
    return SoakResult(
        faults=sum(firmware.faults_injected.values()),
        sent=len(sent),
        executed=len(executed),
        lost=lost,
        duplicated=duplicated,
        reordered=reordered,
        simulated_s=firmware.clock.now(),
        fault_counts=dict(sorted(firmware.faults_injected.items())),
    )
