"""What does each test-object protocol report for a perfect model? Run after `make all`:

    .venv/bin/python docs/diagnostics/perfect_model_objects.py digit_sim
    .venv/bin/python docs/diagnostics/perfect_model_objects.py digit_sim --no-mount-errors

A perfect model (`TruthGradients`: the exact gradients of the true surface of every rendered
press, from the bench's hidden truth, integrated with the scene's first integrator) is scored on
the scene's own presses with the scene's own registration, as the `objects` stage scores a model.
What `printer` reports is then the error of the placement alone (registration, touch height,
mount) plus the integrator's; what `paper` reports is what its alignment and depth fit leave of
it. `--no-mount-errors` presses the objects again (into a temporary folder) with the test
session's hidden mounting errors and lighting drift (`pressing.bench`) set to zero: what is left
is the calibration's registration and touch height. Diagnosis only: the oracle reads the
simulator's truth. Tables go to stdout; nothing is written under results/.
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.evaluate.pressing import (
    TruthGradients,
    evaluate_objects,
    press_objects,
    read_registration,
)
from threedcal.lens import RadialLens
from threedcal.profiles import load_profile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--no-mount-errors", action="store_true")
    args = parser.parse_args()
    root = Path("results") / args.scene
    scene = json.loads((root / "scene.json").read_text())["config"]
    registration = root / "dataset" / "registration.json"
    px_per_mm = load_profile("sensor", scene["sensor"])["px_per_mm"]
    with tempfile.TemporaryDirectory() as out:
        pressing = root / "objects" / "pressing"
        if args.no_mount_errors:
            scene["pressing"]["bench"] = {k: 0.0 for k in scene["pressing"]["bench"]}
            pressing = Path(out) / "pressing"
            press_objects(scene, registration, pressing, progress=False)
        lens = RadialLens.from_record(read_registration(registration).get("lens"))
        perfect = TruthGradients(pressing, px_per_mm, lens=lens)
        errors = evaluate_objects(
            scene,
            {80: "perfect"},
            pressing,
            registration,
            Path(out) / "objects",
            estimator=lambda model, blank: perfect,
            plots=False,
            progress=False,
        )
        presses = pd.read_csv(Path(out) / "objects" / "presses.csv")
    columns = ["object", "protocol", "presses", "type1_um", "type2_um", "type2_um_lo"]
    columns += ["type2_um_hi", "depth_ratio"]
    mounts = "no hidden mounting errors" if args.no_mount_errors else "the scene's presses"
    print(
        f"{args.scene}, {mounts}: a perfect model, reporting presses (MAE um; depth_ratio: /true)"
    )
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


if __name__ == "__main__":
    main()
