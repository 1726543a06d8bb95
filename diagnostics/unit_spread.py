"""How the real units in data/ differ: the figures the sensor profiles' `unit_variation` is set from.

Per unit (threedcal.realism.unit_measure): the blank's smooth field (level and shape, DN), its brighter
side per channel (deg, image frame), and where the unit has labelled or locatable contacts, on the
fitting half of its frames only (threedcal.realism.folder.split_halves, seed 0: the half the check never
scores): each light's direction, the halo (r50 and r10 over the ball's radius) and how far its
frames drift from its blank (smooth part, away from the contact). Then, per sensor model, what
its two units differ by and the spread of one unit (the difference over √2).

Mini frames are compared in the Mini profile's landscape frame: gelsight_ball_fots's portrait
frames are read turned a quarter counter-clockwise, as every reader of that folder reads them.

    .venv/bin/python -m diagnostics.unit_spread [--smoke]

Seconds; `--smoke` uses four contact frames per folder.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from threedcal.images import read_rgb
from threedcal.realism import unit_measure as um
from threedcal.realism.check import load_ball_dataset
from threedcal.realism.folder import split_halves

DATA = Path(__file__).resolve().parents[1] / "data"
MARKER_CONTACT_REACH_PX = 100  # the marker frames' contact and its colour, left out of their field


def contact_unit(folder: Path, orientation: str, frames: int | None) -> dict:
    """Blank and contact figures of a ball folder's unit (fitting half only), in the sensor
    profile's `orientation`."""
    data = load_ball_dataset(folder, orientation)
    blank = data.read("background.png").astype(np.float64)
    fit, _ = split_halves(data.labels, 0)
    fit = fit[:frames] if frames else fit
    ball = data.ball_radius_mm * data.px_per_mm
    images = [data.read(label.image).astype(np.float64) for label in fit]
    centres = [label.center_px for label in fit]
    radius = 0.9 * float(np.median([label.radius_px for label in fit]))
    halos = [um.halo_over_radius(f, blank, c, ball) for f, c in zip(images, centres, strict=True)]
    drift = []
    for f, (cx, cy) in zip(images, centres, strict=True):
        yy, xx = np.mgrid[: blank.shape[0], : blank.shape[1]]
        far = np.hypot(xx - cx, yy - cy) > 3 * ball
        diff = f - blank
        diff = diff - np.median(diff[far], axis=0)
        smooth = um.smooth_field(diff, far, degree=2)
        drift.append(np.sqrt((smooth[far] ** 2).mean(axis=0)))
    level, shape = um.field_level_and_shape(blank)
    return {
        "blank": blank,
        "keep": None,
        "level": level,
        "shape": shape,
        "side": um.brighter_side_deg(blank),
        "light": um.contact_light_deg(images, blank, centres, radius),
        "halo": np.nanmedian(halos, axis=0),
        "drift": np.median(drift, axis=0),
        "frames": len(images),
    }


def blank_unit(path: Path) -> dict:
    """Blank figures of a unit with a blank only."""
    blank = read_rgb(path).astype(np.float64)
    level, shape = um.field_level_and_shape(blank)
    side = um.brighter_side_deg(blank)
    return {"blank": blank, "keep": None, "level": level, "shape": shape, "side": side}


def marker_unit(path: Path) -> dict:
    """Blank figures of a marker-gel frame: its field away from the markers and the contact."""
    image = read_rgb(path).astype(np.float64)
    keep = um.away_from_markers(image)
    height, width = keep.shape
    departure = np.where(keep, np.abs(image - um.smooth_field(image, keep)).sum(axis=2), 0.0)
    cy, cx = np.unravel_index(int(np.argmax(_blurred(departure))), departure.shape)
    yy, xx = np.mgrid[:height, :width]
    keep &= np.hypot(xx - cx, yy - cy) > MARKER_CONTACT_REACH_PX
    level, shape = um.field_level_and_shape(image, keep)
    side = um.brighter_side_deg(image, keep)
    return {"blank": image, "keep": keep, "level": level, "shape": shape, "side": side}


def _blurred(image: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), 6)


def pair(a: dict, b: dict) -> dict:
    """What two units differ by, and one unit's spread (the difference over √2)."""
    keep = a["keep"] if a["keep"] is not None else b["keep"]
    field = um.field_difference_dn(a["blank"], b["blank"], keep)
    side = np.abs(um.angle_difference_deg(a["side"], b["side"]))
    log_ratio = np.log(a["level"] / b["level"])
    colour = log_ratio - log_ratio.mean()
    root2 = math.sqrt(2)
    return {
        "field_dn": field,
        "side_deg": side,
        "level": float(abs(log_ratio.mean())),
        "colour_rms": float(np.sqrt(np.mean(colour**2))),
        "spread_field_dn": float(np.sqrt(np.mean((field / root2) ** 2))),
        "spread_azimuth_deg": float(np.sqrt(np.mean((side / root2) ** 2))),
        "spread_gain": float(abs(log_ratio.mean()) / root2),
        # three channels less their mean: a unit's per-channel sigma s gives 2 s^2 (2/3)
        "spread_colour": float(np.sqrt(np.mean(colour**2)) / math.sqrt(4 / 3)),
    }


def _fmt(values, digits: int = 1) -> str:
    return "/".join(f"{v:.{digits}f}" for v in np.atleast_1d(values))


def main(argv: list[str] | None = None) -> dict:
    """Print each unit's figures and each model's spreads; returns {model: pair(...)}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="four contact frames per folder")
    args = parser.parse_args(argv)
    frames = 4 if args.smoke else None
    models = {
        "DIGIT": (
            (
                "D20368 (digit_frames_fots)",
                contact_unit(DATA / "digit_frames_fots", "portrait", frames),
            ),
            ("TACTO (digit_blank_tacto)", blank_unit(DATA / "digit_blank_tacto/background.jpg")),
        ),
        "Mini": (
            (
                "gelsight_ball_fots, turned",
                contact_unit(DATA / "gelsight_ball_fots", "landscape", frames),
            ),
            ("mini_markers_fots", marker_unit(DATA / "mini_markers_fots/0000.png")),
        ),
    }
    spreads = {}
    for model, units in models.items():
        print(f"== {model}")
        for name, unit in units:
            line = (
                f"{name}: level {_fmt(unit['level'])} DN, field rms {_fmt(unit['shape'])} DN, "
                f"brighter side {_fmt(unit['side'], 0)} deg"
            )
            if "light" in unit:
                line += (
                    f"; lights {_fmt(unit['light'], 0)} deg, halo r50/r10 {_fmt(unit['halo'], 2)} "
                    f"ball radii, drift {_fmt(unit['drift'])} DN ({unit['frames']} fitting frames)"
                )
            print(line)
        figures = spreads[model] = pair(units[0][1], units[1][1])
        print(
            f"differ by: field {_fmt(figures['field_dn'])} DN rms, brighter side "
            f"{_fmt(figures['side_deg'], 0)} deg, level {100 * figures['level']:.1f} %, colour "
            f"{100 * figures['colour_rms']:.1f} % rms"
        )
        print(
            f"one unit's spread: background_field_dn {figures['spread_field_dn']:.1f}, "
            f"light_azimuth_deg {figures['spread_azimuth_deg']:.1f}, light_gain "
            f"{figures['spread_gain']:.3f}, light_colour {figures['spread_colour']:.3f}"
        )
    return spreads


if __name__ == "__main__":
    main()
