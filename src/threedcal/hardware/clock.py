"""How a run keeps time: the clock it reads and sleeps on. A real rig's is the wall clock; the
simulated bench's advances the firmware's virtual one (threedcal.rig.BenchClock)."""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """A real rig's time: monotonic seconds, real waits."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)
