"""Probing time of the paper's DIGIT plan on an Ender 3: our synchronised loop against the authors'
open-loop sleeps, both computed in this run.

The plan is py3DCal's default DIGIT plan shape: a 0.5 mm grid over 16 x 18 mm (33 x 37 = 1,221
points), 2 mm deep at the apex with dome compensation, 30 frames per point. Ours is driven through
the real host code against the fake firmware's motion model (homing, trapezoidal moves with the
Ender 3's feed and acceleration limits, M400 waits, settling, capture at the camera's frame rate).
The authors' time is their `Calibrator` sleeps: 1 s + travel at an assumed 10 mm/s XY and 4 mm/s Z
after every move, 0.1 s per frame and 0.5 s after each point.
"""

import time

import numpy as np

from threedcal.collect.plan import grid_plan, plan_to_printer
from threedcal.profiles import load_profile
from threedcal.study.session import estimate_hardware_s


def authors_open_loop_s(plan, sensor) -> float:
    mount = sensor["mount"]
    clearance = mount["z_touch_mm"] + mount["z_clearance_mm"]
    total = (
        1 + clearance / 4 + 1 + max(mount["x_offset_mm"], mount["y_offset_mm"]) / 10
    )  # initial moves
    previous = (mount["x_offset_mm"], mount["y_offset_mm"], clearance)
    for row in plan.itertuples():
        x, y, z = plan_to_printer(sensor, row.x_mm, row.y_mm, row.depth_mm)
        travel = (
            abs(clearance - previous[2]) / 4 + max(abs(x - previous[0]), abs(y - previous[1])) / 10
        )
        travel += abs(z - clearance) / 4
        total += travel + 1 + row.frames * 0.1 + 0.5
        previous = (x, y, z)
    return total


def main() -> None:
    sensor = load_profile("sensor", "digit")
    printer = load_profile("printer", "ender3")
    plan = grid_plan(sensor, spacing_mm=0.5, depths_mm=2.0, frames=30)
    start = time.perf_counter()
    ours = estimate_hardware_s(sensor, printer, plan)
    seconds = time.perf_counter() - start
    theirs = authors_open_loop_s(plan, sensor)
    n = len(plan)
    print(f"plan: {n} points x 30 frames (py3DCal's default DIGIT plan shape)")
    print(
        f"authors' open loop (their sleeps):   {theirs:8.0f} s = {theirs / 3600:.2f} h  ({theirs / n:.2f} s/point)"
    )
    print(
        f"threedcal synchronised (motion model): {ours:6.0f} s = {ours / 3600:.2f} h  ({ours / n:.2f} s/point)"
    )
    print(
        f"ratio authors / ours: {theirs / ours:.2f}x   goal: ours <= 1 h -> {'met' if ours <= 3600 else 'missed'}"
    )
    print(
        f"(the estimate itself ran the host loop against the fake firmware in {seconds:.1f} s of wall time)"
    )
    assert np.isfinite(ours)


if __name__ == "__main__":
    main()
