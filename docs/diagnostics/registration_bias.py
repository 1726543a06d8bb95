"""How far each contact locator is off, and how that depends on the image position.

    .venv/bin/python docs/diagnostics/registration_bias.py gelsight_mini

Renders a sphere (R 2 mm, 1 mm deep) on a 9 x 7 grid of known sub-pixel centres with the gel
simulator, locates each contact as the dataset stage does (mean of 3 frames against a 10-frame
blank) by its rim and by mirror symmetry, and fits the error (found - true, px) as a linear
function of the position: a slope is what the registration affine absorbs as a wrong scale.
One line per locator and optics variant.
"""

import copy
import sys

import numpy as np

from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.symmetry import refine_by_symmetry
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

VARIANTS = ({}, {"shadow_strength": 0.0}, {"shadow_strength": 0.0, "nonlinearity": 0.0})


def describe(name: str, truth: np.ndarray, contacts, shape) -> str:
    rows = np.array(
        [
            (x - shape[1] / 2, y - shape[0] / 2, c.x_px - x, c.y_px - y)
            for (x, y), c in zip(truth, contacts, strict=True)
            if c is not None
        ]
    )
    design = np.column_stack([rows[:, 0], rows[:, 1], np.ones(len(rows))])
    fx, *_ = np.linalg.lstsq(design, rows[:, 2], rcond=None)
    fy, *_ = np.linalg.lstsq(design, rows[:, 3], rcond=None)
    rms = float(np.sqrt((rows[:, 2:] ** 2).sum(axis=1).mean()))
    return (
        f"  {name:9s} n={len(rows)} rms {rms:.3f} px  "
        f"x-error: {fx[2]:+.3f} px {fx[0]:+.5f}/px  y-error: {fy[2]:+.3f} px {fy[1]:+.5f}/px"
    )


def run(profile, optics_change) -> str:
    profile = copy.deepcopy(profile)
    profile["optics"].update(optics_change)
    sim = GelSimulator(profile, seed=1)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    rng = np.random.default_rng(0)
    truth, frames = [], []
    for cx in np.linspace(45, sim.width - 46, 9):
        for cy in np.linspace(45, sim.height - 46, 7):
            x, y = cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5)
            shots = [sim.render(Sphere(2.0), (x, y), 0, 1.0, frame_index=k) for k in range(3)]
            mean = np.mean(np.asarray(shots, dtype=np.float32), axis=0)
            frames.append(np.clip(mean + 0.5, 0, 255).astype(np.uint8))
            truth.append((x, y))
    rim = [locate_contact(f, blank) for f in frames]
    symmetric = refine_by_symmetry(frames, blank, rim).contacts
    shape = (sim.height, sim.width)
    return "\n".join(
        [
            str(optics_change or "profile optics"),
            describe("rim", np.array(truth), rim, shape),
            describe("symmetry", np.array(truth), symmetric, shape),
        ]
    )


if __name__ == "__main__":
    sensor = load_profile("sensor", sys.argv[1] if len(sys.argv) > 1 else "gelsight_mini")
    for change in VARIANTS:
        print(run(sensor, change), flush=True)
