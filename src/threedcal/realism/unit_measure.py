"""How real units of one sensor model differ, measured from their frames: what `unit_variation`
(threedcal.sim.units) is set from.

Per unit, from its blank (or the parts of a contact frame far from the contact and its markers):

- the smooth background field: a polynomial of `FIELD_DEGREE` per channel fitted by least squares
  (the simulator's `optics.background_field` basis), its level (mean) and its shape (rms about the
  level, DN);
- the brighter side: per channel, the direction (deg, image frame: 0 = +x, 90 = +y, down) of the
  field's best plane, where that channel's light is brightest;

and from its contacts (frame, blank, contact centre and radius):

- each channel's light direction: the direction in which that channel's change grows with the
  sphere's normal inside the contact (least squares on nx, ny, nz, 1), as the optics fit reads it;
- the halo: where the radial contact magnitude falls to 50 % and 10 % of its peak
  (threedcal.realism.check.halo_radii), over the ball's radius.

Between units, a spread (1 sigma of one unit about the model's mean) is what two units differ by
over √2: two independent draws about one mean differ by √2 sigma. Angles are differenced on the
circle. With more than two units the spread is the sample standard deviation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from threedcal.errors import ConfigError
from threedcal.realism.check import halo_radii
from threedcal.sim.background_field import field_terms

FIELD_DEGREE = 4


def _keep(shape: tuple[int, int], keep: np.ndarray | None) -> np.ndarray:
    if keep is None:
        return np.ones(shape, bool)
    keep = np.asarray(keep, bool)
    if keep.shape != shape:
        raise ConfigError(f"a keep mask of shape {keep.shape} for a {shape} image")
    if keep.sum() < 3 * (FIELD_DEGREE + 1) ** 2:
        raise ConfigError(f"{int(keep.sum())} pixels kept: too few to fit a smooth field")
    return keep


def away_from_markers(image: np.ndarray, darkness: float = 0.6, grow_px: int = 3) -> np.ndarray:
    """(H, W) bool: the pixels that are not a dark marker (luminance under `darkness` times its
    sigma-15 px surroundings) nor within `grow_px` of one."""

    lum = np.asarray(image, dtype=np.float32).mean(axis=2)
    dark = (lum < darkness * cv2.GaussianBlur(lum, (0, 0), 15)).astype(np.uint8)
    size = 2 * int(grow_px) + 1
    return ~cv2.dilate(dark, np.ones((size, size), np.uint8)).astype(bool)


def smooth_field(
    image: np.ndarray, keep: np.ndarray | None = None, degree: int = FIELD_DEGREE
) -> np.ndarray:
    """(H, W, C) float64: the image's polynomial field of `degree` per channel, fitted on the kept
    pixels (threedcal.sim.background_field.field_terms) and evaluated everywhere."""

    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3:
        raise ConfigError(f"a field is fitted to an (H, W, C) image, got shape {image.shape}")
    height, width = image.shape[:2]
    keep = _keep((height, width), keep)
    terms = np.stack([t.astype(np.float64) for t in field_terms(width, height, degree)])
    design = terms[:, keep].T
    coefficients, *_ = np.linalg.lstsq(design, image[keep], rcond=None)
    return np.einsum("khw,kc->hwc", terms, coefficients)


def field_level_and_shape(image, keep=None) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the smooth field's mean (DN) and its rms about that mean (DN), over kept pixels."""
    keep = _keep(np.shape(image)[:2], keep)
    field = smooth_field(image, keep)[keep]
    level = field.mean(axis=0)
    return level, np.sqrt(((field - level) ** 2).mean(axis=0))


def field_difference_dn(a, b, keep=None) -> np.ndarray:
    """Per channel rms (DN) of the difference between two units' smooth fields, each about its own
    level: how differently their backgrounds are shaped, brightness aside."""
    if np.shape(a) != np.shape(b):
        raise ConfigError(f"blanks of shapes {np.shape(a)} and {np.shape(b)}")
    keep = _keep(np.shape(a)[:2], keep)
    fa, fb = smooth_field(a, keep)[keep], smooth_field(b, keep)[keep]
    diff = (fa - fa.mean(axis=0)) - (fb - fb.mean(axis=0))
    return np.sqrt((diff**2).mean(axis=0))


def brighter_side_deg(image, keep=None) -> np.ndarray:
    """Per channel, the direction (deg, 0..360, image frame) in which the smooth field rises: the
    gradient of its least-squares plane over the kept pixels."""
    field = smooth_field(image, keep)
    height, width = field.shape[:2]
    keep = _keep((height, width), keep)
    rows, cols = np.nonzero(keep)
    design = np.c_[cols, rows, np.ones(rows.size)].astype(np.float64)
    slope, *_ = np.linalg.lstsq(design, field[keep], rcond=None)
    return np.degrees(np.arctan2(slope[1], slope[0])) % 360.0


def contact_light_deg(
    frames: Sequence[np.ndarray],
    blank: np.ndarray,
    centres: Sequence[tuple[float, float]],
    radius_px: float,
    disc: float = 0.8,
    valid: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """Per channel, the direction (deg, image frame) of that channel's light, from contacts: the
    change (frame − blank, less its median beyond two radii) fitted on the sphere's normal (nx, ny,
    nz, one offset per frame) inside `disc` radii of each centre; atan2 of the ny and nx terms.
    `valid`: per frame, the pixels that may take part (e.g. not a marker); by default all."""
    blank = np.asarray(blank, dtype=np.float64)
    if not (math.isfinite(radius_px) and radius_px > 0):
        raise ConfigError(f"the contact radius must be > 0 px, got {radius_px}")
    if len(frames) != len(centres) or not len(frames):
        raise ConfigError("give one centre per contact frame, and at least one frame")
    height, width = blank.shape[:2]
    yy, xx = np.mgrid[:height, :width].astype(np.float64)
    design, values = [], []
    for k, (frame, (cx, cy)) in enumerate(zip(frames, centres, strict=True)):
        change = np.asarray(frame, dtype=np.float64) - blank
        ok = np.ones((height, width), bool) if valid is None else np.asarray(valid[k], bool)
        nx, ny = (xx - cx) / radius_px, (yy - cy) / radius_px
        r2 = nx * nx + ny * ny
        change = change - np.median(change[(r2 > 4.0) & ok], axis=0)
        inside = (r2 < disc * disc) & ok
        offsets = np.zeros((int(inside.sum()), len(frames)))
        offsets[:, k] = 1.0
        nz = np.sqrt(np.clip(1.0 - r2[inside], 0.0, 1.0))
        design.append(np.c_[nx[inside], ny[inside], nz, offsets])
        values.append(change[inside])
    coefficients, *_ = np.linalg.lstsq(np.concatenate(design), np.concatenate(values), rcond=None)
    return np.degrees(np.arctan2(coefficients[1], coefficients[0])) % 360.0


def halo_over_radius(frame, blank, centre, ball_radius_px: float) -> tuple[float, float]:
    """(r50, r10) / ball radius: where the contact's radial magnitude falls to 50 % and 10 % of
    its peak (threedcal.realism.check.halo_radii), in ball radii."""

    r50, r10 = halo_radii(
        np.asarray(frame, np.float32), np.asarray(blank, np.float32), centre, ball_radius_px
    )
    return r50 / ball_radius_px, r10 / ball_radius_px


def angle_difference_deg(a, b) -> np.ndarray:
    """a − b on the circle, in (−180, 180]."""
    d = (np.asarray(a, float) - np.asarray(b, float) + 180.0) % 360.0 - 180.0
    return np.where(d == -180.0, 180.0, d)


def spread(values: Sequence, angular: bool = False) -> np.ndarray:
    """One unit's spread (1 sigma) about the model's mean, from one figure of several units (rows):
    the sample standard deviation, angles about their circular mean. Two units: |a − b| / √2."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[0] < 2:
        raise ConfigError("a spread between units needs at least two units")
    if angular:
        rad = np.radians(values)
        mean = np.degrees(np.arctan2(np.sin(rad).mean(axis=0), np.cos(rad).mean(axis=0)))
        values = angle_difference_deg(values, mean)
    return values.std(axis=0, ddof=1)
