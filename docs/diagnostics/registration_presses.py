"""How well shallow registration presses register the rig, against the grid's own contacts.

For each sensor, seed and (depth, spacing) variant: a plan of registration-like presses alone
(one depth, the plan's 3 frames a press unless `--frames`, no touch search) collected on the
simulated bench, registered by the dataset stage (`register_store`), then the RMS / max error
against the bench's hidden truth over a 0.25 mm lattice of the probe area, where it lies in view.
Seeds other than the default study's 0: the figures the study reports are not the ones this chose
on (docs/explanation/registration.md, Registration presses). Usage (about a minute per run on 2 cores):

    .venv/bin/python docs/diagnostics/registration_presses.py [--elastic] digit 11 0.4 1.0 [...]

arguments in fours: sensor, seed, depth_mm, spacing_mm. `--elastic`: the bench simulates the gel as
an elastic layer (`bench.gel_mechanics: elastic`; docs/explanation/simulator.md, Gel mechanics). `--kappa2`: the
stage's lens fit frees κ₂ too (as before the stage kept κ₁ alone; docs/explanation/registration.md, The lens).
`--frames N`: N frames per press, the contact located in their mean (default: the plan's 3; the
study's registration presses take `plan.registration.frames`, 1 by default).

Each run also prints the rim locator's own error (camera frames, whole contacts) against where the
camera truly images each press's axis and, on a domed gel, what is left of it once the patch's
shift toward the dome's apex is taken out: a paraboloid ball of radius R on a dome z = k x²
touches where the gap is smallest, x0 - 2 k x0 R / (1 + 2 k R) per axis (x0 from the apex).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from threedcal.collect.plan import plan_area_mm
from threedcal.collect.session import collect_scene
from threedcal.config import validate_config
from threedcal.dataset.build import register_store
from threedcal.dataset.contacts import Contact, locate_contact
from threedcal.dataset.splits import in_field_of_view
from threedcal.dataset.symmetry import refine_by_symmetry
from threedcal.lens import RadialLens
from threedcal.sim.bench import BenchTruth


def measure(
    sensor: str,
    seed: int,
    depth_mm: float,
    spacing_mm: float,
    folder: Path,
    elastic: bool,
    frames: int | None = None,
) -> str:
    plan = {
        "spacing_mm": spacing_mm,
        "depths_mm": [depth_mm],
        "touch_search": {"points": 0},
        "registration": {"spacing_mm": 0},
    }
    if frames is not None:
        plan["frames"] = frames
    scene = {"sensor": sensor, "printer": "ender3", "plan": plan}
    if elastic:
        scene["bench"] = {"gel_mechanics": "elastic"}
    config = validate_config({"seed": seed, "scenes": {"s": scene}})
    scene = config["scenes"]["s"]
    collect_scene("s", scene, folder / "raw.zarr", truth_path=folder / "truth.json", progress=False)
    truth = BenchTruth.read(folder / "truth.json")
    store = register_store(scene, folder / "raw.zarr", progress=False)
    raw = store.raw
    height, width = raw["frames"].shape[1:3]
    area_w, area_h = plan_area_mm(store.sensor)
    gx, gy = np.meshgrid(np.arange(0, area_w + 1e-9, 0.25), np.arange(0, area_h + 1e-9, 0.25))
    # plan-relative mm to commanded printer mm: the store's own first row gives the offset
    mount = np.array(
        [
            raw["cmd_x_mm"].values[0] - raw["x_mm"].values[0],
            raw["cmd_y_mm"].values[0] - raw["y_mm"].values[0],
        ]
    )
    probe = np.column_stack([gx.ravel(), gy.ravel()]) + mount
    true_px = truth.camera_px(probe)
    view = in_field_of_view(true_px[:, 0], true_px[:, 1], width, height)
    fit = store.registration.fit
    error = np.linalg.norm(fit.apply(probe[view]) - true_px[view], axis=1)
    return (
        f"{sensor}{' (elastic gel)' if elastic else ''} seed {seed}, {depth_mm:g} mm deep on a {spacing_mm:g} mm lattice: "
        f"{np.sqrt(np.mean(error**2)):.3f} / {error.max():.2f} px RMS / max "
        f"({store.registration.locator}, {int(fit.inliers.sum())} contacts of "
        f"{len(store.rows('grid'))} presses)\n  "
        + radial_error(store, truth)
        + "\n  "
        + locator_bias(store, truth, radius_mm=2.0)
    )


def radial_error(store, truth: BenchTruth) -> str:
    """The stage's own contacts (the fit's inliers) against where the camera truly images each
    press, split into the part along the ray from the true lens's centre (+ outward) and the
    part across it, by that ray's length: the pattern a radial lens term can take up."""
    raw = store.raw
    rows = store.rows("grid")
    cmd = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])[store.first[rows]]
    true_px = truth.camera_px(cmd)
    if truth.lens is None:
        return "no lens"
    centre = np.asarray(truth.lens["centre_px"], dtype=float)
    reach, along, across = [], [], []
    for contact, where, inlier in zip(
        store.registration.contacts, true_px, store.registration.fit.inliers, strict=True
    ):
        if contact is None or not inlier:
            continue
        ray = where - centre
        r = float(np.hypot(*ray))
        error = np.array([contact.x_px, contact.y_px]) - where
        reach.append(r)
        along.append(float(error @ ray) / r)
        across.append(abs(float(error @ np.array([-ray[1], ray[0]])) / r))
    reach, along, across = map(np.array, (reach, along, across))
    bands = []
    for low, high in ((0, 60), (60, 90), (90, 120), (120, np.inf)):
        inside = (reach >= low) & (reach < high)
        if inside.any():
            bands.append(
                f"{low:g}-{high:g} px {along[inside].mean():+.3f} / {across[inside].mean():.3f}"
                f" (n {int(inside.sum())})"
            )
    return (
        "stage's contacts, mean radial / |tangential| error by distance from the lens's centre: "
        + (", ".join(bands))
    )


def symmetry_by_edge(store, rows, true_px, blank, lens=None) -> str:
    """The symmetry locator's RMS error against the truth, by the contact's distance from the
    frame's nearest edge (px); with `lens` (the bench's true one), also on frames rectified
    through it, against where the ideal frame holds each axis (is the lens the cause?); and with
    the fit started at the true centre instead of the rim locator's (is the start the cause?)."""
    raw = store.raw
    height, width = raw["frames"].shape[1:3]
    frames = [store.mean_frame(row) for row in rows]
    cases = [("camera frames", frames, blank, true_px, False)]
    if lens is not None:
        rectified = [lens.rectify(frame) for frame in frames]
        cases.append(("rectified", rectified, lens.rectify(blank), lens.undistort(true_px), False))
    cases.append(
        ("camera frames, the fit started at the true centre", frames, blank, true_px, True)
    )
    lines = []
    for label, images, reference, truth_px, true_start in cases:
        rim = [locate_contact(image, reference) for image in images]
        if true_start:  # the rim's radius, the truth's centre: is the fit's start the cause?
            rim = [
                None if c is None else Contact(float(t[0]), float(t[1]), c.radius_px, c.strength)
                for c, t in zip(rim, truth_px, strict=True)
            ]
        refined = refine_by_symmetry(images, reference, rim, progress=False).contacts
        edge, error = [], []
        for contact, where in zip(refined, truth_px, strict=True):
            if contact is not None:
                x, y = contact.x_px, contact.y_px
                edge.append(min(x, width - 1 - x, y, height - 1 - y))
                error.append(np.hypot(x - where[0], y - where[1]))
        edge, error = np.array(edge), np.array(error)
        bands = []
        for low, high in ((0, 30), (30, 45), (45, 60), (60, 80), (80, np.inf)):
            inside = (edge >= low) & (edge < high)
            if inside.any():
                rms = float(np.sqrt(np.mean(error[inside] ** 2)))
                bands.append(f"{low:g}-{high:g} px {rms:.2f} px (n {int(inside.sum())})")
        lines.append(f"{label}: " + ", ".join(bands))
    return "symmetry locator by distance from the frame's edge, " + "; ".join(lines)


def locator_bias(store, truth: BenchTruth, radius_mm: float) -> str:
    """The rim locator against the truth, and against the truth shifted by the dome (docstring)."""
    raw = store.raw
    height, width = raw["frames"].shape[1:3]
    rows = store.rows("grid")
    cmd = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])[store.first[rows]]
    true_px = truth.camera_px(cmd)
    blank = raw["blank_frames"].values.astype(np.float32).mean(axis=0)
    found, axis = [], []
    for row, where in zip(rows, true_px, strict=True):
        contact = locate_contact(store.mean_frame(row), blank)
        margin = None if contact is None else contact.radius_px + 5
        if margin is None or not (
            margin <= contact.x_px <= width - 1 - margin
            and margin <= contact.y_px <= height - 1 - margin
        ):
            continue
        found.append((contact.x_px, contact.y_px))
        axis.append(where)
    found, axis = np.array(found), np.array(axis)
    rms = float(np.sqrt(np.mean(np.sum((found - axis) ** 2, axis=1))))
    text = f"rim locator: {rms:.3f} px RMS over {len(found)} whole contacts"
    dome = store.sensor["gel"].get("dome")
    if dome is None:
        return (
            text
            + " (flat gel); "
            + symmetry_by_edge(store, rows, true_px, blank, RadialLens.from_record(truth.lens))
        )
    scale = store.px_per_mm
    shift = np.zeros_like(axis)
    for i, (key, apex, size) in enumerate(
        (("kx_per_mm", "apex_x_mm", width), ("ky_per_mm", "apex_y_mm", height))
    ):
        k = float(dome[key])
        offset = (axis[:, i] - (size - 1) / 2) / scale - float(dome.get(apex, 0.0))
        shift[:, i] = -2 * k * offset * radius_mm / (1 + 2 * k * radius_mm) * scale
    left = float(np.sqrt(np.mean(np.sum((found - axis - shift) ** 2, axis=1))))
    return (
        text + f"; the dome's shift (up to {np.abs(shift).max():.2f} px) taken out: {left:.3f} px"
    )


def main() -> None:
    args = sys.argv[1:]
    elastic = "--elastic" in args
    if "--kappa2" in args:  # as the stage was: κ₁ on the first pass, κ₁ + κ₂ on the relocated one
        from threedcal.dataset import registration

        plain_fit, plain_pass = registration.fit_lensed, registration._locate_and_fit
        relocated = [False]

        def one_pass(*a, **k):
            relocated[0] = k.get("back") is not None
            return plain_pass(*a, **k)

        registration._locate_and_fit = one_pass
        registration.fit_lensed = lambda *a, **k: plain_fit(*a, **{**k, "kappa2": relocated[0]})
    frames = None
    if "--frames" in args:
        at = args.index("--frames")
        if at + 1 >= len(args) or not args[at + 1].isdigit() or int(args[at + 1]) < 1:
            raise SystemExit("--frames needs a whole number of frames, at least 1\n\n" + __doc__)
        frames = int(args[at + 1])
        del args[at : at + 2]
    args = [a for a in args if a not in ("--elastic", "--kappa2")]
    if not args or len(args) % 4:
        raise SystemExit(__doc__)
    for i in range(0, len(args), 4):
        sensor, seed, depth, spacing = args[i : i + 4]
        with tempfile.TemporaryDirectory() as folder:
            print(
                measure(
                    sensor, int(seed), float(depth), float(spacing), Path(folder), elastic, frames
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
