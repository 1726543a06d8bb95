"""Integrate perfect labels of a pressed ball and compare with the true depth (the labels
explanation: why labels are clamped at `dataset.max_slope_deg`).

    .venv/bin/python -m diagnostics.label_integration [--out DIR] [--smoke]

For the ball of the probe (R = 2 mm) at the DIGIT's and the GelSight Mini's scale, pressed 1.0 mm
(the calibration press), 2.0 mm (d = R) and 3.0 mm (d > R: a 1 mm vertical rim), the exact labels
(threedcal.dataset.labels.sphere_gradients, each pixel's mean slope) are integrated with
poisson_dst (no slope clamp) and compared with each pixel's true mean depth; then the same for
labels clamped at 45 and 75 degrees (the option `dataset.max_slope_deg`). Also: how much of the
labels' squared magnitude (what a mean-squared-error loss weighs) lies in pixels steeper than 75°.
The table is printed and written to DIR/label_integration.csv when `--out` is given. Seconds;
`--smoke`: the DIGIT's scale alone, each pixel's true depth from 4 x 4 samples, not 16 x 16.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.labels import contact_radius_mm, sphere_depth, sphere_gradients
from threedcal.depth import poisson_dst

RADIUS_MM = 2.0
SHAPE = (130, 120)
CENTRE = (60.3, 64.6)
SCALES = (("digit", 19.5), ("gelsight_mini", 15.77))  # px/mm


def pixel_mean_depth(px_per_mm: float, depth_mm: float, n: int = 16) -> np.ndarray:
    total = np.zeros(SHAPE)
    for sy in (np.arange(n) + 0.5) / n - 0.5:
        for sx in (np.arange(n) + 0.5) / n - 0.5:
            centre = (CENTRE[0] - sx, CENTRE[1] - sy)
            total += sphere_depth(SHAPE, centre, RADIUS_MM, depth_mm, px_per_mm)
    return total / (n * n)


def main(argv: list[str] | None = None) -> pd.DataFrame:
    """Print (and with --out write) the table: one row per sensor scale, depth and labels."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="folder for label_integration.csv")
    parser.add_argument("--smoke", action="store_true", help="the DIGIT alone, 4 x 4 samples")
    args = parser.parse_args(argv)
    scales = SCALES[:1] if args.smoke else SCALES
    samples = 4 if args.smoke else 16
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    r_px = np.hypot(cols - CENTRE[0], rows - CENTRE[1])
    print(
        "sensor scale     d mm  labels   centre err um  volume err %  max err um  "
        "beyond 3 px of rim um  max slope deg  share of g² above 75°"
    )
    table = []
    for name, ppm in scales:
        for depth in (1.0, 2.0, 3.0):
            truth = pixel_mean_depth(ppm, depth, samples)
            peak = np.unravel_index(np.argmax(truth), SHAPE)
            away = np.abs(r_px - contact_radius_mm(RADIUS_MM, depth) * ppm) > 3
            for clamp in (None, 45.0, 75.0):
                g = sphere_gradients(SHAPE, CENTRE, RADIUS_MM, depth, ppm, max_slope_deg=clamp)
                z = poisson_dst(g[..., 0], g[..., 1], px_per_mm=ppm, max_angle_deg=None)
                error = np.abs(z - truth)
                magnitude2 = (g.astype(np.float64) ** 2).sum(axis=-1)
                steep = magnitude2 > np.tan(np.radians(75.0)) ** 2
                row = {
                    "sensor_scale": name,
                    "depth_mm": depth,
                    "labels": "exact" if clamp is None else f"{clamp:.0f}deg",
                    "centre_error_um": (z[peak] - truth[peak]) * 1000,
                    "volume_error_pct": (z.sum() - truth.sum()) / truth.sum() * 100,
                    "max_error_um": error.max() * 1000,
                    "max_error_off_rim_um": error[away].max() * 1000,
                    "max_slope_deg": np.degrees(np.arctan(np.sqrt(magnitude2.max()))),
                    "share_above_75deg": magnitude2[steep].sum() / magnitude2.sum(),
                }
                table.append(row)
                print(
                    f"{name:14s} {depth:5.1f}  {'exact' if clamp is None else f'{clamp:.0f}°':7s}"
                    f"{row['centre_error_um']:+14.2f}{row['volume_error_pct']:+14.3f}"
                    f"{row['max_error_um']:12.1f}{row['max_error_off_rim_um']:23.1f}"
                    f"{row['max_slope_deg']:15.1f}{row['share_above_75deg']:22.2f}"
                )
    frame = pd.DataFrame(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        frame.to_csv(args.out / "label_integration.csv", index=False)
        print(f"wrote {args.out / 'label_integration.csv'}")
    return frame


if __name__ == "__main__":
    main()
