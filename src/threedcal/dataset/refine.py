"""Contact labels refined from the images: hand-drawn circles are noisy, a ball's imprint is round.

Hand-drawn contact circles disagree by several pixels between presses that left the same image (on
data/gelsight_ball_fots: radii 36, 41, 43, 45 px for four presses 1-8 px apart whose colour
profiles coincide), and 1 px of radius is 75-250 µm of cap depth. The refinement uses only the
frame, the blank and the labels' own average:

1. colour change: |frame - blank - per-channel median| (the median removes lighting drift, as the
   model inputs do), smoothed with a Gaussian of 1.5 px;
2. centre: the point about which that field is most nearly radially symmetric (least variance left
   within 0.5 px rings), searched within ``search_px`` of the labelled centre on a 1 px grid, then
   on a 0.25 px grid;
3. radius: each image's ring profile is taken as a stretched copy of the common profile, p_i(r) =
   g_i · P(r / s_i); the stretches s_i (mean 1) are fitted by alternating with P, and the radius is
   s_i times the mean labelled radius — the images give the relative sizes, the hand labels only
   their common level (whose noise averages out over all images).

Tested on simulated frames (tests/dataset/test_refine.py): centre within 0.5 px, radius within 0.5 px of the
rendered ball's where hand labels scatter by 2.5 px. Depth follows the radius (a = sqrt(2Rd - d²)).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage, optimize

from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError

RING_PX = 0.5
SEARCH_PX = 8.0
# Rings used: centre symmetry out to CENTRE_REACH, stretch fit between FIT_RANGE (times the median
# labelled contact radius); stretches outside STRETCH_BOUNDS mean the image is not a ball imprint.
CENTRE_REACH = 1.5
PROFILE_REACH = 1.8
FIT_RANGE = (0.25, 1.35)
STRETCH_BOUNDS = (0.7, 1.3)
# A ball imprint's colour change is mostly radially symmetric about its centre (real GelSight frames:
# at most 61 % of its variance is left within rings, 44 % typically; a blank frame: 100 %).
MAX_ASYMMETRY = 0.8


def imprint_magnitude(frame: np.ndarray, blank: np.ndarray) -> np.ndarray:
    """(H, W) float32 magnitude of the drift-corrected colour change, smoothed (sigma 1.5 px)."""
    diff = np.asarray(frame, dtype=np.float32) - np.asarray(blank, dtype=np.float32)
    diff -= np.median(diff[::4, ::4].reshape(-1, 3), axis=0)
    return ndimage.gaussian_filter(np.linalg.norm(diff, axis=2), 1.5)


def ring_profile(field: np.ndarray, cx: float, cy: float, reach: float) -> tuple[np.ndarray, float]:
    """(mean of `field` in 0.5 px rings about (cx, cy) out to `reach`, share of variance left in rings)."""
    height, width = field.shape
    x0, x1 = int(max(math.floor(cx - reach), 0)), int(min(math.ceil(cx + reach) + 1, width))
    y0, y1 = int(max(math.floor(cy - reach), 0)), int(min(math.ceil(cy + reach) + 1, height))
    dx = np.arange(x0, x1) - cx
    dy = np.arange(y0, y1) - cy
    r = np.sqrt(dy[:, None] ** 2 + dx[None, :] ** 2)
    keep = r < reach
    ring = (r[keep] * (1 / RING_PX)).astype(np.intp)
    values = field[y0:y1, x0:x1][keep]
    bins = int(reach / RING_PX) + 1
    count = np.bincount(ring, minlength=bins)
    total = np.bincount(ring, values, minlength=bins)
    mean = total / np.maximum(count, 1)
    within = float(np.sum((values - mean[ring]) ** 2))
    spread = float(np.sum((values - values.mean()) ** 2))
    return mean, within / spread if spread > 0 else 1.0


def symmetric_centre(
    field: np.ndarray, cx: float, cy: float, reach: float, search: float = SEARCH_PX
) -> tuple[float, float]:
    """The centre near (cx, cy) about which `field` is most radially symmetric."""
    for span, step in ((search, 1.0), (1.5, 0.25)):
        offsets = np.arange(-span, span + 1e-9, step)
        best = min(
            (
                (ring_profile(field, cx + dx, cy + dy, reach)[1], cx + dx, cy + dy)
                for dx in offsets
                for dy in offsets
            ),
            key=lambda item: item[0],
        )
        cx, cy = best[1], best[2]
    return float(cx), float(cy)


def profile_stretches(
    profiles: np.ndarray, fit: tuple[float, float], rounds: int = 5
) -> np.ndarray:
    """(N,) stretch s_i (mean 1) that best maps a common profile onto each image's ring profile."""
    r = (np.arange(profiles.shape[1]) + 0.5) * RING_PX
    sel = (r > fit[0]) & (r < fit[1])
    stretch = np.ones(len(profiles))
    for _ in range(rounds):
        common = np.mean(
            [np.interp(r, r * s, p) for s, p in zip(stretch, profiles, strict=True)], 0
        )
        for i, p in enumerate(profiles):

            def misfit(s, p=p, common=common):
                model = np.interp(r[sel] / s, r, common)
                gain = (model @ p[sel]) / max(model @ model, 1e-12)
                return float(np.sum((p[sel] - gain * model) ** 2))

            stretch[i] = optimize.minimize_scalar(
                misfit, bounds=STRETCH_BOUNDS, method="bounded", options={"xatol": 1e-4}
            ).x
        stretch /= stretch.mean()
    return stretch


def refine_contacts(
    frames: np.ndarray,
    blank: np.ndarray,
    center_px: np.ndarray,
    contact_px: np.ndarray,
    search: float = SEARCH_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """Refined (centres (N, 2), contact radii (N,)) px, from labelled ones and the frames."""
    contact_px = np.asarray(contact_px, dtype=float)
    if len(contact_px) < 3:
        raise ConfigError(
            f"label refinement needs at least 3 labelled frames (a common profile), got {len(contact_px)}"
        )
    scale = float(np.median(contact_px))
    centres, profiles, asymmetric = [], [], []
    for i, (frame, (cx, cy)) in enumerate(
        zip(frames, np.asarray(center_px, dtype=float), strict=True)
    ):
        field = imprint_magnitude(frame, blank)
        cx, cy = symmetric_centre(field, cx, cy, CENTRE_REACH * scale, search)
        centres.append((cx, cy))
        profile, left = ring_profile(field, cx, cy, PROFILE_REACH * scale)
        profiles.append(profile)
        if left > MAX_ASYMMETRY:
            asymmetric.append(i)
    if asymmetric:
        raise ConfigError(
            f"label refinement: frame(s) {asymmetric} show no round imprint near the labelled "
            f"contact (over {MAX_ASYMMETRY:.0%} of the colour change is not radially symmetric); "
            "check their labels or turn dataset.refine_labels off"
        )
    length = min(len(p) for p in profiles)
    stretch = profile_stretches(
        np.stack([p[:length] for p in profiles]), (FIT_RANGE[0] * scale, FIT_RANGE[1] * scale)
    )
    at_bound = np.isclose(stretch, STRETCH_BOUNDS[0], atol=1e-3) | np.isclose(
        stretch, STRETCH_BOUNDS[1], atol=1e-3
    )
    if at_bound.any():
        raise ConfigError(
            f"label refinement: frame(s) {np.flatnonzero(at_bound).tolist()} do not look like the "
            "others' ball imprint (contact size outside 0.7-1.3 x the common one); "
            "check their labels or turn dataset.refine_labels off"
        )
    return np.array(centres), stretch * float(contact_px.mean())


def refine_labels(ts: TrainingSet) -> TrainingSet:
    """A copy of a model-ready set with centres, depths and evaluation radii refined from its frames.

    The evaluation radius keeps its ratio to the contact radius; depth is capped where the
    importer caps it (a contact radius of 0.98 ball radii).
    """
    r_mm = ts.sphere_radius_mm
    depth = np.minimum(ts.depth_mm, r_mm)
    contact = np.sqrt(np.maximum(2 * r_mm * depth - depth**2, 0.0)) * ts.px_per_mm
    centres, radius = refine_contacts(np.asarray(ts.frames), ts.blank, ts.center_px, contact)
    radius = np.minimum(radius, 0.98 * r_mm * ts.px_per_mm)
    a_mm = radius / ts.px_per_mm
    samples = ts.samples.copy()
    samples["center_x_px"] = centres[:, 0]
    samples["center_y_px"] = centres[:, 1]
    samples["depth_mm"] = r_mm - np.sqrt(r_mm * r_mm - a_mm * a_mm)
    ratio = np.divide(ts.eval_radius_px, contact, out=np.ones(len(contact)), where=contact > 0)
    samples["eval_radius_px"] = ratio * radius
    meta = {**(ts.meta or {}), "labels": "refined from the images (threedcal.dataset.refine)"}
    return dataclasses.replace(ts, samples=samples, meta=meta)
