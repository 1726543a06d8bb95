"""How well does threedcal.dataset.refine recover contacts? Simulated frames at the real set's scale.

    .venv/bin/python docs/diagnostics/refine_on_sim.py

Renders 30 presses of the 4.70 mm ball into the GelSight Mini simulator at data/gelsight_ball_fots'
size and scale (240 x 320 px, 19.58 px/mm), depths 0.7-1.9 mm, draws "hand labels" off by
N(0, 2.5 px) in centre and radius (plus a +2 px radius bias, as drawn circles that include the
halo), refines them, and prints the errors against the rendered truth. Then, on the real frames,
how much better presses at one place agree after refinement.
"""

import math

import numpy as np

from threedcal.dataset.importers import load_ball_folder
from threedcal.dataset.refine import refine_contacts
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

BALL_MM, PX_PER_MM = 2.35, 19.58


def simulated() -> None:
    sim = GelSimulator(
        load_profile("sensor", "gelsight_mini"), 0, image_size=(240, 320), px_per_mm=PX_PER_MM
    )
    rng = np.random.default_rng(1)
    centres = rng.uniform([80, 110], [160, 220], (30, 2))
    depths = rng.uniform(0.7, 1.9, 30)
    frames = np.stack(
        [
            sim.render(Sphere(BALL_MM), tuple(c), 0.0, float(d), frame_index=i + 1)
            for i, (c, d) in enumerate(zip(centres, depths, strict=True))
        ]
    )
    contact = np.sqrt(2 * BALL_MM * depths - depths**2) * PX_PER_MM
    drawn_c = centres + rng.normal(0, 2.5, centres.shape)
    drawn_r = contact + 2.0 + rng.normal(0, 2.5, contact.shape)
    found_c, found_r = refine_contacts(frames, sim.blank(0), drawn_c, drawn_r)
    level = drawn_r.mean() - contact.mean()
    print(f"simulated: true contact radius {contact.min():.1f}-{contact.max():.1f} px")
    for name, c, r in (("hand labels", drawn_c, drawn_r), ("refined", found_c, found_r)):
        centre = np.hypot(*(c - centres).T)
        print(
            f"  {name:12s} centre error mean {centre.mean():.2f} max {centre.max():.2f} px | "
            f"radius error sd {np.std(r - contact):.2f} px (common offset {np.mean(r - contact):+.2f})"
        )
    print(f"  (the refined radii inherit the labels' mean offset, {level:+.2f} px here)")


def real() -> None:
    data = load_ball_folder("data/gelsight_ball_fots")
    r_mm = data.sphere_radius_mm
    drawn = np.sqrt(2 * r_mm * data.depth_mm - data.depth_mm**2) * data.px_per_mm
    centres, refined = refine_contacts(data.frames, data.blank, data.center_px, drawn)
    pairs = [
        (i, j)
        for i in range(len(drawn))
        for j in range(i + 1, len(drawn))
        if math.dist(centres[i], centres[j]) < 5.0
    ]
    for name, r in (("hand-drawn", drawn), ("refined", refined)):
        rms = math.sqrt(np.mean([(r[i] - r[j]) ** 2 for i, j in pairs]))
        print(
            f"real: {len(pairs)} press pairs < 5 px apart, {name} radii differ by {rms:.2f} px RMS"
        )
    shift = np.hypot(*(centres - data.center_px).T)
    print(f"real: refined centres {np.median(shift):.1f} px (median) from the drawn ones")


if __name__ == "__main__":
    simulated()
    real()
