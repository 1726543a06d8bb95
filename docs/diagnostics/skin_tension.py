"""How a skin tension for the Mini (gel.skin_tension_n_per_mm) is chosen: on the fitting half only.

Usage: python docs/diagnostics/skin_tension.py [REAL_FOLDER] [SENSOR] [--split-seed S] [--tensions T ...]
       python docs/diagnostics/skin_tension.py --speed [--tensions T ...]
Splits the real ball frames by press exactly as `threedcal sim realism` does (split_seed 0), renders
the sensor's elastic gel at each tension under the *fitting* half's contacts and prints the median
halo figures (threedcal.sim.realism.halo_radii) beside the real fitting half's. The held-out half
is never read: the realism table reports on it afterwards, out of sample. `--speed`: frames/s of
the sensor's elastic gel at each tension, a new 2 mm ball press every frame, at the profile's size.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from threedcal.profiles import load_profile, with_gel_mechanics
from threedcal.sim.fit import split_halves
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator
from threedcal.sim.realism import (
    elastic_contact_radii,
    halo_radii,
    load_ball_dataset,
    simulated_depth_mm,
)


def halo(data, profile, labels, seed: int = 0) -> tuple[float, float]:
    """Median (r50, r10 - r50) px of `profile`'s elastic renders of `labels`' contacts."""
    sim = GelSimulator(
        profile, seed, image_size=(data.width_px, data.height_px), px_per_mm=data.px_per_mm
    )
    blank = sim.blank(frame_index=0)
    table = elastic_contact_radii(sim, data.ball_radius_mm, labels[0].center_px)
    ball, ball_px = Sphere(data.ball_radius_mm), data.ball_radius_mm * data.px_per_mm
    out = []
    for i, label in enumerate(labels):
        depth = simulated_depth_mm(label, data, table)
        frame = sim.render(ball, label.center_px, 0.0, depth, frame_index=i + 1)
        out.append(halo_radii(frame, blank, label.center_px, ball_px))
    r50, r10 = np.array(out).T
    return float(np.nanmedian(r50)), float(np.nanmedian(r10 - r50))


def speed(profile, frames: int = 40) -> float:
    sim = GelSimulator(profile, 0)
    sim.blank(frame_index=0)
    rng, ball = np.random.default_rng(0), Sphere(2.0)
    w, h = sim.frame_width, sim.frame_height
    sim.render(ball, (w / 2, h / 2), 0.0, 1.0, frame_index=0)  # kernel tables and spectra
    start = time.perf_counter()
    for k in range(frames):
        centre = (w * rng.uniform(0.3, 0.7), h * rng.uniform(0.3, 0.7))
        sim.render(ball, centre, 0.0, rng.uniform(0.3, 1.5), frame_index=k + 1)
    return frames / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("real", nargs="?", default="data/gelsight_ball_fots")
    ap.add_argument("sensor", nargs="?", default="gelsight_mini")
    ap.add_argument("--split-seed", type=int, default=0)
    ap.add_argument("--tensions", type=float, nargs="+", default=[0, 0.5, 1, 1.5, 2, 2.5, 3, 4])
    ap.add_argument("--speed", action="store_true")
    args = ap.parse_args()
    base = with_gel_mechanics(load_profile("sensor", args.sensor), "elastic")
    if args.speed:
        for t in args.tensions:
            profile = copy.deepcopy(base)
            profile["gel"]["skin_tension_n_per_mm"] = float(t)
            print(f"skin tension {t:.2f} N/mm: {speed(profile):.0f} frames/s", flush=True)
        return
    data = load_ball_dataset(args.real)
    fit_half, _ = split_halves(data.labels, args.split_seed, where=str(data.root))
    bg = data.read("background.png")
    ball_px = data.ball_radius_mm * data.px_per_mm
    real = np.array([halo_radii(data.read(lb.image), bg, lb.center_px, ball_px) for lb in fit_half])
    print(
        f"real fitting half ({len(fit_half)} images): r50 {np.nanmedian(real[:, 0]):.1f} px, "
        f"width {np.nanmedian(real[:, 1] - real[:, 0]):.1f} px"
    )
    print("skin tension N/mm   r50 px   width px")
    for t in args.tensions:
        profile = copy.deepcopy(base)
        profile["gel"]["skin_tension_n_per_mm"] = float(t)
        r50, width = halo(data, profile, fit_half)
        print(f"{t:17.2f} {r50:8.1f} {width:10.1f}", flush=True)


if __name__ == "__main__":
    main()
