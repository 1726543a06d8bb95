"""Frames/s of renders at 240x320 (the `digit` profile, and the default study's two sensors): the
geometric gel against a naive full-frame baseline, and the elastic gel (gel.mechanics: elastic)
against the geometric one, all in this run.

- The geometric baseline shades every pixel of the frame and blurs the whole frame, as a direct
  implementation would; the simulator re-shades only a window around the contact on a precomputed
  background. Goal: >= 200 frames/s.
- The elastic gel solves a contact per frame (every frame a new pose and depth: nothing reused) and
  shades its far field, which reaches most of the frame. Goal: >= 50 frames/s for the ball.
- A test object (the pawn, vertical walls) pressed at varied poses, both gels.
- The camera's lens (profile `lens`: threedcal.sim.camera.LensedGel) on top of each gel, against the
  same gel without it. Goal with the elastic gel and the lens: >= 50 frames/s.
- The profiles the default study renders, with the elastic gel and each profile's own lens: the
  DIGIT fitted to real frames (`digit_fots`) and the GelSight Mini with its painted skin, against
  the `digit` profile's elastic gel and lens of this run. Goal: >= 50 frames/s each.

Wall-clock frames/s on this machine, and frames per CPU-second of this process (the machine is
shared: under load the wall clock counts other people's work too).
"""

from __future__ import annotations

import copy
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from threedcal.evaluate.object_presses import relief_indenter  # noqa: E402
from threedcal.evaluate.objects import load_object  # noqa: E402
from threedcal.profiles import load_profile, with_gel_mechanics  # noqa: E402
from threedcal.sim.camera import LensedGel, make_gel  # noqa: E402
from threedcal.sim.indenters import Sphere  # noqa: E402
from threedcal.sim.optics import GelSimulator  # noqa: E402

cv2.setNumThreads(2)


def rate(render, n: int) -> tuple[float, float]:
    """(wall frames/s, frames per CPU second) of n calls render(0..n-1), after one warm-up call."""
    render(0)
    wall, cpu = time.perf_counter(), time.process_time()
    for i in range(n):
        render(i)
    return n / (time.perf_counter() - wall), n / (time.process_time() - cpu)


def show(label: str, fps: tuple[float, float]) -> None:
    print(f"{label:48s} {fps[0]:6.0f} frames/s  ({fps[1]:.0f} per CPU-s)")


def main() -> None:
    digit = load_profile("sensor", "digit")
    elastic_profile = copy.deepcopy(digit)
    elastic_profile["gel"]["mechanics"] = "elastic"
    sim = GelSimulator(digit, seed=0)
    gel = GelSimulator(elastic_profile, seed=0)
    ball = Sphere(2.0)
    rng = np.random.default_rng(0)
    poses = [
        (rng.uniform(40, 200), rng.uniform(40, 280), rng.uniform(0.3, 1.5)) for _ in range(401)
    ]
    fast, soft = sphere_renders(sim, gel, ball, poses)
    soft_lens = lensed_renders(digit, elastic_profile, ball, poses, fast, soft)
    study_renders(ball, poses, soft_lens)
    pawn_renders(sim, gel, rng)
    print(
        f"load average (1 min) during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )


def through(simulator, ball, poses):
    """A render of a new pose and depth every frame."""

    def render(i):
        x, y, d = poses[i]
        return simulator.render(ball, (x, y), 0.0, d, frame_index=i)

    return render


def sphere_renders(sim, gel, ball, poses):
    """The geometric gel windowed against the whole frame, and the elastic gel."""

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
    soft = rate(through(gel, ball, poses), 400)
    print("sphere renders 240x320 (digit, R = 2 mm, depth 0.3-1.5 mm):")
    show("  geometric gel, windowed", fast)
    show("  geometric gel, full-frame baseline", base)
    show("  elastic gel, a new pose every frame", soft)
    print(
        f"  ratio windowed / full-frame: {fast[0] / base[0]:.1f}x   "
        f"goal >= 200 frames/s: {'met' if fast[0] >= 200 else 'NOT met'}"
    )
    print(
        f"  ratio elastic / geometric: {soft[0] / fast[0]:.2f}x   "
        f"goal elastic >= 50 frames/s: {'met' if soft[0] >= 50 else 'NOT met'}"
        f" (per CPU-s: {'met' if soft[1] >= 50 else 'NOT met'})"
    )
    return fast, soft


def lensed_renders(digit, elastic_profile, ball, poses, fast, soft):
    """The same spheres through the DIGIT's lens; the elastic gel's rate."""
    lensed = LensedGel(digit, seed=0)
    lensed_elastic = LensedGel(elastic_profile, seed=0)
    geo_lens = rate(through(lensed, ball, poses), 400)
    soft_lens = rate(through(lensed_elastic, ball, poses), 400)
    print("the same sphere renders through the DIGIT's lens (distortion and vignetting):")
    show("  geometric gel + lens", geo_lens)
    show("  elastic gel + lens", soft_lens)
    print(
        f"  ratio with / without the lens: geometric {geo_lens[0] / fast[0]:.2f}x, "
        f"elastic {soft_lens[0] / soft[0]:.2f}x   goal elastic + lens >= 50 frames/s: "
        f"{'met' if soft_lens[0] >= 50 else 'NOT met'}"
    )
    return soft_lens


def study_renders(ball, poses, soft_lens) -> None:
    """The default study's sensors, elastic gel + lens, as its benches render them."""
    print("the default study's sensors, elastic gel + lens, a new pose every frame:")
    for name in ("digit_fots", "gelsight_mini"):
        # as the study's benches render it (bench.gel_mechanics: elastic)
        profile = with_gel_mechanics(load_profile("sensor", name), "elastic")
        simulator = make_gel(profile, seed=0)
        height, width = profile["image"]["height_px"], profile["image"]["width_px"]
        # the same poses, scaled to this frame (the Mini's is landscape)
        scaled = [(x * width / 240, y * height / 320, d) for x, y, d in poses]
        study = rate(through(simulator, ball, scaled), 400)
        show(f"  {name} ({width}x{height})", study)
        print(
            f"  ratio {name} / digit elastic + lens: {study[0] / soft_lens[0]:.2f}x   "
            f"goal >= 50 frames/s: {'met' if study[0] >= 50 else 'NOT met'}"
        )


def pawn_renders(sim, gel, rng) -> None:
    """A pawn pressed at 12 poses into the geometric and the elastic gel."""
    pawn = load_object("pawn")
    presses = [
        (rng.uniform(80, 160), rng.uniform(100, 220), rng.uniform(-10, 10), rng.uniform(0.8, 1.2))
        for _ in range(12)
    ]
    indenters = [relief_indenter(pawn, sim.px_per_mm, rot) for _, _, rot, _ in presses]

    def pawn_with(simulator):
        def render(i):
            x, y, _, d = presses[i % len(presses)]
            return simulator.render(indenters[i % len(presses)], (x, y), 0.0, d, frame_index=i)

        return render

    geo_pawn = rate(pawn_with(sim), 12)
    soft_pawn = rate(pawn_with(gel), 12)
    print("pawn pressed 0.8-1.2 mm deep, turned up to 10 degrees, 240x320 (digit):")
    show("  geometric gel", geo_pawn)
    show("  elastic gel", soft_pawn)
    print(f"  ratio elastic / geometric: {soft_pawn[0] / geo_pawn[0]:.2f}x")


if __name__ == "__main__":
    main()
