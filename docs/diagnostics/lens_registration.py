"""How well registration finds the bench's lens, and what each part of the lens model buys.

For each sensor and seed: the paper's 0.5 mm grid collected on the simulated bench (depths cycling
1, 1, 2, 1, 1, 3 mm as the default scenes do), the contacts located as the dataset stage locates
them, then the error against the bench's hidden truth (where the camera truly images each probe
point, RMS and max over every probe point whose centre is in view) of:

- `affine`: the affine alone (the lens left in the labels);
- `k1`, `k1+k2`, each with the principal point free or held at the frame's centre, fitted to the
  contacts the dataset stage located (on frames rectified through its first fit);
- the stage's first pass (κ₁ on the contacts as first located), and the stage itself
  (threedcal.dataset.registration.register_camera: relocated, κ₁ and κ₂, outliers rejected).

Seeds other than the default study's 0: the figures the study reports are not the ones this
chose on. Usage (about a minute per sensor and seed on 2 cores):

    .venv/bin/python docs/diagnostics/lens_registration.py [seed ...]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy import optimize

from threedcal.collect.session import collect_scene
from threedcal.config import validate_config
from threedcal.dataset.build import register_store
from threedcal.dataset.camera_fit import AffineFit, fit_affine, fit_lensed
from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.splits import in_field_of_view
from threedcal.lens import RadialLens
from threedcal.sim.bench import BenchTruth

PLAN = {"spacing_mm": 0.5, "depths_mm": [1.0, 1.0, 2.0, 1.0, 1.0, 3.0], "depth_mode": "cycle"}


def variant(xy, px, shape, free_centre: bool, kappa2: bool) -> AffineFit:
    """Affine + lens by least squares over the located contacts (no rejection: a comparison)."""
    ok = np.isfinite(px).all(axis=1)
    a, b = xy[ok], px[ok]
    height, width = shape
    c0 = np.array([(width - 1) / 2, (height - 1) / 2])
    r0 = float(np.hypot(*c0))

    def model(p):
        centre, k = (p[6:8], p[8:]) if free_centre else (c0, p[6:])
        lens = RadialLens(
            tuple(centre), k[0] / r0**2, (k[1] / r0**4) if kappa2 else 0.0, (height, width)
        )
        return AffineFit(p[:6].reshape(2, 3), 0.0, ok, lens)

    start = np.concatenate(
        [fit_affine(a, b).matrix.ravel(), c0 if free_centre else [], [0.0, 0.0][: 1 + kappa2]]
    )
    p = optimize.least_squares(
        lambda p: (model(p).apply(a) - b).ravel(), start, method="lm", x_scale="jac"
    ).x
    return model(p)


def measure(sensor: str, seed: int, folder: Path) -> None:
    config = validate_config(
        {"seed": seed, "scenes": {"s": {"sensor": sensor, "printer": "ender3", "plan": PLAN}}}
    )
    scene = config["scenes"]["s"]
    collect_scene("s", scene, folder / "raw.zarr", truth_path=folder / "truth.json", progress=False)
    store = register_store(scene, folder / "raw.zarr", progress=False)
    truth = BenchTruth.read(folder / "truth.json")
    raw = store.raw
    height, width = raw["frames"].shape[1:3]
    cmd = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])
    grid = np.flatnonzero(store.phase == "grid")
    xy = cmd[store.first[grid]]
    probe = np.unique(cmd[store.first[grid]], axis=0)
    true_px = truth.camera_px(probe)
    view = in_field_of_view(true_px[:, 0], true_px[:, 1], width, height)

    def error(fit: AffineFit) -> str:
        e = np.linalg.norm(fit.apply(probe[view]) - true_px[view], axis=1)
        return f"{np.sqrt(np.mean(e**2)):.3f} / {e.max():.2f}"

    reg = store.registration
    relocated = np.array(
        [(c.x_px, c.y_px) if c is not None else (np.nan, np.nan) for c in reg.contacts]
    )
    # the first pass: the same locator on the camera's frames
    blank = raw["blank_frames"].values.astype(np.float32).mean(axis=0)
    first = []
    for row, contact in zip(grid, reg.contacts, strict=True):
        found = None
        if contact is not None:  # only where the stage kept one (same accept rule)
            found = locate_contact(store.mean_frame(row), blank)
        first.append((found.x_px, found.y_px) if found is not None else (np.nan, np.nan))
    first = np.array(first)
    if reg.locator != "rim":  # the symmetry locator's first pass is not repeated here
        first = relocated
    shape = (height, width)
    rows = {
        "affine": fit_affine(xy, relocated),
        "k1, centre fixed": variant(xy, relocated, shape, False, False),
        "k1": variant(xy, relocated, shape, True, False),
        "k1+k2, centre fixed": variant(xy, relocated, shape, False, True),
        "k1+k2": variant(xy, relocated, shape, True, True),
        "the stage, first pass (k1)": fit_lensed(xy, first, shape, kappa2=False),
        "the stage (relocated, k1)": reg.fit,
    }
    print(
        f"{sensor}, seed {seed}: {int(np.isfinite(relocated).all(axis=1).sum())} contacts "
        f"({reg.locator}), {int(view.sum())} probe points in view; error RMS / max px:"
    )
    for label, fit in rows.items():
        print(f"  {label:28s} {error(fit)}")


def main() -> None:
    seeds = [int(s) for s in sys.argv[1:]] or [11, 12]
    for seed in seeds:
        for sensor in ("digit", "gelsight_mini"):
            with tempfile.TemporaryDirectory() as folder:
                measure(sensor, seed, Path(folder))


if __name__ == "__main__":
    main()
