"""The touch height on the simulated bench: the first-contact search against the rim's radii.

    .venv/bin/python docs/diagnostics/touch_height.py                      # both sensors, seeds 0-2
    .venv/bin/python docs/diagnostics/touch_height.py --sensors digit --plans grid --seeds 3 4
    .venv/bin/python docs/diagnostics/touch_height.py --law elastic        # a Hertz-like gel

Each case collects a store on the bench (the default touch search first, then the plan's grid
rows, one frame a point), registers its grid rows once (threedcal.dataset.build.register_store)
and measures the touch height both ways from that one registration — `search` (the plan's
first-contact search, what plans use by default) and `rim` (the grid's contact radii, what a plan
without a search falls back to, and what every plan used before) — against the bench's hidden
touch height. Plans: grid (one depth, 1.0 mm: the old default), paper (2.0 mm = R, as
config/paper.yaml), cross (the authors' cross at 1.0, 2.0, 3.0 mm), default (config.yaml's:
1.0/2.0/3.0 mm cycled), study (the default study's own scene whose sensor this is, as config.yaml
has it — its bench, first-contact search and registration presses — with the grid thinned to
--spacing; `--touch-frames N` sets its search's frames per step). `--spacing` thins the grids
(registration is the slow part; the touch search does not depend on it). `--law elastic` swaps the
simulator's rigid contact for the Hertz solution (a² = Rd, the surface sinking around the
contact), `--law skirt` widens its skirt. The fitted DIGIT's search with 1 and with 4 frames a
step (docs/explanation/registration.md, Four frames a step):

    .venv/bin/python docs/diagnostics/touch_height.py --sensors digit_fots --plans study \
        --seeds 11 12 13 14 21 22 23 24 31 32 33 34 --touch-frames 4

Its `error_px` compares the fitted registration with the bench's affine alone. On a bench with a
lens (the study's scenes) that error includes the lens's distortion, so it is not the
registration's error there: read the stage's own `error_px` in registration.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from threedcal.collect.session import collect_scene
from threedcal.config import validate_config
from threedcal.dataset.build import register_store, touch_height
from threedcal.dataset.splits import in_field_of_view
from threedcal.errors import ThreedcalError
from threedcal.profiles import resolve_profile


def plan_of(kind: str, spacing: float) -> dict:
    if kind == "grid":
        return {"spacing_mm": spacing, "depth_mm": 1.0, "frames": 1}
    if kind == "paper":
        return {"spacing_mm": spacing, "depth_mm": 2.0, "frames": 1}
    if kind == "cross":
        return {
            "pattern": "cross",
            "spacing_mm": spacing,
            "depths_mm": [1.0, 2.0, 3.0],
            "frames": 1,
        }
    if kind == "default":
        return {
            "spacing_mm": spacing,
            "depths_mm": [1.0, 2.0, 3.0],
            "depth_mode": "cycle",
            "frames": 1,
        }
    raise SystemExit(f"unknown plan {kind!r} (grid, paper, cross, default)")


def elastic_surface(self, indenter, center_px, rotation_deg, depth_mm, window):
    """The Hertz solution for a sphere on an elastic half-space: a = sqrt(R d); the surface follows
    d − r²/2R inside, ((2a² − r²) asin(a/r) + a sqrt(r² − a²)) / (π R) outside."""
    y0, y1, x0, x1 = window
    x = self.X[y0:y1, x0:x1] - (center_px[0] - self._cx) / self.px_per_mm
    y = self.Y[y0:y1, x0:x1] - (center_px[1] - self._cy) / self.px_per_mm
    r = np.hypot(x, y)
    radius = indenter.radius_mm
    a = math.sqrt(radius * depth_mm)
    safe = np.maximum(r, a)
    outside = (
        (2 * a * a - safe**2) * np.arcsin(np.minimum(a / safe, 1.0))
        + a * np.sqrt(np.maximum(safe**2 - a * a, 0.0))
    ) / (math.pi * radius)
    sink = np.where(r < a, depth_mm - r * r / (2 * radius), outside)
    return (self.Z0[y0:y1, x0:x1] + sink).astype(np.float32), r < a


def wide_window(self, indenter, center_px, depth_mm, rotation_deg=0.0):
    reach = 3 * indenter.radius_mm * self.px_per_mm
    x0, x1 = max(int(center_px[0] - reach), 0), min(int(center_px[0] + reach) + 1, self.width)
    y0, y1 = max(int(center_px[1] - reach), 0), min(int(center_px[1] + reach) + 1, self.height)
    return (y0, y1, x0, x1) if x1 - x0 >= 3 and y1 - y0 >= 3 else None


def sensor_ref(sensor: str, law: str, folder: Path) -> str:
    if law != "skirt":
        return sensor
    profile = yaml.safe_load(resolve_profile("sensor", sensor).read_text())
    profile["gel"].update(skirt_width_per_thickness=0.3, rim_volume_fraction=0.8)
    path = folder / f"{sensor}_wide_skirt.yaml"
    path.write_text(yaml.safe_dump(profile))
    return str(path)


def study_scene(sensor: str, spacing: float, touch_frames: int | None = None) -> dict:
    """config.yaml's scene on `sensor`, its grid thinned to `spacing` (its ablation, objects and
    model are not used here), its search taking `touch_frames` frames a step when given."""
    study = yaml.safe_load(Path("config.yaml").read_text())["scenes"]
    found = [dict(scene) for scene in study.values() if scene.get("sensor") == sensor]
    if not found:
        raise SystemExit(f"config.yaml has no scene on sensor {sensor!r}")
    scene = found[0]
    scene["plan"] = {**scene["plan"], "spacing_mm": spacing}
    if touch_frames is not None:
        search = scene["plan"].get("touch_search", {})
        scene["plan"]["touch_search"] = {**search, "frames": touch_frames}
    return scene


def run_case(
    sensor: str,
    kind: str,
    seed: int,
    spacing: float,
    law: str,
    folder: Path,
    touch_frames: int | None = None,
) -> dict:
    if kind == "study":
        if law != "rigid":
            raise SystemExit("--plans study runs the scene's own bench: leave --law rigid")
        spec = study_scene(sensor, spacing, touch_frames)
    elif touch_frames is not None:
        raise SystemExit("--touch-frames applies to --plans study only")
    else:
        spec = {
            "sensor": sensor_ref(sensor, law, folder),
            "printer": "ender3",
            "plan": plan_of(kind, spacing),
        }
    scene = validate_config({"seed": seed, "scenes": {"s": spec}})["scenes"]["s"]
    store = folder / f"{sensor}_{kind}_{seed}.zarr"
    truth_path = folder / f"{sensor}_{kind}_{seed}.json"
    collect_scene("s", scene, store, truth_path=truth_path, progress=False)
    truth = json.loads(truth_path.read_text())
    registered = register_store(scene, store, progress=False)
    fit = registered.registration.fit
    true_affine = np.asarray(truth["affine_px_per_mm"])
    # registration.json's error_px: over the grid points whose probe the affine puts in view
    grid = registered.first[registered.rows("grid")]
    height, width = registered.raw["frames"].shape[1:3]
    centres = registered.centres[grid]
    in_view = in_field_of_view(centres[:, 0], centres[:, 1], width, height)
    probe = np.column_stack([registered.raw["cmd_x_mm"].values, registered.raw["cmd_y_mm"].values])
    probe = np.unique(probe[grid][in_view], axis=0)
    error = np.linalg.norm(
        fit.apply(probe) - (probe @ true_affine[:, :2].T + true_affine[:, 2]), axis=1
    )
    row = {
        "sensor": sensor,
        "plan": kind,
        "seed": seed,
        "true_mm": truth["touch_offset_mm"],
        "locator": registered.registration.locator,
        "error_px": float(np.sqrt(np.mean(error**2))),
        "exponent": math.nan,  # the search's measured power, when it succeeds
    }
    for method in ("search", "rim"):
        try:
            estimate = touch_height(registered, float(scene["probe"]["radius_mm"]), method)
            row[method] = estimate["touch_offset_mm"] - truth["touch_offset_mm"]
            if method == "search":
                row["exponent"] = estimate["touch_search"]["signal_exponent"]
        except ThreedcalError as exc:
            row[method] = f"fails: {str(exc).splitlines()[0][:60]}"
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", nargs="+", default=["digit", "gelsight_mini"])
    parser.add_argument("--plans", nargs="+", default=["grid", "paper", "cross"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--spacing", type=float, default=3.0)
    parser.add_argument("--law", choices=["rigid", "elastic", "skirt"], default="rigid")
    parser.add_argument("--touch-frames", type=int, default=None)
    args = parser.parse_args()
    if args.touch_frames is not None and args.touch_frames < 1:
        parser.error("--touch-frames must be at least 1")
    if args.law == "elastic":
        from threedcal.sim.optics import GelSimulator

        GelSimulator.surface = elastic_surface
        GelSimulator.window = wide_window
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for sensor in args.sensors:
            for kind in args.plans:
                for seed in args.seeds:
                    started = time.perf_counter()
                    row = run_case(
                        sensor, kind, seed, args.spacing, args.law, Path(tmp), args.touch_frames
                    )
                    rows.append(row)
                    cells = [
                        f"{row[m] * 1000:+7.1f}" if isinstance(row[m], float) else row[m]
                        for m in ("search", "rim")
                    ]
                    print(
                        f"{sensor:14s} {kind:8s} seed {seed}  true {row['true_mm']:+.4f} mm  "
                        f"search {cells[0]} um (p {row['exponent']:.2f})  rim {cells[1]}  "
                        f"error_px {row['error_px']:.3f} "
                        f"({row['locator']}, {time.perf_counter() - started:.0f} s)",
                        flush=True,
                    )
    print(
        f"\nlaw: {args.law}, grid spacing {args.spacing} mm; |error| in um: mean (max) over seeds"
    )
    for sensor in args.sensors:
        for kind in args.plans:
            cells = []
            for method in ("search", "rim"):
                values = [r[method] for r in rows if r["sensor"] == sensor and r["plan"] == kind]
                numbers = [abs(v) * 1000 for v in values if isinstance(v, float)]
                failed = len(values) - len(numbers)
                text = f"{np.mean(numbers):6.1f} ({max(numbers):6.1f})" if numbers else "   -"
                cells.append(text + (f", {failed} failed" if failed else ""))
            print(f"{sensor:14s} {kind:8s} search {cells[0]:16s} rim {cells[1]}")


if __name__ == "__main__":
    sys.exit(main())
