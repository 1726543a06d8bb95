"""The sensor and printer frames of DepthEstimator.points, and the bench's sphere round trip.

A DIGIT is calibrated on the simulated bench (2 mm grid of 1 mm presses, seed 3, as
tests/model/test_points.py), a `lookup` model is trained on it, and a 2 mm radius ball is pressed
1 mm deep at three printer positions. For each press it prints how far the sphere fitted to the
contact points lies from the printer's ball (X, Y; Z) and how far the points lie from that sphere:
once with the press's exact gradients (the geometry: integration, registration, touch height) and
once through the model. It draws docs/figures/point_frames.png: the model frame with both frames'
axes, the points in the printer frame, and a section through the press.

Usage: .venv/bin/python docs/diagnostics/point_frames.py [--figure PATH]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "tests" / "model"))

from conftest import collect_and_register, lens_free  # noqa: E402
from test_points import PLAN, RADIUS, SEED, bench_press, fit_sphere  # noqa: E402

from threedcal.dataset.labels import local_dome, sphere_gradients  # noqa: E402
from threedcal.dataset.trainset import TrainingSet  # noqa: E402
from threedcal.depth import integrate  # noqa: E402
from threedcal.model.inference import DepthEstimator  # noqa: E402
from threedcal.model.train import TrainSettings, train  # noqa: E402

OFFSETS = [(0.0, 0.0), (2.5, -3.0), (-3.3, 4.1)]


def report(name, cloud, ball):
    centre, residual = fit_sphere(cloud.points[cloud.contact])
    xy = np.hypot(*(centre - ball)[:2]) * 1000
    z = (centre - ball)[2] * 1000
    rms = np.sqrt(np.mean(residual**2)) * 1000
    print(
        f"  {name:<10} centre off by {xy:5.1f} um in X, Y and {z:+6.1f} um in Z; "
        f"points off the sphere {rms:5.1f} um RMS, {np.abs(residual).max() * 1000:5.1f} um max "
        f"({int(cloud.contact.sum())} contact points)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", default=str(REPO / "docs/figures/point_frames.png"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        collect_and_register(folder, lens_free("digit"), PLAN, SEED)
        settings = TrainSettings.of(preset="lookup", epochs_base=1, torch_threads=2)
        train(TrainingSet.load(folder / "ts"), folder / "model", 80, settings, progress=False)
        estimator = DepthEstimator.from_checkpoint(folder / "model" / "model.pt", device="cpu")
    for offset in OFFSETS:
        frame, ball, centre_px, depth, sensor = bench_press(*offset, 1.0)
        print(f"press at plan centre {offset[0]:+.1f}, {offset[1]:+.1f} mm, {depth:.3f} mm deep:")
        px = float(sensor["px_per_mm"])
        dome = local_dome(sensor["gel"]["dome"], centre_px, estimator.image_shape, px)
        labels = sphere_gradients(estimator.image_shape, centre_px, RADIUS, depth, px, None, dome)
        exact = integrate(labels[..., 0], labels[..., 1], px_per_mm=estimator.px_per_mm)
        report("geometry", estimator.points_of_depth(exact, "printer"), ball)
        report("model", estimator.points(frame, "printer"), ball)
    figure(estimator, *OFFSETS[2], Path(args.figure))


def figure(estimator, dx, dy, path: Path) -> None:
    frame, ball, centre_px, _, _ = bench_press(dx, dy, 1.0)
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
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
