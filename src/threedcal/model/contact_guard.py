"""Does a depth map show only what the probe can make? Its contact against the ball's bound.

A ball of radius R touches at most a disc of radius R, whatever the press: πR² in the model's
pixels is the physical bound of any contact it makes. A model whose contact mask (depth above
threedcal.model.CONTACT_DEPTH_MM) covers more than that reads something else as depth — most
often the unit's own lighting (its halo, its brighter side) that the weights never learnt, or a
blank taken under other light. Wherever the probe's radius is known (calibration presses, the
quick loop's rounds, `threedcal live --probe-radius-mm`) the figure is computed and a model over
the bound is named with its fix: calibrate this unit, or retake the blank.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.model import CONTACT_DEPTH_MM
from threedcal.model.inference import DepthEstimator


@dataclass(frozen=True)
class ContactFigures:
    """One depth map's contact: mask area (px), the probe's bound (px), the mask's centroid (px;
    NaN without contact) and the deepest depth (mm)."""

    area_px: int
    bound_px: float
    centroid_x_px: float
    centroid_y_px: float
    peak_mm: float

    @property
    def area_ratio(self) -> float:
        """Contact area over the probe's bound: above 1, more than the probe can touch."""
        return self.area_px / self.bound_px


def probe_bound_px(probe_radius_mm: float, px_per_mm: float) -> float:
    """πR² in pixels: the largest contact a ball of `probe_radius_mm` can make."""
    for name, value in (("probe radius (mm)", probe_radius_mm), ("px/mm", px_per_mm)):
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"the contact bound needs a {name} > 0, got {value!r}")
    return math.pi * (probe_radius_mm * px_per_mm) ** 2


def contact_figures(
    depth_mm: np.ndarray,
    probe_radius_mm: float,
    px_per_mm: float,
    threshold_mm: float = CONTACT_DEPTH_MM,
) -> ContactFigures:
    """The contact of one (H, W) depth map (mm, positive into the gel; NaN: no reading)."""
    depth = np.asarray(depth_mm, dtype=np.float64)
    if depth.ndim != 2:
        raise ConfigError(f"contact figures take one (H, W) depth map, got shape {depth.shape}")
    if not (math.isfinite(threshold_mm) and threshold_mm >= 0):
        raise ConfigError(f"the contact threshold must be a number >= 0 mm, got {threshold_mm}")
    bound = probe_bound_px(probe_radius_mm, px_per_mm)
    with np.errstate(invalid="ignore"):
        mask = depth > threshold_mm
    rows, cols = np.nonzero(mask)
    finite = np.isfinite(depth)
    return ContactFigures(
        area_px=int(rows.size),
        bound_px=bound,
        centroid_x_px=float(cols.mean()) if rows.size else math.nan,
        centroid_y_px=float(rows.mean()) if rows.size else math.nan,
        peak_mm=float(depth[finite].max()) if finite.any() else math.nan,
    )


def median_press(figures: list[ContactFigures]) -> ContactFigures:
    """The press in the middle by contact area (of two middles, the larger): over the bound
    whenever the median area ratio is."""
    return sorted(figures, key=lambda f: f.area_ratio)[len(figures) // 2]


def oversized_message(unit: str, figures: ContactFigures, probe_radius_mm: float) -> str | None:
    """The warning for a contact larger than the probe can make, or None within the bound."""
    if figures.area_px <= figures.bound_px:
        return None
    return (
        f"{unit}: the model's contact covers {figures.area_px} px, {figures.area_ratio:.2f} times "
        f"the most a {probe_radius_mm:g} mm probe can touch ({figures.bound_px:.0f} px): it reads "
        "this unit's lighting as depth. Calibrate this unit (a calibration or quick calibration "
        "from its own presses), or retake the blank with nothing touching the gel"
    )


def warn_if_oversized(unit: str, figures: ContactFigures, probe_radius_mm: float) -> str | None:
    """Log `oversized_message` as a warning of the `threedcal` logger; returns it (or None)."""
    message = oversized_message(unit, figures, probe_radius_mm)
    if message:
        logging.getLogger("threedcal").warning("%s", message)
    return message


def check_calibration_presses(model_path, trainset, unit: str, limit: int = 8) -> float:
    """A trained model on up to `limit` of its calibration's validation presses (evenly spread;
    the training ones where it has none): the median contact area over the probe's disc, and a
    warning when the median press reads more than the probe can touch. NaN without presses."""
    if not isinstance(trainset, TrainingSet):
        trainset = TrainingSet.load(trainset)
    chosen = trainset.indices("val")
    if not chosen.size:
        chosen = trainset.indices("train")
    if not chosen.size or limit < 1:
        return math.nan
    spread = np.unique(np.linspace(0, chosen.size - 1, min(limit, chosen.size)).round())
    chosen = chosen[spread.astype(int)]
    estimator = DepthEstimator.from_checkpoint(model_path, device="cpu")
    radius = float(trainset.sphere_radius_mm)
    depth = estimator.depth(np.asarray(trainset.frames)[chosen])
    figures = [contact_figures(d, radius, trainset.px_per_mm) for d in depth]
    ratios = [f.area_ratio for f in figures]
    warn_if_oversized(unit, median_press(figures), radius)
    return float(np.median(ratios))
