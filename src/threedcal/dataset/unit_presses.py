"""Simulated ball presses on many units of one sensor, labelled exactly: what pretraining learns from.

Each unit (threedcal.sim.units) is rendered as the bench renders it — its gel and lights, seen
through its own lens (drawn as the bench draws it) — and its frames are then rectified through
that lens and pooled to the working resolution, as the dataset stage prepares a calibration's
frames. Presses fall uniformly over the whole frame (contacts may leave it at the edges) at depths
uniform in `depth_mm`, measured below the undeformed gel under the ball (on a domed gel, the
dome's), as the labels are. The result is one TrainingSet whose frames know their unit's blank.

A real frame is never lit quite as its blank was (the blank is taken before or after, and the
LEDs and exposure drift): each press gets a smooth field of the profile's
`unit_variation.blank_drift_dn` rms added after rendering (threedcal.sim.units'
smooth field, degree DRIFT_DEGREE), which the blank does not have.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.dataset.labels import check_max_slope, contact_radius_mm
from threedcal.dataset.trainset import TrainingSet, downscale, samples_table
from threedcal.errors import ConfigError
from threedcal.profiles import with_gel_mechanics
from threedcal.sim.background_field import background_field
from threedcal.sim.bench import draw_lens
from threedcal.sim.camera import make_gel
from threedcal.sim.indenters import Sphere
from threedcal.sim.units import draw_unit, smooth_field_coefficients

# Blank frames averaged per unit (a calibration averages the profile's probing.n_blank).
BLANK_FRAMES = 10
# A frame's drift from its blank is smoother than a unit's field: degree 2 (the real frames' drift,
# measured beside their blanks, is a tilt and a bowl: docs/explanation/simulator.md).
DRIFT_DEGREE = 2
_DRIFT_STREAM = 0xD21F


def simulate_units(
    profile: Mapping,
    units: Sequence[int],
    presses_per_unit: int,
    depth_mm: tuple[float, float],
    probe_radius_mm: float,
    factor: int = 1,
    gel_mechanics: str | None = None,
    val_units: int = 1,
    progress: bool = True,
) -> TrainingSet:
    """Presses of every unit in `units` (the last `val_units` of them split 'val'), pooled by
    `factor`; blank per unit (TrainingSet.unit_blanks)."""
    lo, hi = (float(v) for v in depth_mm)
    if not 0 < lo <= hi <= probe_radius_mm:
        raise ConfigError(
            f"pretraining depth_mm: [{lo}, {hi}] must lie within (0, {probe_radius_mm}] "
            "(the probe's radius)"
        )
    if presses_per_unit < 1 or len(units) < 1:
        raise ConfigError("pretraining needs at least one unit and one press per unit")
    if not 0 <= val_units < len(units):
        raise ConfigError(f"val_units must lie in 0..{len(units) - 1}, got {val_units}")
    pooled = [
        downscale(
            _unit_set(profile, int(u), presses_per_unit, (lo, hi), probe_radius_mm, gel_mechanics),
            int(factor),
        )
        for u in tqdm(units, desc="simulate units", unit="unit", disable=not progress)
    ]
    unit_index = np.repeat(np.arange(len(units)), presses_per_unit)
    split = np.where(unit_index >= len(units) - val_units, "val", "train")
    samples = pd.concat([ts.samples for ts in pooled], ignore_index=True)
    samples = samples.assign(
        frame=np.arange(len(samples)),
        point=np.arange(len(samples)),
        split=split,
        min_p=np.where(split == "train", 80, 0),
        unit=unit_index,
    )
    return TrainingSet(
        frames=np.concatenate([ts.frames for ts in pooled]),
        blank=pooled[0].blank,
        samples=samples,
        px_per_mm=pooled[0].px_per_mm,
        sphere_radius_mm=float(probe_radius_mm),
        max_slope_deg=check_max_slope(None),
        meta={
            "source": f"simulated presses of {len(units)} units of {profile.get('name')}",
            "sensor": profile.get("name"),
            "units": [int(u) for u in units],
            "dome": profile["gel"].get("dome"),
            "downscale": int(factor),
        },
        unit_blanks=np.stack([ts.blank for ts in pooled]),
    )


def _unit_set(profile, unit, n, depth_mm, radius_mm, gel_mechanics) -> TrainingSet:
    """One unit's presses at full resolution, rectified through its own lens."""

    sensor = draw_unit(with_gel_mechanics(profile, gel_mechanics), unit)
    lens = draw_lens(profile, unit)
    gel = make_gel(sensor, seed=unit, lens=lens)
    width, height = int(profile["image"]["width_px"]), int(profile["image"]["height_px"])
    px_per_mm = float(profile["px_per_mm"])
    rng = np.random.default_rng([unit, 0x9E55])
    centres = rng.uniform([0.0, 0.0], [width - 1.0, height - 1.0], (n, 2))
    depths = rng.uniform(*depth_mm, n)
    ball = Sphere(radius_mm)
    frames = np.stack(
        [
            gel.render(ball, tuple(c), 0.0, float(d), frame_index=i + 1)
            for i, (c, d) in enumerate(zip(centres, depths, strict=True))
        ]
    )
    drift_dn = float((profile.get("unit_variation") or {}).get("blank_drift_dn", 0) or 0)
    if drift_dn > 0:
        frames = drifted_frames(frames, drift_dn, unit)
    blanks = [gel.blank(frame_index=n + 1 + k).astype(np.float32) for k in range(BLANK_FRAMES)]
    blank = np.mean(blanks, axis=0)
    if lens is not None:
        frames, blank = lens.rectify(frames), lens.rectify(blank[None])[0]
    samples = samples_table(
        np.arange(n),
        centres,
        depths,
        [contact_radius_mm(radius_mm, float(d)) * px_per_mm for d in depths],
        np.full(n, "train"),
        np.full(n, 80),
    )
    return TrainingSet(
        frames=frames,
        blank=blank.astype(np.float32),
        samples=samples,
        px_per_mm=px_per_mm,
        sphere_radius_mm=float(radius_mm),
        max_slope_deg=check_max_slope(None),
    )


def drifted_frames(frames: np.ndarray, rms_dn: float, unit: int) -> np.ndarray:
    """Unit `unit`'s uint8 frames (N, H, W, 3), each plus its own smooth field (degree
    DRIFT_DEGREE) of `rms_dn` expected rms, rounded and clipped; seeded by the unit."""

    rng = np.random.default_rng([int(unit), _DRIFT_STREAM])
    height, width = frames.shape[1:3]
    out = np.empty_like(frames)
    for k, frame in enumerate(frames):
        coefficients = smooth_field_coefficients(rng, rms_dn, DRIFT_DEGREE)
        field = background_field(width, height, DRIFT_DEGREE, coefficients)
        out[k] = np.clip(np.rint(frame.astype(np.float32) + field), 0, 255).astype(np.uint8)
    return out
