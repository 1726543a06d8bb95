"""What does each test-object protocol report for a perfect model? Run after `make all`:

    .venv/bin/python -m diagnostics.perfect_model_objects digit_sim
    .venv/bin/python -m diagnostics.perfect_model_objects digit_sim --no-mount-errors
    .venv/bin/python -m diagnostics.perfect_model_objects mini_sim --gel [geometric|elastic]

A perfect model (`TruthGradients`: the exact gradients of the true surface of every rendered
press, from the bench's hidden truth, integrated with the scene's first integrator) is scored on
the scene's own presses with the scene's own registration, as the `objects` stage scores a model.
What `printer` reports is then the error of the placement alone (registration, touch height,
mount) plus the integrator's; what `paper` reports is what its alignment and depth fit leave of
it. `--no-mount-errors` presses the objects again (into a temporary folder) with the test
session's hidden mounting errors and lighting drift (`pressing.bench`) set to zero: what is left
is the calibration's registration and touch height. `--gel` takes the exact gradients of the
*pressed gel's* surface instead (the bench's gel under each object, elastic or geometric as the
scene's bench simulates it, central differences at the pixel centres): what a model that reads the
gel perfectly scores against the rigid object's ground truth. On a flat geometric gel, which
follows the object, the two agree but at walls (central differences over two pixels carry part of
a wall's step, pixel-centre gradients none); on the elastic gel the difference is the gel's own
share of the error; on the domed DIGIT the gel's depth below its undeformed dome also holds the
dome's sag across the contact, which the ground truth does not. Diagnosis only: the oracle reads the simulator's truth. Tables go to
stdout; nothing is written under results/ (`--results`: another study's results folder).
`--smoke`: a DIGIT scene of one pill pressed twice, registered as the bench's truth, built in a
temporary folder (seconds; the scene argument is then ignored).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.depth import integrate
from threedcal.evaluate.object_presses import press_objects, read_presses, relief_indenter
from threedcal.evaluate.object_scores import evaluate_objects
from threedcal.evaluate.objects import load_object
from threedcal.evaluate.press_plan import read_registration
from threedcal.evaluate.truth_gradients import TruthGradients
from threedcal.lens import RadialLens, rectify_if
from threedcal.profiles import load_profile, with_gel_mechanics
from threedcal.sim.bench import SimBench
from threedcal.sim.optics import GelSimulator
from threedcal.study.config import validate_config
from threedcal.study.pressing import objects_setup


class GelGradients:
    """A model that reads the pressed gel perfectly: the gradients of the bench's gel surface
    under each press (its true pose and depth), integrated as a model's would be. What
    `evaluate_objects` asks of a model: `px_per_mm`, `image_shape`, `depth(frame, method=)`."""

    def __init__(self, pressing_dir: Path, scene: dict, lens: RadialLens | None):
        plan, frames, _, truth = read_presses(pressing_dir)
        frames = rectify_if(lens, frames)
        sensor = with_gel_mechanics(
            load_profile("sensor", scene["sensor"]), scene["bench"].get("gel_mechanics")
        )
        sensor = {**sensor, "lens": None}  # the rectified (ideal) frame
        gel = GelSimulator(sensor, seed=0)
        self.px_per_mm = float(gel.px_per_mm)
        height, width = self.image_shape = tuple(frames.shape[1:3])
        self.gradients = {}
        reliefs = {}
        for row, frame, true in zip(plan.itertuples(), frames, truth["presses"], strict=True):
            if row.object not in reliefs:
                reliefs[row.object] = relief_indenter(load_object(row.object), self.px_per_mm)
            z, _ = gel.surface(
                reliefs[row.object],
                tuple(true["center_px"]),
                true["rotation_deg"],
                true["depth_mm"],
                (0, height, 0, width),
            )
            depth = np.asarray(z, dtype=np.float64) - gel.Z0[:height, :width]
            gy, gx = np.gradient(depth)
            self.gradients[frame.tobytes()] = (gx * self.px_per_mm, gy * self.px_per_mm)

    def depth(self, frame: np.ndarray, method: str = "poisson_dst") -> np.ndarray:
        gx, gy = self.gradients[np.asarray(frame).tobytes()]
        return integrate(gx, gy, method=method, px_per_mm=self.px_per_mm)


def smoke_study(results: Path) -> str:
    """A tiny finished scene under `results`: scene.json, a registration as good as the bench's
    truth, and the objects' presses (one pill, one tuning and one reporting press). Its name."""
    config = {"sensor": "digit", "printer": "ender3", "objects": ["pill"]}
    config["pressing"] = {"presses": 1, "tuning_presses": 1}
    scene = validate_config({"scenes": {"smoke": config}})["scenes"]["smoke"]
    root = results / "smoke"
    (root / "dataset").mkdir(parents=True)
    (root / "scene.json").write_text(json.dumps({"config": scene}))
    sensor = load_profile("sensor", scene["sensor"])
    with SimBench(sensor, 2.0, scene["bench"], scene["seed"]) as bench:
        truth = bench.truth
    record = {
        "affine_px_per_mm": truth.affine_px_per_mm,
        "lens": truth.lens,
        "touch_offset_mm": truth.touch_offset_mm,
        "touch_offset_error_mm": 0.0,
    }
    registration = root / "dataset" / "registration.json"
    registration.write_text(json.dumps(record))
    press_objects(objects_setup(scene), registration, root / "objects" / "pressing", progress=False)
    return "smoke"


def main(argv: list[str] | None = None) -> pd.DataFrame:
    """Score the perfect model on the scene's presses and print the tables: errors.csv's rows."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="digit_sim")
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--no-mount-errors", action="store_true")
    parser.add_argument(
        "--gel",
        nargs="?",
        const="scene",
        choices=["scene", "geometric", "elastic"],
        help="the pressed gel's gradients (the scene's bench's gel, or the one named)",
    )
    parser.add_argument("--smoke", action="store_true", help="a tiny scene in a temporary folder")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as out:
        if args.smoke:
            args.results = Path(out) / "results"
            args.scene = smoke_study(args.results)
        return score(args, Path(out))


def score(args: argparse.Namespace, out: Path) -> pd.DataFrame:
    root = args.results / args.scene
    scene = json.loads((root / "scene.json").read_text())["config"]
    registration = root / "dataset" / "registration.json"
    px_per_mm = load_profile("sensor", scene["sensor"])["px_per_mm"]
    pressing = root / "objects" / "pressing"
    if args.no_mount_errors:
        scene["pressing"]["bench"] = {k: 0.0 for k in scene["pressing"]["bench"]}
        pressing = out / "pressing"
        press_objects(objects_setup(scene), registration, pressing, progress=False)
    lens = RadialLens.from_record(read_registration(registration).get("lens"))
    if args.gel:
        if args.gel != "scene":
            scene["bench"] = {**scene["bench"], "gel_mechanics": args.gel}
        perfect = GelGradients(pressing, scene, lens)
    else:
        dome = load_profile("sensor", scene["sensor"])["gel"].get("dome")
        perfect = TruthGradients(pressing, px_per_mm, lens=lens, dome=dome)
    errors = evaluate_objects(
        objects_setup(scene),
        {80: "perfect"},
        pressing,
        registration,
        out / "objects",
        estimator=lambda model, blank: perfect,
        plots=False,
        progress=False,
    )
    presses = pd.read_csv(out / "objects" / "presses.csv")
    columns = ["object", "protocol", "presses", "type1_um", "type2_um", "type2_um_lo"]
    columns += ["type2_um_hi", "depth_ratio"]
    mounts = "no hidden mounting errors" if args.no_mount_errors else "the scene's presses"
    oracle = "the pressed gel's gradients" if args.gel else "the true surface's gradients"
    print(f"{args.scene}, {mounts}: {oracle}, reporting presses (MAE um; depth_ratio: /true)")
    print(errors[columns].round(3).to_string(index=False))
    printer = presses[presses["protocol"] == "printer"]
    depth = (printer["registered_depth_mm"] - printer["true_depth_mm"]) * 1000
    centre = np.hypot(
        printer["registered_x_px"] - printer["true_x_px"],
        printer["registered_y_px"] - printer["true_y_px"],
    )
    touch = json.loads(registration.read_text()).get("touch_offset_error_mm")
    print(
        f"placement (printer protocol, all presses): registered - true depth {depth.mean():+.1f} um "
        f"(SD {depth.std():.1f}); centre {centre.mean():.2f} px; the registration's touch-offset "
        f"error {touch * 1000:+.1f} um"
    )
    return errors


if __name__ == "__main__":
    main()
