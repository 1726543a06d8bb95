"""Sim-to-real's simulated probing: the sensor profile's optics fitted to a group's training frames
(or used as they are), and seeded presses of the real set's ball rendered with them and labelled
exactly. No training here: the simulate job loads no network library."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.dataset.folds import contact_radius_px, read_folds
from threedcal.dataset.labels import check_max_slope, contact_radius_mm
from threedcal.dataset.trainset import TrainingSet, samples_table
from threedcal.errors import ConfigError
from threedcal.evaluate.sim2real_settings import (
    EVAL_SHRINK,
    SimToRealSettings,
    group_name,
)
from threedcal.realism.check import BallLabel
from threedcal.realism.fit import fit_optics
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator


def simulate_trainset(
    real: TrainingSet, profile: Mapping, settings: SimToRealSettings, seed: int, progress=True
) -> TrainingSet:
    """Simulated presses of the real set's ball at its image size and px/mm, labelled exactly.

    Centres are uniform over the positions that keep the whole contact circle inside the image;
    depths uniform in `depth_mm`. The last tenth of the frames (at least one) is split 'val'.
    """

    height, width = real.image_shape
    radius = real.sphere_radius_mm
    lo, hi = settings.depth_mm
    if hi > radius:
        raise ConfigError(
            f"sim_to_real.depth_mm: {hi} mm is deeper than the ball's radius {radius} mm"
        )
    reach = contact_radius_mm(radius, hi) * real.px_per_mm + 1.0
    if 2 * reach >= min(height, width):
        raise ConfigError(
            f"sim_to_real.depth_mm: a {hi} mm press of the {radius} mm ball is "
            f"{2 * reach:.0f} px across, too wide for the {width} x {height} px images"
        )
    sim = GelSimulator(profile, seed, image_size=(width, height), px_per_mm=real.px_per_mm)
    rng = np.random.default_rng([seed, 0x51A2])
    n = settings.frames
    centres = rng.uniform([reach, reach], [width - 1 - reach, height - 1 - reach], (n, 2))
    depths = rng.uniform(lo, hi, n)
    ball = Sphere(radius)
    frames = np.empty((n, height, width, 3), dtype=np.uint8)
    for i in tqdm(range(n), desc="simulate presses", unit="frame", disable=not progress):
        frames[i] = sim.render(ball, tuple(centres[i]), 0.0, float(depths[i]), frame_index=i + 1)
    contact = np.array([contact_radius_mm(radius, float(d)) for d in depths]) * real.px_per_mm
    n_val = max(1, n // 10)
    split = np.where(np.arange(n) < n - n_val, "train", "val")
    samples = samples_table(
        np.arange(n),
        centres,
        depths,
        EVAL_SHRINK * contact,
        split,
        np.where(split == "train", 80, 0),
    )
    return TrainingSet(
        frames=frames,
        blank=sim.blank(0).astype(np.float32),
        samples=samples,
        px_per_mm=real.px_per_mm,
        sphere_radius_mm=radius,
        max_slope_deg=check_max_slope(real.max_slope_deg),
        meta={"source": f"simulated {profile.get('name')} presses", "seed": seed},
    )


# Fewest training images a fold's optics are fitted to: with fewer, the LED levels and the shading
# shape are not determined. (Enough for a gain is more: docs/explanation/real-data.md, 8 images give none.)
MIN_FIT_IMAGES = 3


@dataclass(frozen=True)
class _SetImages:
    """A model-ready set seen as the ball folder threedcal.realism.fit reads: frames by name, its
    blank as background.png. Works for every import format, and takes the set's own (possibly
    refined) contact circles."""

    ts: TrainingSet
    root: str
    names: tuple[str, ...]

    @property
    def px_per_mm(self) -> float:
        return self.ts.px_per_mm

    @property
    def ball_radius_mm(self) -> float:
        return self.ts.sphere_radius_mm

    @property
    def height_px(self) -> int:
        return self.ts.image_shape[0]

    @property
    def width_px(self) -> int:
        return self.ts.image_shape[1]

    def read(self, name: str) -> np.ndarray:
        if name == "background.png":
            return self.ts.blank
        return self.ts.frames[self.names.index(name)]


def fold_profile(
    profile: Mapping, ts: TrainingSet, folds: pd.DataFrame, held_out: Sequence[int], where: str
):
    """`profile` with its optics fitted to the frames outside the `held_out` folds and the set's
    blank: the simulator then never sees a test image of those folds."""
    held_out = sorted(int(f) for f in held_out)
    frames = folds.loc[~folds["fold"].isin(held_out), "frame"].to_numpy()
    if len(frames) < MIN_FIT_IMAGES:
        named = f"fold {held_out[0]}" if len(held_out) == 1 else f"folds {group_name(held_out)}"
        raise ConfigError(
            f"{where}: {len(frames)} training images lie outside {named}; fitting the optics "
            f"(sim_to_real.profile: fitted) needs at least {MIN_FIT_IMAGES} — add images, "
            "lower cv.folds, evaluate fewer sim_to_real.folds, or set profile: as_is"
        )
    return fitted_to_frames(profile, ts, frames, where)


def fitted_to_frames(profile: Mapping, ts: TrainingSet, frames: Sequence[int], where: str):
    """`profile` with its optics fitted (threedcal.realism.fit.fit_optics) to these frames of the
    model-ready set, with their contact circles, and its blank."""
    names = tuple(f"frame{i:05d}" for i in range(len(ts.frames)))
    radius = contact_radius_px(ts)
    labels = [
        BallLabel(
            names[i], (float(ts.center_px[i, 0]), float(ts.center_px[i, 1])), float(radius[i])
        )
        for i in frames
    ]
    return fit_optics(profile, _SetImages(ts, where, names), labels)


def write_simulated(
    real_dir: str | Path,
    profile: Mapping,
    sim_to_real: Mapping,
    seed: int,
    out_dir: str | Path,
    progress: bool = True,
    *,
    folds_path: str | Path | None = None,
    held_out: Sequence[int] | None = None,
) -> TrainingSet:
    """The simulated set of a group of test folds (`held_out`, :func:`pretraining_groups`) in
    `out_dir`; with `profile: fitted` also the fitted profile (profile.yaml, headed by the frames
    it was fitted on: frameNNNNN, the set's frame numbers, none of a held-out fold)."""
    settings = SimToRealSettings.of(**sim_to_real)
    real = TrainingSet.load(real_dir)
    fit = None
    if settings.profile == "fitted":
        if folds_path is None or not held_out:
            raise ConfigError(
                "sim_to_real.profile: fitted needs the scene's folds and the folds held out"
            )
        folds = read_folds(folds_path, real)
        fit = fold_profile(profile, real, folds, held_out, str(real_dir))
        profile = fit.profile
    ts = simulate_trainset(real, profile, settings, seed, progress)
    ts.save(out_dir)
    if fit is not None:
        fit.write_profile(Path(out_dir) / "profile.yaml")
    return ts
