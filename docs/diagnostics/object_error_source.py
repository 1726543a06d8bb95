"""Where does a scene's test-object error come from? Run after `make all`:

    .venv/bin/python docs/diagnostics/object_error_source.py digit_sim

For every reporting press of the scene (results/{scene}/objects/pressing/) it scores, under both
protocols of the `objects` stage: the simulator's own gel surface where the bench put the object
(exact in contact: the limit of the ground truth, the registration and, for `paper`, the
alignment and depth fit), and the P = 80 model's prediction, with the model's signed error by
ground-truth depth (where in the contact it sits). Then, on validation frames of the scene's
training set, the mean predicted slope magnitude against the label in rings around the probe
centre. It reads the bench's truth (where the object really was), so it is a diagnosis, never a
reported figure.
"""

import json
import sys
from pathlib import Path

import numpy as np

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.groundtruth import surface_height
from threedcal.evaluate.object_presses import read_presses, relief_indenter
from threedcal.evaluate.object_scores import head_position, score_press
from threedcal.evaluate.press_plan import PrinterFrame, object_mesh, read_registration, scene_mount
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.inference import DepthEstimator
from threedcal.profiles import load_profile
from threedcal.sim.optics import GelSimulator


def main(scene_name: str, p: int = 80) -> None:
    root = Path("results") / scene_name
    scene = json.loads((root / "scene.json").read_text())["config"]
    sensor = load_profile("sensor", scene["sensor"])
    sim = GelSimulator(sensor, seed=scene["seed"])
    frame = PrinterFrame(
        sensor, read_registration(root / "dataset" / "registration.json"), scene_mount(scene)
    )
    plan, frames, blanks, truth = read_presses(root / "objects" / "pressing")
    checkpoint = read_checkpoint(root / "models" / f"P{p}" / "r0" / "model.pt")
    est = DepthEstimator(checkpoint, device="cpu", blank=blanks["reporting"])
    limit = sim.max_penetration_mm
    print(f"{scene_name}: Type 2 / Type 1 MAE (um) of the simulator's own surface and of P = {p}")
    for press in plan[plan["set"] == "reporting"].itertuples():
        mesh, true = object_mesh(press.object), truth["presses"][press.frame]
        placed = frame.placement(head_position(press))
        surface_gt = surface_height(
            mesh, frames.shape[1:3], 1.0, placed.center_px, 0.0, placed.linear_px_per_mm
        )
        window = (0, sim.height, 0, sim.width)
        indenter = relief_indenter(mesh, sim.px_per_mm)
        z, contact = sim.surface(
            indenter, true["center_px"], true["rotation_deg"], true["depth_mm"], window
        )
        u = (true["center_px"][0] - (sim.width - 1) / 2) / sim.px_per_mm
        v = (true["center_px"][1] - (sim.height - 1) / 2) / sim.px_per_mm
        # in contact the model's labels describe the object's shape (flat reference); outside, the gel
        gel = np.where(contact, z - float(sim.sag_mm(u, v)), z - sim.Z0).astype(np.float64)
        name = f"{press.label} #{press.press}"
        for label, depth in (
            ("simulator surface", gel),
            (f"model P{p}", est.depth(frames[press.frame])),
        ):
            scored = score_press(
                depth, mesh, placed, surface_gt, px_per_mm=est.px_per_mm, max_penetration_mm=limit
            )
            printer, paper = scored["printer"], scored["paper"]
            e, f = printer.errors, paper.errors
            print(
                f"  {name:15s} {label:18s} printer {e['type2_um']:7.1f} / {e['type1_um']:6.1f}"
                f"   paper {f['type2_um']:7.1f} / {f['type1_um']:6.1f}"
                f" (fitted depth {paper.indentation_mm:.2f} of {true['depth_mm']:.2f} mm)"
            )
        evaluation = printer
        # where the model's Type 2 error sits: signed mean (prediction - truth) by true depth
        gt, err = evaluation.gt_mm, (depth - evaluation.gt_mm) * 1000
        bands = [(0.0, 0.1), (0.1, 0.3), (0.3, 0.6), (0.6, np.inf)]
        cells = [
            f"{lo:g}-{hi:g} mm: {err[(gt > lo) & (gt <= hi)].mean():+.0f}"
            for lo, hi in bands
            if ((gt > lo) & (gt <= hi)).any()
        ]
        print(f"  {'':15s} signed error (um) by true depth: {', '.join(cells)}")
    ts = TrainingSet.load(root / "dataset" / "trainset")
    sums: dict[int, np.ndarray] = {}
    for i in ts.indices("val")[::10]:
        g = est.gradients(np.asarray(ts.frames[i]))  # (H, W, 2)
        lab = ts.labels(i).transpose(1, 2, 0)  # (2, H, W) -> (H, W, 2)
        cx, cy = ts.center_px[i]
        yy, xx = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
        r = np.hypot(xx - cx, yy - cy)
        for lo in range(0, 45, 5):
            ring = (r >= lo) & (r < lo + 5)
            add = [np.hypot(*g[ring].T).sum(), np.hypot(*lab[ring].T).sum(), ring.sum()]
            sums[lo] = sums.get(lo, np.zeros(3)) + add
    print("  validation frames, mean |slope| by ring (px from the probe centre): predicted / label")
    for lo, (pred, label, n) in sums.items():
        print(f"    r {lo:2d}-{lo + 5:2d}: {pred / n:.3f} / {label / n:.3f}")


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) for a in sys.argv[2:]))
