"""Registration contacts/s: the symmetric-centre locator against the rim locator (its first step, the
baseline) and against the original symmetric-centre implementation, all timed in this run on the
same simulated frames; and what the paper's 1,221-point plan costs at these rates.

Frames: a 2 mm sphere 1 mm deep on a grid of known sub-pixel centres (each the mean of 3 renders,
against a 10-frame blank), as tests/dataset/test_registration.py builds them: 25 GelSight Mini
contacts (flat gel: rim, then symmetric centre) and 9 DIGIT contacts (its geometric domed gel:
`register` uses the rim only there, and moves each centre from its contact, which leans toward the
dome's apex, to the press's axis). The error of each locator against those centres is printed
beside its speed.

A symmetric-centre fit is timed per contact with its window (the crop, smoothing and cell table)
and the unmixing already fitted: at scale the unmixing is fitted on 40 contacts in 2 rounds (80
extra fits) and every contact is then fitted once, which is what the projection adds up. The
original implementation (scipy least_squares on finite differences over the whole frame, before
issue 25) is read from git history (`ORIGINAL`) and timed on a few contacts with the same
unmixing; without the history the recorded figure is printed instead. CPU seconds of this
process are the figures that count: the machine is shared.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from threedcal.dataset import symmetry
from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

PLAN_POINTS = 1221  # the paper's DIGIT plan
CALIBRATION_FITS = 80  # 2 rounds on 40 contacts (refine_by_symmetry's defaults)
REACH, SMOOTH_PX = 1.4, 1.0  # refine_by_symmetry's defaults
# The symmetric-centre locator before issue 25 (commit facac97, src/threedcal/dataset/registration.py),
# and what it measured then: 2.8-3.0 CPU-s per contact on the 9 contacts of the test.
ORIGINAL = ("facac97", "src/threedcal/dataset/registration.py")
ORIGINAL_RECORDED_CPU_S = (2.8, 3.0)
ORIGINAL_CONTACTS = 4


def contacts(sensor: str, grid: int, margin: int):
    sim = GelSimulator(load_profile("sensor", sensor), seed=1)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    rng = np.random.default_rng(1)
    centres, frames = [], []
    for cx in np.linspace(margin, sim.width - 1 - margin, grid):
        for cy in np.linspace(margin, sim.height - 1 - margin, grid):
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
    xy = np.array([(c[0], c[1]) if c is not None else (np.nan, np.nan) for c in found])
    e = np.linalg.norm(xy - truth, axis=1)
    return f"error max {np.nanmax(e):.3f} px, rms {np.sqrt(np.nanmean(e**2)):.3f} px"


def centres(found):
    return [None if c is None else (c.x_px, c.y_px) for c in found]


def original_module():
    """The original registration module from git history, or None where it is not at hand."""
    commit, path = ORIGINAL
    try:
        source = subprocess.run(
            ["git", "show", f"{commit}:{path}"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parent,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as file:
        file.write(source)
    spec = importlib.util.spec_from_file_location("registration_original", file.name)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    os.unlink(file.name)
    return module


def symmetric_fits(frames, blank, rim, unmixing):
    """Window + fit of every contact with a given unmixing (the per-contact cost at scale)."""
    return [
        symmetry._symmetry_fit(
            symmetry._Window.around(f, blank, SMOOTH_PX, c, REACH), unmixing, c, REACH
        )
        for f, c in zip(frames, rim, strict=True)
    ]


def original_fits(module, frames, blank, rim, unmixing):
    """The same with the original implementation (its window is the whole frame)."""
    fits = []
    for f, c in zip(frames, rim, strict=True):
        contact = module.Contact(c.x_px, c.y_px, c.radius_px, c.strength)
        window = module._Window.of(f, blank, SMOOTH_PX)
        fits.append(module._symmetry_fit(window, unmixing, contact, REACH))
    return fits


def main() -> None:
    truth, frames, blank = contacts("gelsight_mini", grid=5, margin=50)
    n = len(frames)
    print(f"{n} GelSight Mini contacts (320x240); load average {os.getloadavg()[0]:.1f}")
    rim, rim_wall, rim_cpu = timed(lambda: [locate_contact(f, blank) for f in frames])
    print(
        f"rim (baseline)     {n / rim_wall:7.1f} contacts/s  ({n / rim_cpu:5.1f} per CPU-s)  "
        f"{error(centres(rim), truth)}"
    )
    unmixing = symmetry.refine_by_symmetry(frames, blank, rim).unmixing  # not timed
    fits, fit_wall, fit_cpu = timed(lambda: symmetric_fits(frames, blank, rim, unmixing))
    print(
        f"symmetric centre   {n / fit_wall:7.1f} contacts/s  ({n / fit_cpu:5.1f} per CPU-s)  "
        f"{error(fits, truth)}"
    )
    print(f"symmetric / rim cost: {fit_cpu / rim_cpu:.1f}x")
    original = original_module()
    if original is None:
        low, high = ORIGINAL_RECORDED_CPU_S
        print(
            f"original symmetric centre: not in this checkout's history ({ORIGINAL[0]}); recorded "
            f"{low}-{high} CPU-s per contact: {low * n / fit_cpu:.0f}-{high * n / fit_cpu:.0f}x"
        )
    else:
        k = ORIGINAL_CONTACTS
        picked = np.linspace(0, n - 1, k).astype(int)
        slow, slow_wall, slow_cpu = timed(
            lambda: original_fits(
                original, [frames[i] for i in picked], blank, [rim[i] for i in picked], unmixing
            )
        )
        print(
            f"original symmetric {k / slow_wall:7.2f} contacts/s  ({k / slow_cpu:5.2f} per CPU-s)  "
            f"{error(slow, truth[picked])} ({k} contacts, {ORIGINAL[0]})"
        )
        print(f"symmetric centre speed-up over the original: {(slow_cpu / k) / (fit_cpu / n):.0f}x")
    per_point = (rim_cpu + fit_cpu) / n
    flat = PLAN_POINTS * per_point + CALIBRATION_FITS * fit_cpu / n
    print(
        f"{PLAN_POINTS} points on a flat gel (rim + symmetric centre): {flat:.0f} CPU-s projected "
        "(goal < 60 s)"
    )

    d_truth, d_frames, d_blank = contacts("digit", grid=3, margin=60)
    m = len(d_frames)
    digit = load_profile("sensor", "digit")
    d_rim, d_wall, d_cpu = timed(lambda: [locate_contact(f, d_blank) for f in d_frames])
    # the contacts lean toward the dome's apex: the stage moves each to its press's axis
    dome = DomedContacts(
        digit["gel"]["dome"], 2.0, np.full(m, 1.0), digit["px_per_mm"], d_blank.shape
    )
    d_axes, axes_wall, axes_cpu = timed(lambda: dome.to_axis(d_rim))
    print(
        f"{m} DIGIT contacts (240x320), rim: {m / d_wall:.1f} contacts/s ({m / d_cpu:.1f} per "
        f"CPU-s), {error(centres(d_rim), d_truth)}; moved to the axes: "
        f"{m / (d_cpu + axes_cpu):.1f} per CPU-s, {error(centres(d_axes), d_truth)}"
    )
    print(
        f"paper's DIGIT plan ({PLAN_POINTS} points, a domed gel that follows the ball: rim only): "
        f"{PLAN_POINTS * (d_cpu + axes_cpu) / m:.0f} CPU-s projected (goal < 60 s)"
    )


if __name__ == "__main__":
    main()
