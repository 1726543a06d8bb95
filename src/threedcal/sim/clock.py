"""A virtual clock for simulated hardware: time passes only when someone waits on it.

Waiting ``dt`` simulated seconds sleeps ``dt / speedup`` real seconds (none at all when the speedup
is infinite) and then moves the clock forward by exactly ``dt``. The host's own computing takes no
simulated time, so runs are deterministic: same inputs, same timeline.
"""

from __future__ import annotations

import math
import time


class VirtualClock:
    def __init__(self, speedup: float = 1.0, start: float = 0.0):
        if not speedup > 0:
            raise ValueError(f"speedup must be > 0 (or inf), got {speedup}")
        self.speedup = float(speedup)
        self._now = float(start)
        self._debt = 0.0

    def now(self) -> float:
        """Simulated seconds since the clock started."""
        return self._now

    def advance_to(self, t: float) -> None:
        if t <= self._now:
            return
        if math.isfinite(self.speedup):
            # Owe tiny sleeps and pay them in one go: sleep() costs ~0.1 ms however short.
            self._debt += (t - self._now) / self.speedup
            if self._debt >= 1e-3:
                time.sleep(self._debt)
                self._debt = 0.0
        self._now = t

    def advance(self, dt: float) -> None:
        self.advance_to(self._now + dt)

    def sleep(self, seconds: float) -> None:
        """Wait on the clock (the collection loops' Clock protocol: now() and sleep())."""
        self.advance(seconds)
