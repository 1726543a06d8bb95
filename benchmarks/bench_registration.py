"""Registration contacts/s: the symmetric-centre locator against the rim locator (its first step, the
baseline) on the same simulated GelSight Mini frames, timed in this run; and what the paper's DIGIT
plan (1,221 points) costs at these rates.

Frames: a 2 mm sphere 1 mm deep on a grid of known sub-pixel centres (each the mean of 3 renders,
against a 10-frame blank), as tests/dataset/test_registration.py builds them; the error of each locator
against those centres is printed beside its speed. At scale the unmixing is fitted on 40 contacts
in 2 rounds (80 extra fits) and every contact is fitted once; here the fits are timed with the
unmixing already fitted (rounds=0 after one calibration), so the figure is the per-contact cost.
CPU seconds of this process are printed too: the machine is shared.
"""

from __future__ import annotations

import os
import time

import numpy as np

from threedcal.dataset.registration import locate_contact, refine_by_symmetry
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

GRID = 5  # 25 contacts
PLAN_POINTS = 1221
CALIBRATION_FITS = 80


def contacts():
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=1)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    rng = np.random.default_rng(1)
    centres, frames = [], []
    for cx in np.linspace(50, sim.width - 51, GRID):
        for cy in np.linspace(50, sim.height - 51, GRID):
            centre = (cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5))
            shots = [sim.render(Sphere(2.0), centre, 0, 1.0, frame_index=k) for k in range(3)]
            mean = np.mean(np.asarray(shots, dtype=np.float32), axis=0)
            frames.append(np.clip(mean + 0.5, 0, 255).astype(np.uint8))
            centres.append(centre)
    return np.array(centres), frames, blank


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    result = fn()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def error(found, truth) -> str:
    xy = np.array([(c.x_px, c.y_px) if c is not None else (np.nan, np.nan) for c in found])
    e = np.linalg.norm(xy - truth, axis=1)
    return f"error max {np.nanmax(e):.3f} px, rms {np.sqrt(np.nanmean(e**2)):.3f} px"


def main() -> None:
    truth, frames, blank = contacts()
    n = len(frames)
    print(f"{n} GelSight Mini contacts (320x240); load average {os.getloadavg()[0]:.1f}")
    rim, rim_wall, rim_cpu = timed(lambda: [locate_contact(f, blank) for f in frames])
    print(
        f"rim (baseline)   {n / rim_wall:7.1f} contacts/s  ({n / rim_cpu:.1f} per CPU-s)  {error(rim, truth)}"
    )
    unmixing = refine_by_symmetry(frames, blank, rim).unmixing  # calibration, not timed
    from threedcal.dataset import registration

    fits, fit_wall, fit_cpu = timed(
        lambda: [
            registration._symmetry_fit(w, unmixing, c, 1.4) for w, c in windows(rim, frames, blank)
        ]
    )
    found = [
        None if fit is None else registration.Contact(fit[0], fit[1], c.radius_px, c.strength)
        for fit, c in zip(fits, rim, strict=True)
    ]
    print(
        f"symmetric centre {n / fit_wall:7.1f} contacts/s  ({n / fit_cpu:.1f} per CPU-s)  {error(found, truth)}"
    )
    print(f"symmetric / rim cost: {fit_cpu / rim_cpu:.1f}x")
    per_point = (rim_cpu + fit_cpu) / n
    plan = PLAN_POINTS * per_point + CALIBRATION_FITS * fit_cpu / n
    print(f"paper's DIGIT plan ({PLAN_POINTS} points): {plan:.0f} CPU-s projected (goal < 60 s)")


def windows(rim, frames, blank):
    from threedcal.dataset.registration import _Window

    return [
        (_Window.around(np.asarray(f), blank, 1.0, c, 1.4), c)
        for f, c in zip(frames, rim, strict=True)
    ]


if __name__ == "__main__":
    main()
