"""Automatic registration: contact centres from the frames themselves → printer-mm → pixel affine.

The authors register by hand (1 px steps, one isotropic scale, no rotation). Here every probe frame
votes: its contact centre is found on |frame − blank|, and a full 2×3 affine (translation, rotation,
per-axis scale, shear) is fitted to (printer x, y) → (column, row) by least squares with iterative
outlier rejection. The first-touch Z is estimated from the contact radius against commanded depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from threedcal.errors import ThreedcalError


class RegistrationError(ThreedcalError):
    pass


@dataclass(frozen=True)
class Contact:
    """A contact found in one frame: centre and equivalent radius in pixels, and its strength."""

    x_px: float
    y_px: float
    radius_px: float
    strength: float  # mean |ΔI| inside the contact, in DN


def difference_magnitude(frame: np.ndarray, blank: np.ndarray, blur_px: float = 1.5) -> np.ndarray:
    """Per-pixel colour change |frame − blank| (Euclidean over channels), lightly smoothed, float32."""
    if frame.shape != blank.shape:
        raise RegistrationError(f"frame shape {frame.shape} differs from blank shape {blank.shape}")
    diff = frame.astype(np.float32) - blank.astype(np.float32)
    magnitude = np.sqrt((diff * diff).sum(axis=-1)) if diff.ndim == 3 else np.abs(diff)
    return ndimage.gaussian_filter(magnitude, blur_px) if blur_px > 0 else magnitude


def find_contact(
    frame: np.ndarray,
    blank: np.ndarray,
    level: float = 0.5,
    min_contrast_sigma: float = 8.0,
    smooth_px: float = 3.0,
) -> Contact | None:
    """The contact in `frame`, or None when nothing stands out of the noise.

    Real frames differ from the blank everywhere a little (exposure drift) and around the contact a
    lot (the gel's elastic skirt), so a fixed threshold fails. Instead: the peak of the smoothed
    change |frame − blank| above its median must exceed `min_contrast_sigma` times the per-pixel
    noise (robust sigma of the unsmoothed change's high frequencies); the region above `level` of that peak height, connected to the peak and with holes
    filled, gives the centre (area centroid) and the radius of the circle of equal area.
    """
    raw = difference_magnitude(frame, blank, blur_px=0)
    magnitude = ndimage.gaussian_filter(raw, smooth_px)
    background = float(np.median(magnitude))
    high_pass = raw - ndimage.gaussian_filter(raw, 1.0)
    sigma = 1.4826 * float(np.median(np.abs(high_pass - np.median(high_pass)))) + 0.1
    peak_index = np.unravel_index(int(np.argmax(magnitude)), magnitude.shape)
    height = float(magnitude[peak_index]) - background
    if height < min_contrast_sigma * sigma:
        return None
    labels, _ = ndimage.label(magnitude > background + level * height)
    blob = ndimage.binary_fill_holes(labels == labels[peak_index])
    rows, cols = np.nonzero(blob)
    return Contact(
        x_px=float(cols.mean()),
        y_px=float(rows.mean()),
        radius_px=math.sqrt(rows.size / math.pi),
        strength=height,
    )


def refine_contact(
    frame: np.ndarray,
    blank: np.ndarray,
    coarse: Contact,
    n_rays: int = 72,
    smooth_px: float = 1.0,
) -> Contact | None:
    """Sub-pixel centre and radius from the contact's rim; None when the rim leaves the image.

    The edge of a pressed sphere is where the gel's slope changes fastest, so the colour change's
    spatial gradient peaks on a circle there. Along `n_rays` rays from the coarse centre the peak is
    located to sub-pixel (parabola through the maximum), and a circle is fitted to those points with
    outlier rejection. Equal angular sampling keeps the fit symmetric: a brighter side, a one-sided
    shadow or a lighting gradient barely moves it (an area centroid moves by pixels).
    """
    diff = frame.astype(np.float32) - blank.astype(np.float32)
    if diff.ndim == 2:
        diff = diff[..., None]
    energy = np.zeros(diff.shape[:2], dtype=np.float32)
    for channel in range(diff.shape[2]):
        gy, gx = np.gradient(ndimage.gaussian_filter(diff[..., channel], smooth_px))
        energy += gx * gx + gy * gy
    edge = np.sqrt(energy)
    height, width = edge.shape
    r0 = coarse.radius_px
    radii = np.linspace(0.5 * r0, 1.6 * r0, max(int(4.4 * r0), 8))
    points = []
    for angle in np.linspace(0.0, 2 * np.pi, n_rays, endpoint=False):
        xs = coarse.x_px + radii * np.cos(angle)
        ys = coarse.y_px + radii * np.sin(angle)
        if xs.min() < 0 or ys.min() < 0 or xs.max() > width - 1 or ys.max() > height - 1:
            return None  # the rim may be cut by the frame's edge: no unbiased circle
        profile = ndimage.map_coordinates(edge, [ys, xs], order=1)
        k = int(np.argmax(profile))
        offset = 0.0
        if 0 < k < len(profile) - 1:
            curvature = profile[k - 1] - 2 * profile[k] + profile[k + 1]
            if curvature < 0:
                offset = 0.5 * (profile[k - 1] - profile[k + 1]) / curvature
        r = float(np.interp(k + offset, np.arange(len(radii)), radii))
        points.append((coarse.x_px + r * np.cos(angle), coarse.y_px + r * np.sin(angle)))
    points = np.asarray(points)
    keep = np.ones(len(points), dtype=bool)
    for _ in range(3):
        x, y = points[keep, 0], points[keep, 1]
        solution, *_ = np.linalg.lstsq(
            np.column_stack([x, y, np.ones_like(x)]), x * x + y * y, rcond=None
        )
        cx, cy = solution[0] / 2, solution[1] / 2
        radius = float(np.sqrt(max(solution[2] + cx * cx + cy * cy, 0.0)))
        residual = np.abs(np.hypot(points[:, 0] - cx, points[:, 1] - cy) - radius)
        keep = residual < max(3 * 1.4826 * float(np.median(residual[keep])), 0.5)
        if keep.sum() < 8:
            return None
    return Contact(x_px=float(cx), y_px=float(cy), radius_px=radius, strength=coarse.strength)


def locate_contact(frame: np.ndarray, blank: np.ndarray) -> Contact | None:
    """Coarse contact (find_contact) refined on its rim (refine_contact); None without a whole contact."""
    coarse = find_contact(frame, blank, level=0.3)
    return None if coarse is None else refine_contact(frame, blank, coarse)


@dataclass(frozen=True)
class AffineFit:
    matrix: np.ndarray  # (2, 3): [col, row]ᵀ = M[:, :2] @ [x_mm, y_mm]ᵀ + M[:, 2]
    residual_px: float  # RMS residual over the inliers
    inliers: np.ndarray  # bool per input point

    def apply(self, xy_mm: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy_mm, dtype=float))
        return xy @ self.matrix[:, :2].T + self.matrix[:, 2]

    @property
    def px_per_mm(self) -> tuple[float, float]:
        """Scale along printer x and y (column norms of the linear part)."""
        linear = self.matrix[:, :2]
        return float(np.linalg.norm(linear[:, 0])), float(np.linalg.norm(linear[:, 1]))


def fit_affine(
    xy_mm: np.ndarray, xy_px: np.ndarray, reject_sigma: float = 4.0, max_rounds: int = 10
) -> AffineFit:
    """Least-squares affine mm → px, refitted after rejecting points beyond `reject_sigma` robust sigmas."""
    src = np.asarray(xy_mm, dtype=float)
    dst = np.asarray(xy_px, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 2:
        raise RegistrationError(
            f"need matching (N, 2) point arrays, got {src.shape} and {dst.shape}"
        )
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    inliers = finite.copy()
    design = np.column_stack([src, np.ones(len(src))])
    for _ in range(max_rounds):
        if inliers.sum() < 3 or np.linalg.matrix_rank(design[inliers]) < 3:
            raise RegistrationError(
                f"registration needs >= 3 contacts not on one line; {int(inliers.sum())} usable"
            )
        solution, *_ = np.linalg.lstsq(design[inliers], dst[inliers], rcond=None)
        residuals = np.full(len(src), np.inf)
        residuals[finite] = np.linalg.norm(design[finite] @ solution - dst[finite], axis=1)
        inlier_res = residuals[inliers]
        sigma = max(1.4826 * float(np.median(inlier_res)), 0.05)
        updated = finite & (residuals <= reject_sigma * sigma)
        if np.array_equal(updated, inliers):
            break
        inliers = updated
    matrix = solution.T  # (2, 3)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return AffineFit(matrix=matrix, residual_px=rms, inliers=inliers)


def estimate_touch_offset_mm(
    commanded_depth_mm: np.ndarray, contact_radius_mm: np.ndarray, sphere_radius_mm: float
) -> float:
    """Offset δ with true depth = commanded + δ, from contact radii a: d_true = R − sqrt(R² − a²).

    A positive δ means the gel surface sits higher than the plan assumed (the probe touches earlier).
    The median over all contacts is robust to the few whose radius a halo or a clipped edge biased.
    """
    depth = np.asarray(commanded_depth_mm, dtype=float)
    a = np.asarray(contact_radius_mm, dtype=float)
    ok = np.isfinite(depth) & np.isfinite(a) & (a > 0) & (a < sphere_radius_mm)
    if not ok.any():
        raise RegistrationError("no contact with a usable radius to estimate the touch height")
    true_depth = sphere_radius_mm - np.sqrt(sphere_radius_mm**2 - a[ok] ** 2)
    return float(np.median(true_depth - depth[ok]))
