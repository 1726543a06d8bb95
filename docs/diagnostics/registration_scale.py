"""Registration of a paper-sized plan, end to end: how long `register` takes and how right it is.

    .venv/bin/python docs/diagnostics/registration_scale.py [sensor ...] [--points N] [--elastic]

For each sensor (default: digit and gelsight_mini) the gel simulator renders one frame per point
of an N-point lattice (default 1,221, the paper's DIGIT plan) over the area where a contact lies
whole in the image, the depth cycling over 1.0, 2.0 and 3.0 mm as in the default plans, against
a 10-frame blank. The printer coordinates map to pixels by a known affine (a 1.5 degree rotation,
the sensor's scale). `register` then runs as the dataset stage calls it (rim on every frame; on a
flat gel the symmetric centres too; the affine) and is timed; its affine is scored against the
known one over the lattice (the stage's `error_px`). One frame per point where the stage uses the
mean of `probing.frames_per_point`: slightly noisier contacts, the same work. On a domed gel the
located centres are moved to the press axes as the stage moves them (DomedContacts); `--elastic`
renders the elastic gel, whose symmetric centres are moved by the elastic pressure's centroid
(its per-depth pressure field is part of the timed `register`).
"""

import argparse
import math
import os
import time

import numpy as np

from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.dataset.registration import register_camera
from threedcal.profiles import load_profile, with_gel_mechanics
from threedcal.sim.elastic import GelMaterial
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

DEPTHS_MM = (1.0, 2.0, 3.0)
SPHERE_MM = 2.0


def lattice(sim: GelSimulator, points: int):
    """(xy_mm, centres_px) of `points` points where a contact lies whole."""
    margin = SPHERE_MM * sim.px_per_mm + 6  # the rim at d >= R, and `whole`'s 5 px
    width, height = sim.width - 1 - 2 * margin, sim.height - 1 - 2 * margin
    cols = max(round(math.sqrt(points * width / height)), 2)
    rows = max(math.ceil(points / cols), 2)
    t = math.radians(1.5)
    linear = sim.px_per_mm * np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    linear[:, 1] *= -1  # printer y points up in the image
    offset = np.array([(sim.width - 1) / 2, (sim.height - 1) / 2])
    # the lattice in pixels (shrunk by the rotation's reach), back to printer mm
    px = np.stack(
        np.meshgrid(
            np.linspace(-width / 2, width / 2, cols) * 0.97,
            np.linspace(-height / 2, height / 2, rows) * 0.97,
        ),
        axis=-1,
    ).reshape(-1, 2)
    px = px[np.linspace(0, len(px) - 1, points).round().astype(int)]  # exactly `points`, spread
    xy_mm = px @ np.linalg.inv(linear).T
    return xy_mm, xy_mm @ linear.T + offset


def run(sensor: str, points: int, elastic: bool = False) -> str:
    profile = with_gel_mechanics(load_profile("sensor", sensor), "elastic" if elastic else None)
    sim = GelSimulator(profile, seed=1)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    xy_mm, centres = lattice(sim, points)
    frames = [
        sim.render(Sphere(SPHERE_MM), tuple(c), 0, DEPTHS_MM[i % len(DEPTHS_MM)], frame_index=i)
        for i, c in enumerate(centres)
    ]

    def whole(contact) -> bool:  # as threedcal.dataset.build: the rim and a margin inside
        margin = contact.radius_px + 5
        return (
            margin <= contact.x_px <= sim.width - 1 - margin
            and margin <= contact.y_px <= sim.height - 1 - margin
        )

    flat = profile["gel"].get("dome") is None
    dome = None
    if not flat:
        depths = [DEPTHS_MM[i % len(DEPTHS_MM)] for i in range(len(frames))]
        material = GelMaterial.from_profile(profile["gel"]) if elastic else None
        dome = DomedContacts(
            profile["gel"]["dome"], SPHERE_MM, depths, sim.px_per_mm, blank.shape, material
        )
    wall, cpu = time.perf_counter(), time.process_time()
    result = register_camera(xy_mm, frames, blank, accept=whole, flat_gel=flat, dome=dome)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    error = np.linalg.norm(result.fit.apply(xy_mm) - centres, axis=1)
    return (
        f"{sensor}: {len(frames)} points, {'flat' if flat else 'domed'}"
        f"{' elastic' if elastic else ''} gel, locator "
        f"{result.locator}, {int(result.fit.inliers.sum())} contacts used; register "
        f"{wall:.1f} s wall, {cpu:.1f} CPU-s ({len(frames) / cpu:.0f} points per CPU-s); "
        f"error_px {np.sqrt(np.mean(error**2)):.3f} RMS, {error.max():.3f} max"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sensors", nargs="*", default=["digit", "gelsight_mini"])
    parser.add_argument("--points", type=int, default=1221)
    parser.add_argument("--elastic", action="store_true", help="render the elastic gel")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}")
    for sensor in args.sensors:
        print(run(sensor, args.points, args.elastic), flush=True)


if __name__ == "__main__":
    main()
