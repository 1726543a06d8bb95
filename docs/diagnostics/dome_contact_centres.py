"""Where a ball's contact on the DIGIT's domed gel lies, and what each contact locator finds there.

On a domed gel a ball touches first where the gap between them is smallest, toward the dome's
apex, so the contact is not centred on the ball's axis (what the printer knows). This renders
presses of a 2 mm ball at 25 places over the DIGIT's frame (no lens, so pixel = ideal pixel) at
three depths and prints, per depth, in px:

- how far the contact's centre (the elastic solution's pressure centroid; with `geometric`, the
  axis, where that gel centres its contact) lies from the axis, and from the paraboloid's first-touch
  point x0 / (1 + 2 k R) per axis;
- the rigid interference region's centroid (area-weighted, and sqrt(interference)-weighted, as
  Hertz's pressure is) against the pressure centroid: can geometry alone predict the centre?;
- the rim and the symmetry locator (started at the pressure centroid) against the pressure
  centroid, and what is left once a linear field over the frame is taken out (what an affine
  absorbs).

Usage (about a minute on 2 cores): `.venv/bin/python docs/diagnostics/dome_contact_centres.py
[elastic|geometric]`. Findings: docs/explanation/simulator.md, Gel mechanics, Measured.
"""

from __future__ import annotations

import sys

import numpy as np

from threedcal.dataset.contacts import Contact, locate_contact
from threedcal.dataset.symmetry import refine_by_symmetry
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

RADIUS_MM = 2.0
PLACES = [(x, y) for x in (50, 90, 120, 150, 190) for y in (60, 110, 160, 210, 260)]


def rms(dx, dy) -> float:
    return float(np.sqrt(np.nanmean(np.square(dx) + np.square(dy))))


def centres(sim: GelSimulator, ball: Sphere, place, depth: float, dome) -> dict:
    """Pixel positions of the axis, the first-touch point, the pressure centroid, the rigid
    interference's centroids."""
    s = sim.px_per_mm
    ax, ay = sim.axis_mm(place)

    def pixel(x_mm, y_mm):
        return np.array([x_mm * s + sim._cx, y_mm * s + sim._cy])

    out = {"axis": np.asarray(place, dtype=float)}
    touch = [
        (a + 2 * dome[k] * RADIUS_MM * dome[apex]) / (1 + 2 * dome[k] * RADIUS_MM)
        for a, k, apex in ((ax, "kx_per_mm", "apex_x_mm"), (ay, "ky_per_mm", "apex_y_mm"))
    ]
    out["first touch"] = pixel(*touch)
    if sim.mechanics == "elastic":
        press = sim.press(ball, place, 0.0, depth)
        X, Y = press.node_coords(press.node_box())
        p = press.pressure
        out["pressure"] = pixel((X * p).sum() / p.sum(), (Y * p).sum() / p.sum())
    else:
        out["pressure"] = out["axis"]
    g = np.linspace(-RADIUS_MM, RADIUS_MM, 401)
    GX, GY = np.meshgrid(ax + g, ay + g)
    w = np.asarray(sim.interference(ball, place, 0.0, depth)(GX, GY), dtype=float)
    w = np.where(np.isfinite(w), w, -1.0)
    inside = w > 0
    out["rigid area"] = pixel(GX[inside].mean(), GY[inside].mean())
    root = np.sqrt(np.clip(w, 0.0, None))
    out["rigid sqrt(w)"] = pixel((GX * root).sum() / root.sum(), (GY * root).sum() / root.sum())
    return out


def linear_residual(places: np.ndarray, error: np.ndarray, shape) -> float:
    """RMS of `error` (n, 2) left after a least-squares linear field over the frame."""
    ok = np.isfinite(error).all(axis=1)
    height, width = shape
    A = np.column_stack([np.ones(ok.sum()), places[ok, 0] - width / 2, places[ok, 1] - height / 2])
    left = []
    for c in range(2):
        coef, *_ = np.linalg.lstsq(A, error[ok, c], rcond=None)
        left.append(error[ok, c] - A @ coef)
    return rms(*left)


def main() -> None:
    mechanics = sys.argv[1] if len(sys.argv) > 1 else "elastic"
    profile = dict(load_profile("sensor", "digit"))
    profile["lens"] = None
    profile["gel"] = dict(profile["gel"], mechanics=mechanics)
    dome = profile["gel"]["dome"]
    sim = GelSimulator(profile, seed=3)
    ball = Sphere(RADIUS_MM)
    blank = sim.blank(frame_index=0).astype(np.float32)
    places = np.array(PLACES, dtype=float)
    print(f"DIGIT, {mechanics} gel, ball R {RADIUS_MM} mm, {len(PLACES)} places, no lens (px)")
    for depth in (0.3, 0.5, 0.8):
        found = [centres(sim, ball, p, depth, dome) for p in PLACES]
        frames = [
            sim.render(ball, p, 0.0, depth, frame_index=100 + i) for i, p in enumerate(PLACES)
        ]
        centre = np.array([f["pressure"] for f in found])
        shift = centre - places
        line = [f"depth {depth:g} mm: contact centre from the axis up to {np.abs(shift).max():.2f}"]
        for name in ("first touch", "rigid area", "rigid sqrt(w)"):
            d = np.array([f[name] for f in found]) - centre
            line.append(f"{name} {rms(d[:, 0], d[:, 1]):.2f}")
        print("; ".join(line) + " (RMS from the contact centre)")
        rim = [locate_contact(frame, blank) for frame in frames]
        starts = [
            None if c is None else Contact(float(t[0]), float(t[1]), c.radius_px, c.strength)
            for c, t in zip(rim, centre, strict=True)
        ]
        symmetric = refine_by_symmetry(frames, blank, starts).contacts
        for name, located in (("rim", rim), ("symmetry", symmetric)):
            xy = np.array([(np.nan, np.nan) if c is None else (c.x_px, c.y_px) for c in located])
            error = xy - centre
            print(
                f"  {name}: {rms(error[:, 0], error[:, 1]):.2f} RMS from the contact centre, "
                f"{linear_residual(places, error, blank.shape[:2]):.2f} after a linear field"
            )


if __name__ == "__main__":
    main()
