"""What does each test-object protocol report for a perfect model? Run after `make all`:

    .venv/bin/python docs/diagnostics/perfect_model_objects.py digit_sim

A perfect model (`TruthGradients`: the exact gradients of the true surface of every rendered
press, from the bench's hidden truth, integrated with the scene's first integrator) is scored on
the scene's own presses with the scene's own registration, as the `objects` stage scores a model.
What `printer` reports is then the error of the placement alone (registration, touch height,
mount) plus the integrator's; what `paper` reports is what its alignment and depth fit leave of
it. Diagnosis only: the oracle reads the simulator's truth. Tables go to stdout; nothing is
written under results/.
"""

import json
import sys
import tempfile
from pathlib import Path

from threedcal.evaluate.pressing import TruthGradients, evaluate_objects
from threedcal.profiles import load_profile


def main(scene_name: str) -> None:
    root = Path("results") / scene_name
    scene = json.loads((root / "scene.json").read_text())["config"]
    px_per_mm = load_profile("sensor", scene["sensor"])["px_per_mm"]
    perfect = TruthGradients(root / "objects" / "pressing", px_per_mm)
    with tempfile.TemporaryDirectory() as out:
        errors = evaluate_objects(
            scene,
            {80: "perfect"},
            root / "objects" / "pressing",
            root / "dataset" / "registration.json",
            out,
            estimator=lambda model, blank: perfect,
            plots=False,
            progress=False,
        )
    columns = ["object", "protocol", "presses", "type1_um", "type2_um", "type2_um_lo"]
    columns += ["type2_um_hi", "depth_ratio"]
    print(f"{scene_name}: a perfect model, reporting presses (MAE um; depth_ratio: depth / true)")
    print(errors[columns].round(3).to_string(index=False))


if __name__ == "__main__":
    main(sys.argv[1])
