"""The sensor and printer frames of DepthEstimator.points, and the bench's sphere round trip.

A DIGIT (its built-in profile without the lens) is calibrated on the simulated bench (2 mm grid of
1 mm presses, seed 3, as tests/model/test_points.py), a `lookup` model is trained on it, and a 2 mm
radius ball is pressed 1 mm deep at three printer positions. For each press it prints how far the
sphere fitted to the contact points lies from the printer's ball (X, Y; Z) and how far the points
lie from that sphere: once with the press's exact gradients (the geometry: integration,
registration, touch height) and once through the model. It draws point_frames.png: the model frame
with both frames' axes, the points in the printer frame, and a section through the press.

    .venv/bin/python -m diagnostics.point_frames [--out docs/figures] [--smoke]

About a minute on 2 cores; `--smoke`: a 3 mm grid and one press, seconds, into a temporary folder.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import least_squares

from threedcal.dataset.build import build_collected
from threedcal.dataset.labels import local_dome, sphere_gradients
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings
from threedcal.profiles import load_profile
from threedcal.sim.bench import SimBench, plan_centre_printer_mm
from threedcal.study.config import validate_config
from threedcal.study.scene import dataset_settings
from threedcal.study.session import collect_scene

FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"
RADIUS = 2.0  # the probe's ball, mm
SEED = 3
PLAN = {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1}
OFFSETS = [(0.0, 0.0), (2.5, -3.0), (-3.3, 4.1)]


def lens_free_digit(folder: Path) -> str:
    """The built-in DIGIT profile without its lens, as a YAML path (a plan this coarse cannot fit
    the lens; registration then keeps the affine alone)."""
    profile = {k: v for k, v in load_profile("sensor", "digit").items() if k != "source"}
    profile["lens"] = None
    path = folder / "digit-lens-free.yaml"
    path.write_text(yaml.safe_dump(profile, sort_keys=False))
    return str(path)


def bench_scene(sensor: str, plan: dict) -> dict:
    """A validated scene on the simulated bench (hidden touch height up to 0.1 mm)."""
    scene = {"sensor": sensor, "printer": "ender3", "plan": plan, "bench": {"touch_offset_mm": 0.1}}
    return validate_config({"seed": SEED, "scenes": {"s": scene}})["scenes"]["s"]


def calibrate(folder: Path, scene: dict, epochs_base: int) -> DepthEstimator:
    """Collect the scene on the bench, run the dataset stage and train a `lookup` model."""
    collect_scene("s", scene, folder / "raw.zarr", truth_path=folder / "truth.json", progress=False)
    paths = [folder / n for n in ("ts", "splits.csv", "reg.json", "reg.png", "truth.json")]
    build_collected(dataset_settings(scene), folder / "raw.zarr", *paths, progress=False)
    settings = TrainSettings.of(preset="lookup", epochs_base=epochs_base, torch_threads=2)
    train(TrainingSet.load(folder / "ts"), folder / "model", 80, settings, progress=False)
    return DepthEstimator.from_checkpoint(folder / "model" / "model.pt", device="cpu")


def bench_press(scene: dict, x_offset_mm: float, y_offset_mm: float, depth_mm: float):
    """A sphere pressed on the bench `depth_mm` into the gel, its axis at the plan centre plus the
    offsets: (frame, true ball centre in printer mm, true pixel centre, true depth, sensor)."""
    sensor = load_profile("sensor", scene["sensor"])
    with SimBench(sensor, RADIUS, scene["bench"], scene["seed"]) as bench:
        cx, cy = plan_centre_printer_mm(sensor)
        x, y = cx + x_offset_mm, cy + y_offset_mm
        centre_px = bench.pose_px(x, y)
        z = bench.penetration_mm(centre_px, 0.0) - depth_mm  # the head's Z for that depth
        true_depth = bench.penetration_mm(centre_px, z)
        frame = bench.gel.render(bench.ball, centre_px, 0.0, true_depth, frame_index=7)
    return frame, np.array([x, y, z + RADIUS]), centre_px, true_depth, sensor


def fit_sphere(points: np.ndarray, radius: float = RADIUS):
    """Least-squares centre of a sphere of known radius through `points`; and each one's residual."""
    start = points.mean(axis=0) + [0.0, 0.0, radius]
    centre = least_squares(lambda c: np.linalg.norm(points - c, axis=1) - radius, start).x
    return centre, np.linalg.norm(points - centre, axis=1) - radius


def report(name: str, cloud, ball: np.ndarray) -> dict:
    centre, residual = fit_sphere(cloud.points[cloud.contact])
    found = {
        "xy_um": float(np.hypot(*(centre - ball)[:2]) * 1000),
        "z_um": float((centre - ball)[2] * 1000),
        "rms_um": float(np.sqrt(np.mean(residual**2)) * 1000),
        "max_um": float(np.abs(residual).max() * 1000),
        "contact_points": int(cloud.contact.sum()),
    }
    print(
        f"  {name:<10} centre off by {found['xy_um']:5.1f} um in X, Y and {found['z_um']:+6.1f} um "
        f"in Z; points off the sphere {found['rms_um']:5.1f} um RMS, {found['max_um']:5.1f} um max "
        f"({found['contact_points']} contact points)"
    )
    return found


def main(argv: list[str] | None = None) -> list[dict]:
    """Print the round trip of each press, draw the figure; one {geometry, model} per press."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="folder for point_frames.png (docs/figures)")
    parser.add_argument("--smoke", action="store_true", help="a 3 mm grid and one press")
    args = parser.parse_args(argv)
    # a smoke run never overwrites the docs' figure
    out = args.out or (Path(tempfile.mkdtemp(prefix="point_frames-")) if args.smoke else FIGURES)
    plan = {**PLAN, "spacing_mm": 3.0} if args.smoke else PLAN
    offsets = OFFSETS[2:] if args.smoke else OFFSETS
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        scene = bench_scene(lens_free_digit(folder), plan)
        estimator = calibrate(folder, scene, epochs_base=1)
        found = []
        for offset in offsets:
            frame, ball, centre_px, depth, sensor = bench_press(scene, *offset, 1.0)
            print(
                f"press at plan centre {offset[0]:+.1f}, {offset[1]:+.1f} mm, {depth:.3f} mm deep:"
            )
            px = float(sensor["px_per_mm"])
            dome = local_dome(sensor["gel"]["dome"], centre_px, estimator.image_shape, px)
            shape = estimator.image_shape
            labels = sphere_gradients(shape, centre_px, RADIUS, depth, px, None, dome)
            exact = integrate(labels[..., 0], labels[..., 1], px_per_mm=estimator.px_per_mm)
            found.append(
                {
                    "geometry": report(
                        "geometry", estimator.points_of_depth(exact, "printer"), ball
                    ),
                    "model": report("model", estimator.points(frame, "printer"), ball),
                }
            )
        figure(estimator, scene, *OFFSETS[2], out / "point_frames.png")
    return found


def figure(estimator, scene: dict, dx: float, dy: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frame, ball, centre_px, _, _ = bench_press(scene, dx, dy, 1.0)
    cloud = estimator.points(frame, "printer")
    height, width = estimator.image_shape
    fig = plt.figure(figsize=(13.5, 4.6), dpi=100)

    ax = fig.add_subplot(1, 3, 1)
    ax.imshow(frame)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    arrow = dict(width=1.5, head_width=7, length_includes_head=True)
    ax.arrow(cx, cy, 60, 0, color="white", **arrow)
    ax.arrow(cx, cy, 0, 60, color="white", **arrow)
    ax.text(cx + 62, cy + 4, "x", color="white", fontsize=12)
    ax.text(cx + 4, cy + 75, "y", color="white", fontsize=12)
    ax.text(cx - 6, cy - 8, "sensor origin", color="white", fontsize=8, ha="right")
    affine = estimator.geometry.registration.affine_px_per_mm
    for column, label in ((0, "printer +X"), (1, "printer +Y")):
        step = affine[:, column] / np.linalg.norm(affine[:, column]) * 45
        ax.arrow(*centre_px, *step, color="orange", **arrow)
        tip = np.asarray(centre_px) + step + (6, 0)
        ax.text(*tip, label, color="orange", fontsize=9, ha="left", va="center")
    ax.set_title("model frame: sensor axes (white),\nprinter axes at the press (orange)")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")

    ax = fig.add_subplot(1, 3, 2, projection="3d")
    grid = cloud.points.reshape(height, width, 3)
    contact = cloud.contact.reshape(height, width)
    sub = (slice(None, None, 6), slice(None, None, 6))
    ax.scatter(*grid[sub][~contact[sub]].T, s=1, c="0.6")
    ax.scatter(*grid[contact].T[:, ::4], s=1, c="tab:orange")
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    sphere = [ball[0] + RADIUS * np.cos(u) * np.sin(v), ball[1] + RADIUS * np.sin(u) * np.sin(v)]
    ax.plot_wireframe(*sphere, ball[2] + RADIUS * np.cos(v), color="tab:blue", lw=0.4)
    shown = np.vstack([grid[sub].reshape(-1, 3), [ball + [0, 0, RADIUS]]])
    ax.set_box_aspect(np.ptp(shown, axis=0))  # one mm is one mm along every axis
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_zlabel("Z (mm)")
    ax.set_title("points in the printer frame (G-code axes)\nand the printer's ball (blue)")

    ax = fig.add_subplot(1, 3, 3)
    row = int(round(centre_px[1]))
    section = grid[row]
    near = np.abs(section[:, 0] - ball[0]) < 3.0
    x = np.linspace(ball[0] - RADIUS, ball[0] + RADIUS, 200)
    ax.plot(x, ball[2] - np.sqrt(np.clip(RADIUS**2 - (x - ball[0]) ** 2 - (section[near, 1].mean() - ball[1]) ** 2, 0, None)), color="tab:blue", label="the printer's ball")  # fmt: skip
    ax.plot(section[near, 0], section[near, 2], ".", ms=3, color="tab:orange", label="points")
    ax.axhline(estimator.geometry.registration.contact_z_mm, color="0.5", lw=0.8, ls="--")
    ax.text(section[near, 0].min(), estimator.geometry.registration.contact_z_mm + 0.03,
            "first-touch height (contact_z_mm)", fontsize=8, color="0.4")  # fmt: skip
    ax.set_xlabel("printer X (mm)")
    ax.set_ylabel("printer Z (mm)")
    ax.set_title(f"section along image row {row}")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
