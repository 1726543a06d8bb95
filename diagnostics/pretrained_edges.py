"""The shipped weights on simulated units at the edges of the measured spread: depth only where
the ball is?

Units 7000-7005 (never pretrained on: those are 1000-1127) are drawn from the sensor profile with
every spread of its `unit_variation` doubled (threedcal.sim.units; the skin's range and the blank
drift as they are): units two sigma out. Each is pressed 8 times by a 2 mm ball, 0.3-1.5 mm deep,
anywhere in the frame (threedcal.dataset.unit_presses), and read with its own blank. Per press:
the contact (depth above 0.05 mm) against the ball's disc, its centroid against the press, the
false contact (pixels in contact more than 2 px outside the true contact disc), the peak depth
over the press depth, and the gradient MSE within 1.5 contact radii.

    .venv/bin/python -m diagnostics.pretrained_edges [--weights DIR] [--sensor S ...] [--smoke]

A few minutes per sensor on 2 cores; `--smoke`: one unit, two presses.
"""

from __future__ import annotations

import argparse
import copy
import math
from pathlib import Path

import numpy as np

from threedcal.dataset.labels import contact_radius_mm
from threedcal.dataset.unit_presses import simulate_units
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.contact_guard import contact_figures
from threedcal.model.inference import DepthEstimator
from threedcal.pretrained import shipped_weights
from threedcal.profiles import load_profile

UNITS = list(range(7000, 7006))
PRESSES, DEPTH_MM, RADIUS_MM = 8, (0.3, 1.5), 2.0
EDGE = 2.0  # each spread doubled
AS_THEY_ARE = ("skin_tension_range_n_per_mm", "blank_drift_dn", "source")


def edge_profile(profile: dict, factor: float = EDGE) -> dict:
    """The profile with every numeric spread of its unit_variation times `factor`."""
    edged = copy.deepcopy(dict(profile))
    spread = edged["unit_variation"]
    for key, value in spread.items():
        if key not in AS_THEY_ARE and isinstance(value, int | float):
            spread[key] = value * factor
    return edged


def press_rows(weights: Path, sensor: str, units: list[int], presses: int) -> np.ndarray:
    """Per press: area ratio, centroid error mm, false contact px, peak over depth, gradient MSE."""
    ts = simulate_units(
        edge_profile(load_profile("sensor", sensor)),
        units,
        presses,
        DEPTH_MM,
        RADIUS_MM,
        factor=2,
        gel_mechanics="elastic",
        val_units=0,
        progress=False,
    )
    checkpoint = read_checkpoint(weights)
    rows = []
    height, width = ts.image_shape
    yy, xx = np.mgrid[:height, :width]
    for i in range(len(ts.frames)):
        estimator = DepthEstimator(
            checkpoint, device="cpu", blank=ts.blank_of(i), px_per_mm=ts.px_per_mm
        )
        grads = estimator.gradients(ts.frames[i])
        depth = estimator.depth(ts.frames[i])
        figures = contact_figures(depth, RADIUS_MM, ts.px_per_mm)
        cx, cy = ts.center_px[i]
        a = contact_radius_mm(RADIUS_MM, float(ts.depth_mm[i])) * ts.px_per_mm
        r = np.hypot(xx - cx, yy - cy)
        false = int(((depth > 0.05) & (r > a + 2)).sum())
        disc = r <= 1.5 * max(a, 3.0)
        mse = float(((grads.transpose(2, 0, 1) - ts.labels(i)) ** 2).sum(0)[disc].mean() / 2)
        error = math.hypot(figures.centroid_x_px - cx, figures.centroid_y_px - cy) / ts.px_per_mm
        rows.append((figures.area_ratio, error, false, figures.peak_mm / ts.depth_mm[i], mse))
    return np.array(rows)


def summary(rows: np.ndarray) -> dict:
    ratio, error, false, peak, mse = rows.T
    return {
        "within_bound": float(np.mean(ratio <= 1)),
        "area_ratio_median": float(np.median(ratio)),
        "area_ratio_max": float(ratio.max()),
        "centroid_mm_median": float(np.nanmedian(error)),
        "centroid_mm_p90": float(np.nanpercentile(error, 90)),
        "false_px_median": float(np.median(false)),
        "peak_over_depth_median": float(np.median(peak)),
        "gradient_mse": float(mse.mean()),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", type=Path, help="a folder of {sensor}.pt (default: shipped)")
    parser.add_argument("--sensor", nargs="+", default=["digit_fots", "gelsight_mini"])
    parser.add_argument("--smoke", action="store_true", help="one unit, two presses")
    args = parser.parse_args(argv)
    units, presses = (UNITS[:1], 2) if args.smoke else (UNITS, PRESSES)
    out = {}
    for sensor in args.sensor:
        weights = shipped_weights(sensor, None, args.weights)
        out[sensor] = summary(press_rows(weights, sensor, units, presses))
        figures = ", ".join(f"{k} {v:.3g}" for k, v in out[sensor].items())
        print(f"{sensor} ({weights}), {len(units)} units x {presses} presses: {figures}")
    return out


if __name__ == "__main__":
    main()
