"""Printer millimetres → camera pixels: a 2×3 affine, and with it the lens's radial distortion.

Both are fitted to (printer x, y) → (column, row) pairs by least squares, refitted after rejecting
the points beyond a few robust sigmas. The authors register by hand (1 px steps, one isotropic
scale, no rotation); the affine has translation, rotation, per-axis scale and shear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

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
    # from a profile's lens (fit_camera): which of its unknowns were refitted, and the
    # cross-validated error (px) of each choice tried; None: no lens to start from
    lens_free: str | None = None
    lens_cv_px: dict[str, float] | None = None

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


# Fewest contacts to fit the lens's extra unknowns (principal point, κ₁) next to the affine with
# no lens to start from; `register_camera` falls back to the affine alone below it, with a warning.
# From the profile's lens, fewer keep it as it is: on the quick plan's 20-27 contacts (bench units
# 15-20 of each sensor), a refitted κ₁ extrapolated worse over the view in every unit where the
# cross-validation chose one (DIGIT up to 0.57 against 0.27 px, Mini 1.83 against 0.90 px).
MIN_LENS_CONTACTS = 30
# From a lens to start from: which of its unknowns a fit frees, and the fewest contacts that fit
# takes (two equations each for the affine's 6 unknowns, with κ₁ 7, with the principal point 9,
# and one contact to spare).
LENS_FREEDOMS = {"none": 4, "kappa1": 5, "all": 6}
# Whole contacts a quick plan's first round must be expected to give (the config check): the
# affine through the profile's lens, and one to spare for a contact rejected as an outlier.
MIN_FIRST_CONTACTS = LENS_FREEDOMS["none"] + 1


def fit_lensed(
    xy_mm: np.ndarray,
    xy_px: np.ndarray,
    shape: tuple[int, int],
    reject_sigma: float = 4.0,
    max_rounds: int = 10,
    kappa2: bool = False,
    start: RadialLens | None = None,
    free: str = "all",
) -> AffineFit:
    """Affine mm → ideal px and the lens's radial distortion (principal point, κ₁ and with
    `kappa2` κ₂) together, by Levenberg–Marquardt from the plain affine, with the same outlier
    rejection.

    `shape` (H, W) of the frames: the principal point starts at their centre and κ at 0, or at
    `start`'s (a sensor profile's lens); `free` says which of them the fit moves: "all", "kappa1"
    (the principal point stays `start`'s) or "none" (the lens is `start`, the affine alone is
    fitted through it). κ is solved in units of the half-diagonal (well scaled); the returned lens
    is in pixels. Contacts lie whole inside the frame, so none is found in its outer band (a
    contact radius and a margin wide): the fit extrapolates there. A free κ₂ follows the locator's
    error at the few outermost contacts and bends it into that band by pixels: `register` fits κ₁
    alone (docs/explanation/registration.md, The lens)."""
    src, dst = _point_arrays(xy_mm, xy_px)
    height, width = shape
    if free not in LENS_FREEDOMS or (free != "all" and start is None):
        raise RegistrationError(f"fit_lensed: free={free!r} needs a start lens to hold")
    centre0 = np.array([(width - 1) / 2, (height - 1) / 2])
    r0 = float(np.hypot(*centre0)) or 1.0
    lens0 = (
        [*centre0, 0.0, 0.0]
        if start is None
        else [*start.centre_px, start.kappa1 * r0**2, start.kappa2 * r0**4]
    )
    # lens unknowns by index: principal point (0, 1), κ₁ (2), κ₂ (3)
    moving = {"all": [0, 1, 2], "kappa1": [2], "none": []}[free] + ([3] if kappa2 else [])
    fewest = MIN_LENS_CONTACTS if start is None else LENS_FREEDOMS[free]
    first = (
        fit_affine(src, dst, reject_sigma, max_rounds)
        if start is None
        else fit_affine(src, start.undistort(dst), reject_sigma, max_rounds)
    )

    def model(params) -> AffineFit:
        lens_params = np.array(lens0, dtype=float)
        lens_params[moving] = params[6:]
        lens = RadialLens(
            centre_px=(float(lens_params[0]), float(lens_params[1])),
            kappa1=float(lens_params[2]) / r0**2,
            kappa2=float(lens_params[3]) / r0**4,
            shape=(int(height), int(width)),
        )
        return AffineFit(params[:6].reshape(2, 3), math.nan, np.zeros(0, bool), lens)

    params = np.concatenate([first.matrix.ravel(), np.asarray(lens0, float)[moving]])

    def solve(inliers):
        nonlocal params
        if inliers.sum() < fewest:
            raise RegistrationError(
                f"fitting the lens ({free} free) needs >= {fewest} contacts; "
                f"{int(inliers.sum())} usable"
            )
        a, b = src[inliers], dst[inliers]

        def residual(p):
            return (model(p).apply(a) - b).ravel()

        params = optimize.least_squares(residual, params, method="lm", x_scale="jac").x
        return model(params)

    fit, residuals, inliers = _robust(src, dst, solve, reject_sigma, max_rounds)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return AffineFit(matrix=fit.matrix, residual_px=rms, inliers=inliers, lens=fit.lens)


# Folds of the cross-validation that chooses how much of the lens to fit.
LENS_FOLDS = 10


def fit_camera(
    xy_mm: np.ndarray, xy_px: np.ndarray, shape: tuple[int, int], prior: RadialLens
) -> AffineFit:
    """The affine and the lens from contacts, starting from `prior` (the sensor profile's lens):
    the profile's lens as it is, its κ₁ refitted, or its κ₁ and principal point refitted —
    whichever predicts contacts left out best (LENS_FOLDS-fold cross-validation over the first
    fit's inliers; a tie goes to the fewer unknowns), recorded in the fit's `lens_free` and
    `lens_cv_px`. A few contacts cannot pin a lens down, and then the profile's is the better
    guess; many can, and then the unit's own is. Under MIN_LENS_CONTACTS inliers the profile's
    lens is kept outright: contacts left out from among the others say how a lens interpolates,
    not how it extrapolates to the band beyond them (docs/explanation/registration.md)."""
    src, dst = _point_arrays(xy_mm, xy_px)
    first = fit_lensed(src, dst, shape, start=prior, free="none")
    inliers = np.flatnonzero(first.inliers)
    folds = np.arange(len(inliers)) % min(LENS_FOLDS, len(inliers))
    errors: dict[str, float] = {}
    fits: dict[str, AffineFit] = {"none": first}
    few = len(inliers) < MIN_LENS_CONTACTS
    for free in ["none"] if few else LENS_FREEDOMS:
        squared = []
        try:
            for fold in np.unique(folds):
                train, test = inliers[folds != fold], inliers[folds == fold]
                fit = fit_lensed(
                    src[train], dst[train], shape, start=prior, free=free, max_rounds=1
                )
                squared.append(np.sum((fit.apply(src[test]) - dst[test]) ** 2, axis=1))
            if free != "none":
                fits[free] = fit_lensed(src, dst, shape, start=prior, free=free)
        except RegistrationError:
            continue
        errors[free] = float(np.sqrt(np.mean(np.concatenate(squared))))
    best = (
        min(errors, key=lambda k: (round(errors[k], 6), list(LENS_FREEDOMS).index(k)))
        if errors
        else "none"
    )
    return replace(fits[best], lens_free=best, lens_cv_px=errors)
