"""Frames/s of sphere renders at 240x320 (DIGIT profile), against a naive full-frame baseline.

The baseline shades every pixel of the frame and blurs the whole frame, as a direct implementation
would; the simulator re-shades only a window around the contact on a precomputed background.
Goal: >= 200 frames/s on 2 cores.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from threedcal.profiles import load_profile  # noqa: E402
from threedcal.sim.indenters import Sphere  # noqa: E402
from threedcal.sim.optics import GelSimulator  # noqa: E402

cv2.setNumThreads(2)


def rate(render, n: int) -> float:
    render(0)
    start = time.perf_counter()
    for i in range(n):
        render(i)
    return n / (time.perf_counter() - start)


def main() -> None:
    sim = GelSimulator(load_profile("sensor", "digit"), seed=0)
    ball = Sphere(2.0)
    rng = np.random.default_rng(0)
    poses = [(rng.uniform(40, 200), rng.uniform(40, 280), rng.uniform(0.3, 1.5)) for _ in range(64)]

    def windowed(i):
        x, y, d = poses[i % 64]
        return sim.render(ball, (x, y), 0.0, d, frame_index=i)

    def full_frame(i):  # the whole frame as the window: same physics, no window, no precomputation
        x, y, d = poses[i % 64]
        win = (0, sim.height, 0, sim.width)
        sim.window = lambda *a, **k: win  # noqa: B023
        try:
            return sim.render(ball, (x, y), 0.0, d, frame_index=i)
        finally:
            del sim.window

    fast = rate(windowed, 400)
    base = rate(full_frame, 40)
    print(f"sphere renders 240x320 (digit, R=2 mm, depth 0.3-1.5 mm): {fast:.0f} frames/s")
    print(f"full-frame baseline (same physics on every pixel):       {base:.0f} frames/s")
    print(
        f"ratio windowed / full-frame: {fast / base:.1f}x   goal >= 200 frames/s: {'met' if fast >= 200 else 'NOT met'}"
    )


if __name__ == "__main__":
    main()
