"""Printer millimetres → camera pixels: a 2×3 affine, and with it the lens's radial distortion.

Both are fitted to (printer x, y) → (column, row) pairs by least squares, refitted after rejecting
the points beyond a few robust sigmas. The authors register by hand (1 px steps, one isotropic
scale, no rotation); the affine has translation, rotation, per-axis scale and shear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from threedcal.errors import RegistrationError
from threedcal.lens import RadialLens


@dataclass(frozen=True)
class AffineFit:
    """Printer mm → pixels: an affine onto the ideal frame, then the camera's lens (None: none)."""

    matrix: np.ndarray  # (2, 3): ideal [col, row]ᵀ = M[:, :2] @ [x_mm, y_mm]ᵀ + M[:, 2]
    residual_px: float  # RMS residual over the inliers, camera pixels
    inliers: np.ndarray  # bool per input point
    lens: RadialLens | None = None

    def ideal(self, xy_mm: np.ndarray) -> np.ndarray:
        """Where the points lie in the ideal (rectified) frame: the affine alone."""
        xy = np.atleast_2d(np.asarray(xy_mm, dtype=float))
        return xy @ self.matrix[:, :2].T + self.matrix[:, 2]

    def apply(self, xy_mm: np.ndarray) -> np.ndarray:
        """Where the camera images the points."""
        ideal = self.ideal(xy_mm)
        return ideal if self.lens is None else self.lens.distort(ideal)

    @property
    def px_per_mm(self) -> tuple[float, float]:
        """Scale along printer x and y (column norms of the linear part)."""
        linear = self.matrix[:, :2]
        return float(np.linalg.norm(linear[:, 0])), float(np.linalg.norm(linear[:, 1]))


def _robust(src, dst, solve, reject_sigma: float, max_rounds: int):
    """Fit `solve(inliers) → model` (with `.apply`), refitting after rejecting points beyond
    `reject_sigma` robust sigmas; the model, its per-point residuals and the inliers."""
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    inliers = finite.copy()
    for _ in range(max_rounds):
        model = solve(inliers)
        residuals = np.full(len(src), np.inf)
        residuals[finite] = np.linalg.norm(model.apply(src[finite]) - dst[finite], axis=1)
        sigma = max(1.4826 * float(np.median(residuals[inliers])), 0.05)
        updated = finite & (residuals <= reject_sigma * sigma)
        if np.array_equal(updated, inliers):
            break
        inliers = updated
    return model, residuals, inliers


def _point_arrays(xy_mm, xy_px) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(xy_mm, dtype=float)
    dst = np.asarray(xy_px, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 2:
        raise RegistrationError(
            f"need matching (N, 2) point arrays, got {src.shape} and {dst.shape}"
        )
    return src, dst


def fit_affine(
    xy_mm: np.ndarray, xy_px: np.ndarray, reject_sigma: float = 4.0, max_rounds: int = 10
) -> AffineFit:
    """Least-squares affine mm → px, refitted after rejecting points beyond `reject_sigma` robust sigmas."""
    src, dst = _point_arrays(xy_mm, xy_px)
    design = np.column_stack([src, np.ones(len(src))])

    def solve(inliers):
        if inliers.sum() < 3 or np.linalg.matrix_rank(design[inliers]) < 3:
            raise RegistrationError(
                f"registration needs >= 3 contacts not on one line; {int(inliers.sum())} usable"
            )
        solution, *_ = np.linalg.lstsq(design[inliers], dst[inliers], rcond=None)
        return AffineFit(matrix=solution.T, residual_px=math.nan, inliers=inliers)

    fit, residuals, inliers = _robust(src, dst, solve, reject_sigma, max_rounds)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return AffineFit(matrix=fit.matrix, residual_px=rms, inliers=inliers)


# Fewest contacts to fit the lens's extra unknowns (principal point, κ₁) next to the affine;
# `register_camera` falls back to the affine alone below it (a small trial plan), with a warning.
MIN_LENS_CONTACTS = 30


def fit_lensed(
    xy_mm: np.ndarray,
    xy_px: np.ndarray,
    shape: tuple[int, int],
    reject_sigma: float = 4.0,
    max_rounds: int = 10,
    kappa2: bool = False,
) -> AffineFit:
    """Affine mm → ideal px and the lens's radial distortion (principal point, κ₁ and with
    `kappa2` κ₂) together, by Levenberg–Marquardt from the plain affine, with the same outlier
    rejection.

    `shape` (H, W) of the frames: the principal point starts at their centre, κ is solved in
    units of the half-diagonal (well scaled); the returned lens is in pixels. Contacts lie whole
    inside the frame, so none is found in its outer band (a contact radius and a margin wide):
    the fit extrapolates there. A free κ₂ follows the locator's error at the few outermost
    contacts and bends it into that band by pixels: `register` fits κ₁ alone
    (docs/explanation/registration.md, The lens)."""
    src, dst = _point_arrays(xy_mm, xy_px)
    height, width = shape
    centre0 = np.array([(width - 1) / 2, (height - 1) / 2])
    r0 = float(np.hypot(*centre0)) or 1.0
    start = fit_affine(src, dst, reject_sigma, max_rounds)

    def model(params) -> AffineFit:
        lens = RadialLens(
            centre_px=(float(params[6]), float(params[7])),
            kappa1=float(params[8]) / r0**2,
            kappa2=float(params[9]) / r0**4 if kappa2 else 0.0,
            shape=(int(height), int(width)),
        )
        return AffineFit(params[:6].reshape(2, 3), math.nan, np.zeros(0, bool), lens)

    params = np.concatenate([start.matrix.ravel(), centre0, [0.0, 0.0][: 1 + kappa2]])

    def solve(inliers):
        nonlocal params
        if inliers.sum() < MIN_LENS_CONTACTS:
            raise RegistrationError(
                f"fitting the lens needs >= {MIN_LENS_CONTACTS} contacts; {int(inliers.sum())} usable"
            )
        a, b = src[inliers], dst[inliers]

        def residual(p):
            return (model(p).apply(a) - b).ravel()

        params = optimize.least_squares(residual, params, method="lm", x_scale="jac").x
        return model(params)

    fit, residuals, inliers = _robust(src, dst, solve, reject_sigma, max_rounds)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return AffineFit(matrix=fit.matrix, residual_px=rms, inliers=inliers, lens=fit.lens)
