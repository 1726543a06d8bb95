"""Where does a scene's test-object error come from? Run after `make all`:

    .venv/bin/python docs/diagnostics/object_error_source.py digit_sim

For every object press of the scene it scores, with the same protocol as the `objects` stage:
the simulator's own gel surface (exact in contact: the limit of ground truth, alignment and depth
fit), and the P = 80 model's prediction, with the model's signed error by true depth (where in
the contact it sits). Then, on validation frames of the scene's training set, the
mean predicted slope magnitude against the label in rings around the probe centre.
"""

import json
import sys
from pathlib import Path

import numpy as np

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.object_errors import evaluate_press
from threedcal.evaluate.objects import load_object
from threedcal.evaluate.pressing import plan_presses, relief_indenter, render_press
from threedcal.model.inference import DepthEstimator
from threedcal.profiles import load_profile
from threedcal.sim.optics import GelSimulator


def main(scene_name: str, p: int = 80) -> None:
    root = Path("results") / scene_name
    scene = json.loads((root / "scene.json").read_text())["config"]
    sim = GelSimulator(load_profile("sensor", scene["sensor"]), seed=scene["seed"])
    est = DepthEstimator.from_checkpoint(root / "models" / f"P{p}" / "model.pt", device="cpu")
    presses = plan_presses(
        scene["objects"], (sim.height, sim.width), scene["pressing"], scene["seed"]
    )
    print(f"{scene_name}: Type 2 / Type 1 MAE (um) of the simulator's own surface and of P = {p}")
    for index, press in enumerate(presses):
        mesh = load_object(press.name)
        window = (0, sim.height, 0, sim.width)
        depth_mm = sim.effective_depth_mm(press.depth_mm, 0)
        indenter = relief_indenter(mesh, sim.px_per_mm, press.rotation_deg)
        z, contact = sim.surface(indenter, press.center_px, 0.0, depth_mm, window)
        u = (press.center_px[0] - (sim.width - 1) / 2) / sim.px_per_mm
        v = (press.center_px[1] - (sim.height - 1) / 2) / sim.px_per_mm
        # in contact the model's labels describe the object's shape (flat reference); outside, the gel
        surface = np.where(contact, z - float(sim.sag_mm(u, v)), z - sim.Z0).astype(np.float64)
        kwargs = dict(
            px_per_mm=sim.px_per_mm,
            nominal_indentation_mm=press.nominal_depth_mm,
            max_penetration_mm=sim.max_penetration_mm,
            center_px=press.center_px,
            rotation_deg=press.rotation_deg,
        )
        frame = render_press(sim, press, frame_index=index)
        name = f"{press.name} #{press.number}"
        for label, depth in (("simulator surface", surface), (f"model P{p}", est.depth(frame))):
            evaluation = evaluate_press(depth, mesh, **kwargs)
            e = evaluation.errors
            print(
                f"  {name:15s} {label:18s} {e['type2_um']:7.1f} / {e['type1_um']:6.1f}"
                f"   fitted depth {evaluation.indentation_mm:.2f} mm"
            )
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
