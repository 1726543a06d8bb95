"""How far the automatic contact locator is off, and how that depends on the image position.

    .venv/bin/python docs/diagnostics/registration_bias.py gelsight_mini

Renders a sphere (R 2 mm, 1 mm deep) on a 9 x 7 grid of known sub-pixel centres with the gel
simulator, locates each contact as the dataset stage does (mean of 3 frames against a 10-frame
blank), and fits the error (found - true, px) as a linear function of the position: a slope is
what the registration affine absorbs as a wrong scale. One line per optics variant.
"""

import copy
import sys

import numpy as np

from threedcal.dataset.registration import locate_contact
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

VARIANTS = ({}, {"shadow_strength": 0.0}, {"shadow_strength": 0.0, "nonlinearity": 0.0})


def run(profile, optics_change) -> str:
    profile = copy.deepcopy(profile)
    profile["optics"].update(optics_change)
    sim = GelSimulator(profile, seed=1)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    rng = np.random.default_rng(0)
    rows = []
    for cx in np.linspace(45, sim.width - 46, 9):
        for cy in np.linspace(45, sim.height - 46, 7):
            x, y = cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5)
            frames = [sim.render(Sphere(2.0), (x, y), 0, 1.0, frame_index=k) for k in range(3)]
            mean = np.mean(np.asarray(frames, dtype=np.float32), axis=0)
            found = locate_contact(np.clip(mean + 0.5, 0, 255).astype(np.uint8), blank)
            if found is not None:
                rows.append((x - sim.width / 2, y - sim.height / 2, found.x_px - x, found.y_px - y))
    r = np.asarray(rows)
    design = np.column_stack([r[:, 0], r[:, 1], np.ones(len(r))])
    fx, *_ = np.linalg.lstsq(design, r[:, 2], rcond=None)
    fy, *_ = np.linalg.lstsq(design, r[:, 3], rcond=None)
    rms = float(np.sqrt((r[:, 2:] ** 2).sum(axis=1).mean()))
    return (
        f"{str(optics_change or 'profile optics'):45s} n={len(r)} rms {rms:.3f} px  "
        f"x-error: {fx[2]:+.3f} px + {fx[0]:+.5f}/px  y-error: {fy[2]:+.3f} px + {fy[1]:+.5f}/px"
    )


if __name__ == "__main__":
    sensor = load_profile("sensor", sys.argv[1] if len(sys.argv) > 1 else "gelsight_mini")
    for change in VARIANTS:
        print(run(sensor, change), flush=True)
