"""Automatic registration: contact centres from the frames themselves → printer-mm → pixel affine.

The authors register by hand (1 px steps, one isotropic scale, no rotation). Here every probe frame
votes: its contact centre is found on |frame − blank|, and a full 2×3 affine (translation, rotation,
per-axis scale, shear) is fitted to (printer x, y) → (column, row) by least squares with iterative
outlier rejection. The first-touch Z is estimated from the contact radius against commanded depth.

Contact centres come in two steps. The rim (`locate_contact`) gives a first centre and the radius.
Its centre drifts with the LED geometry: the shading's nonlinearity moves the rim's edge peak by an
amount that changes across the frame, which an affine absorbs as a wrong scale. `refine_by_symmetry`
then uses the one property that holds for any shading response: a point LED lights a pressed sphere
mirror-symmetrically about the line from the LED through the sphere's centre. Each LED's image
(the colour channels unmixed by a matrix fitted to the same frames) fixes the centre across its axis;
two or more LEDs at different azimuths fix it in 2D. Saturated pixels take no part.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage, optimize
from tqdm import tqdm

from threedcal.dataset.labels import LocalDome
from threedcal.errors import ThreedcalError
from threedcal.lens import RadialLens

if TYPE_CHECKING:
    from threedcal.sim.elastic import GelMaterial


class RegistrationError(ThreedcalError):
    pass


@dataclass(frozen=True)
class Contact:
    """A contact found in one frame: centre and equivalent radius in pixels, and its strength."""

    x_px: float
    y_px: float
    radius_px: float
    strength: float  # mean |ΔI| inside the contact, in DN


def colour_change(frame: np.ndarray, blank: np.ndarray) -> np.ndarray:
    """frame − blank in float32, after checking the two have one shape."""
    if frame.shape != blank.shape:
        raise RegistrationError(f"frame shape {frame.shape} differs from blank shape {blank.shape}")
    return frame.astype(np.float32) - blank.astype(np.float32)


def difference_magnitude(frame: np.ndarray, blank: np.ndarray, blur_px: float = 1.5) -> np.ndarray:
    """Per-pixel colour change |frame − blank| (Euclidean over channels), lightly smoothed, float32."""
    diff = colour_change(frame, blank)
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
    # Holes filled in the blob's bounding box, one pixel wider (the same as in the whole frame).
    box = ndimage.find_objects(labels)[labels[peak_index] - 1]
    top, left = max(box[0].start - 1, 0), max(box[1].start - 1, 0)
    region = labels[top : box[0].stop + 1, left : box[1].stop + 1] == labels[peak_index]
    rows, cols = np.nonzero(ndimage.binary_fill_holes(region))
    rows, cols = rows + top, cols + left
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
    height, width = frame.shape[:2]
    r0 = coarse.radius_px
    radii = np.linspace(0.5 * r0, 1.6 * r0, max(int(4.4 * r0), 8))
    angles = np.linspace(0.0, 2 * np.pi, n_rays, endpoint=False)
    xs = coarse.x_px + np.cos(angles)[:, None] * radii
    ys = coarse.y_px + np.sin(angles)[:, None] * radii
    if xs.min() < 0 or ys.min() < 0 or xs.max() > width - 1 or ys.max() > height - 1:
        return None  # the rim may be cut by the frame's edge: no unbiased circle
    # Only the box the rays cross, widened by the smoothing's and the gradient's reach, is
    # filtered: inside it the values are the whole frame's.
    reach = int(4 * smooth_px + 0.5) + 3
    top, left = max(int(ys.min()) - reach, 0), max(int(xs.min()) - reach, 0)
    bottom = min(int(ys.max()) + reach + 2, height)
    right = min(int(xs.max()) + reach + 2, width)
    diff = colour_change(frame[top:bottom, left:right], blank[top:bottom, left:right])
    if diff.ndim == 2:
        diff = diff[..., None]
    energy = np.zeros(diff.shape[:2], dtype=np.float32)
    for channel in range(diff.shape[2]):
        gy, gx = np.gradient(ndimage.gaussian_filter(diff[..., channel], smooth_px))
        energy += gx * gx + gy * gy
    edge = np.sqrt(energy)
    profiles = ndimage.map_coordinates(edge, [ys - top, xs - left], order=1)
    points = []
    for angle, profile in zip(angles, profiles, strict=True):
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


# Saturated pixels (or pixels saturated in the blank) carry no shading: they are left out of the fit.
SATURATED_DN = 250


@dataclass(frozen=True)
class _Window:
    """One contact's neighbourhood: colour change per channel (smoothed once) and usability.

    Only a box around the contact is kept (everything a fit can sample, plus the filters' reach,
    so its values equal the whole frame's); points outside the box count as unusable. What is
    kept is each pixel's bilinear cell coefficients (`_bilinear_table`), which is all sampling
    needs.
    """

    # (h*w, 4P) float64, P planes: frame − blank per channel, then 1 where usable. Float64, not
    # float32: rounding in the samples makes the fit's steps noise near its minimum.
    table: np.ndarray
    shape: tuple[int, int, int]  # (h, w, P)
    origin: tuple[int, int]  # (row, column) of the box's first pixel in the frame

    @classmethod
    def of(cls, frame: np.ndarray, blank: np.ndarray, smooth_px: float, box=None) -> _Window:
        if frame.shape != blank.shape:
            raise RegistrationError(
                f"frame shape {frame.shape} differs from blank shape {blank.shape}"
            )
        if box is None:
            box = (0, frame.shape[0], 0, frame.shape[1])
        r0, r1, c0, c1 = box
        frame, blank = frame[r0:r1, c0:c1], blank[r0:r1, c0:c1]
        diff = frame.astype(np.float64) - blank.astype(np.float64)
        planes = np.empty(diff.shape[:2] + (4,))
        for c in range(3):
            planes[..., c] = ndimage.gaussian_filter(diff[..., c], smooth_px)
        saturated = ((frame >= SATURATED_DN) | (blank >= SATURATED_DN)).any(axis=-1)
        planes[..., 3] = ndimage.binary_erosion(~saturated, iterations=2, border_value=1)
        return cls(table=_bilinear_table(planes), shape=planes.shape, origin=(r0, c0))

    @classmethod
    def around(
        cls, frame: np.ndarray, blank: np.ndarray, smooth_px: float, contact: Contact, reach: float
    ) -> _Window:
        """The box a symmetry fit of `contact` can reach: its disk, mirrored about any axis through
        a centre moved by up to half a radius (the fit's limit), plus the blur's and erosion's
        reach so that the box's values equal the whole frame's."""
        half = math.ceil((reach + 0.5) * contact.radius_px) + 2 + math.ceil(4 * smooth_px) + 3
        height, width = frame.shape[:2]
        row, col = int(round(contact.y_px)), int(round(contact.x_px))
        box = (
            max(row - half, 0),
            min(row + half + 1, height),
            max(col - half, 0),
            min(col + half + 1, width),
        )
        return cls.of(frame, blank, smooth_px, box)


@dataclass(frozen=True)
class _Disk:
    """Offsets (x, y) from a contact's centre within `reach_px`, `spacing` px apart; the rim at
    `radius_px`."""

    qx: np.ndarray
    qy: np.ndarray
    radius_px: float

    @classmethod
    def around(cls, contact: Contact, reach: float, spacing: int = 1) -> _Disk:
        reach_px = reach * contact.radius_px
        g = np.arange(-math.ceil(reach_px), math.ceil(reach_px) + 1, spacing, dtype=np.float64)
        qx, qy = np.meshgrid(g, g)
        # Each row shifted by a golden-ratio fraction of the spacing: on an integer lattice every
        # sample crosses a pixel boundary at the same centre, and the bilinear residuals kink
        # there together. Spread out, the objective is smoother (on the 9 contacts of
        # tests/dataset/test_registration.py: 15.3 -> 14.4 iterations, max error 0.181 -> 0.178 px).
        qx = qx + spacing * ((np.arange(g.size)[:, None] * 0.6180339887) % 1.0 - 0.5)
        inside = qx * qx + qy * qy <= reach_px * reach_px
        return cls(qx=qx[inside], qy=qy[inside], radius_px=contact.radius_px)


def _bilinear_table(planes: np.ndarray) -> np.ndarray:
    """Per pixel and plane, the bilinear coefficients of the cell to its lower right, (h*w, 4P):
    v00, v01 - v00, v10 - v00 and v11 - v10 - v01 + v00 (the last row and column repeat)."""
    p = np.pad(planes, ((0, 1), (0, 1), (0, 0)), mode="edge")
    v00, v01, v10, v11 = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    table = np.concatenate([v00, v01 - v00, v10 - v00, v11 - v10 - v01 + v00], axis=-1)
    return table.reshape(-1, table.shape[-1])


def _sample(window: _Window, rows: np.ndarray, cols: np.ndarray, gradient: bool = False):
    """Bilinear values (P, ...) of the window's planes (the last: usability) at frame points
    (any shape); points outside the window are 0 and unusable. With `gradient`, also the
    interpolant's derivatives along rows and columns, (P, ...) each.

    One gather of precomputed cell coefficients serves every plane (map_coordinates per plane
    costs ~10x).
    """
    height, width, n = window.shape
    shape = np.shape(rows)
    r = np.ravel(rows) - window.origin[0]
    c = np.ravel(cols) - window.origin[1]
    on = ((r >= 0) & (r <= height - 1) & (c >= 0) & (c <= width - 1))[:, None]
    r = np.clip(r, 0, height - 1)
    c = np.clip(c, 0, width - 1)
    r0 = r.astype(np.intp)
    c0 = c.astype(np.intp)
    fr = (r - r0)[:, None]
    fc = (c - c0)[:, None]
    cell = window.table[r0 * width + c0]
    v00, dc, dr, twist = cell[:, :n], cell[:, n : 2 * n], cell[:, 2 * n : 3 * n], cell[:, 3 * n :]
    values = ((v00 + fc * dc + fr * (dr + fc * twist)) * on).T.reshape((n, *shape))
    if not gradient:
        return values
    along_rows = ((dr + fc * twist) * on).T.reshape((n, *shape))
    along_cols = ((dc + fr * twist) * on).T.reshape((n, *shape))
    return values, along_rows, along_cols


def _mirrored(disk: _Disk, centre, axes):
    """Frame (rows, cols), (K, Q) each, of the disk's offsets mirrored about each axis (angles,
    (K,)) through `centre`."""
    ux, uy = np.cos(axes)[:, None], np.sin(axes)[:, None]
    along = disk.qx * ux + disk.qy * uy
    return centre[1] + 2 * along * uy - disk.qy, centre[0] + 2 * along * ux - disk.qx


def _mirror_pairs(window: _Window, disk: _Disk, centre, axes):
    """Per axis k: the colour change at offsets q from `centre` and at q mirrored about axis k.

    Returns (a, b, weight): a (C, Q), b (K, C, Q), weight (K, Q) — 0 where either point of a pair
    is saturated or off the image.
    """
    here = _sample(window, centre[1] + disk.qy, centre[0] + disk.qx)
    there = _sample(window, *_mirrored(disk, centre, np.asarray(axes, dtype=float)))  # (P, K, Q)
    return here[:3], there[:3].transpose(1, 0, 2), here[3] * there[3]


def _dipole_axes(window: _Window, unmixing: np.ndarray, centre, disk: _Disk) -> np.ndarray:
    """Each unmixed channel's first moment about `centre`: the azimuth of its LED, roughly."""
    values = _sample(window, centre[1] + disk.qy, centre[0] + disk.qx)[:3]
    unmixed = unmixing @ values
    return np.arctan2(unmixed @ disk.qy, unmixed @ disk.qx)


def _without_ramps(
    differences: np.ndarray, weight: np.ndarray, axes: np.ndarray, disk: _Disk
) -> np.ndarray:
    """Weighted mirror differences (K, R, Q) about axes (K,), less their best-fitting ramps.

    Not all of frame − blank follows one LED's mirror symmetry: the unmixing leaves some of the
    other LEDs' scattered light (its colour is not their direct light's), and a domed blank is
    shaded on a slope. Across one contact such light varies smoothly, to first order as a ramp,
    whose mirror difference is proportional to the distance from the axis. One such term inside
    the contact and one outside it are fitted and removed. On the Mini's flat gel this takes the
    symmetric centres' RMS error from 0.16 to 0.09 px (docs/diagnostics/registration_bias.py).
    The two terms have disjoint supports, so each is a one-unknown least-squares fit. `weight`
    is (K, Q): each pair's usability about each axis.
    """
    axes = np.asarray(axes, dtype=float)[:, None]
    across = (-disk.qx * np.sin(axes) + disk.qy * np.cos(axes)) * weight  # (K, Q)
    inner = np.hypot(disk.qx, disk.qy) <= disk.radius_px
    weighted = differences * weight[:, None, :]
    for part in (inner, ~inner):
        basis = across * part
        norm = np.einsum("kq,kq->k", basis, basis)
        share = np.einsum("krq,kq->kr", weighted, basis) / np.where(norm > 0, norm, 1.0)[:, None]
        weighted = weighted - share[:, :, None] * basis[:, None, :]
    return weighted


class _SymmetryResiduals:
    """The symmetry fit's normal equations, for one contact and unmixing.

    Residual block k is LED k's image at the disk's offsets minus its value at the offsets mirrored
    about axis k (weighted, less ramps, per usable pair). Its Jacobian comes with it, from the
    bilinear interpolant's own derivatives: one evaluation per iteration instead of one per
    parameter. Held fixed in the Jacobian (not in the residuals): the usability weights, and
    the ramp basis's turn with the axis — both change only where a pair meets a saturated pixel.
    Block k depends on the centre and axis k only: all blocks are evaluated together and the
    normal matrix is summed block by block, never forming the (KQ × 2+K) Jacobian.
    """

    def __init__(self, window: _Window, unmixing: np.ndarray, disk: _Disk):
        self.window, self.unmixing, self.disk = window, unmixing, disk

    def normal_equations(self, params: np.ndarray):
        """(cost, gradient, normal matrix): Σr², Jᵀr and JᵀJ at `params` (centre x, y, axes)."""
        d, k, u = self.disk, len(self.unmixing), self.unmixing
        cx, cy = params[:2]
        axes = params[2:]
        # The colour planes are sampled and then unmixed (cheaper than unmixing the window).
        here, here_dr, here_dc = _sample(self.window, cy + d.qy, cx + d.qx, gradient=True)
        ux, uy = np.cos(axes)[:, None], np.sin(axes)[:, None]
        along = d.qx * ux + d.qy * uy
        across = -d.qx * uy + d.qy * ux
        there, there_dr, there_dc = _sample(
            self.window, cy + 2 * along * uy - d.qy, cx + 2 * along * ux - d.qx, True
        )  # (P, K, Q): every plane about every axis; axis k reads LED k's image
        weight = here[3] * there[3]
        here, here_dr, here_dc = (
            np.einsum("kj,jq->kq", u, v[:3]) for v in (here, here_dr, here_dc)
        )
        there, there_dr, there_dc = (
            np.einsum("kj,jkq->kq", u, v[:3]) for v in (there, there_dr, there_dc)
        )
        # the mirrored point moves with the centre one for one, and turns with the axis
        turn = -(there_dc * 2 * (across * ux - along * uy))
        turn -= there_dr * 2 * (across * uy + along * ux)
        stack = np.stack([here - there, here_dc - there_dc, here_dr - there_dr, turn], axis=1)
        # (K, 4, Q): residual, then its derivatives along x, y and axis k
        # Per pair usable: the mean, not the sum, so that pushing pairs onto saturated pixels
        # (weight 0) does not pay.
        cleaned = _without_ramps(stack, weight, axes, d)
        cleaned /= np.sqrt(np.maximum(weight.sum(axis=1), 1e-9))[:, None, None]
        blocks = np.einsum("kiq,kjq->kij", cleaned, cleaned)  # (K, 4, 4)
        gradient, normal = np.zeros(params.size), np.zeros((params.size, params.size))
        for j in range(k):
            block = [0, 1, 2 + j]
            gradient[block] += blocks[j, 1:, 0]
            normal[np.ix_(block, block)] += blocks[j, 1:, 1:]
        return float(blocks[:, 0, 0].sum()), gradient, normal


def _levenberg_marquardt(problem, start: np.ndarray, scale: np.ndarray, tolerance: float):
    """Minimise Σr² from the problem's normal equations; (x, converged).

    Steps are taken in units of `scale` (a pixel of centre, 0.05 rad of axis). The fit has
    converged once a step would move the first two unknowns (the centre) by less than
    `tolerance` (taken if it lowers the cost): near the minimum the bilinear samples make the
    cost bumpy at that scale, and further steps only polish noise. Damping (a multiple of the
    normal matrix's diagonal) shrinks after a step that lowered the cost and grows after one
    that did not; a problem with few unknowns needs no more.
    """
    x = start.astype(np.float64)
    cost, gradient, normal = problem.normal_equations(x)
    if not np.isfinite(cost):
        return x, False
    damping = 1e-4
    for _ in range(MAX_FIT_EVALUATIONS):
        scaled = normal * np.outer(scale, scale)
        diagonal = np.maximum(np.diag(scaled), 1e-12)
        try:
            step = -np.linalg.solve(scaled + damping * np.diag(diagonal), gradient * scale)
        except np.linalg.LinAlgError:
            return x, False
        short = float(np.linalg.norm(step[:2] * scale[:2])) < tolerance
        trial = x + step * scale
        trial_cost, trial_gradient, trial_normal = problem.normal_equations(trial)
        if np.isfinite(trial_cost) and trial_cost <= cost:
            x, cost, gradient, normal = trial, trial_cost, trial_gradient, trial_normal
            damping = max(damping / 10, 1e-7)
        else:
            damping *= 10
        if short:  # the minimum lies within `tolerance` of x (a shorter step cannot help)
            return x, True
    return x, False


# Evaluations one symmetry fit may spend (scipy's least_squares allowed 100 per unknown).
MAX_FIT_EVALUATIONS = 100
# The fit samples the disk every SAMPLE_SPACING_PX pixels (each row still shifted by a fraction):
# a quarter of the samples, a quarter of the cost. Error against the known centres, every pixel →
# every 2nd (max / RMS px): the 25 contacts of benchmarks/bench_registration.py 0.202 / 0.106 →
# 0.225 / 0.110; the 9 of tests/dataset/test_registration.py 0.224 / 0.119 → 0.196 / 0.116; 49
# Mini contacts at 1, 2 and 3 mm, seeds 2 and 3: 0.395 / 0.137 → 0.443 / 0.144 and 0.238 / 0.114
# → 0.245 / 0.122. About 4 % more noise per contact, which an affine over many contacts averages.
SAMPLE_SPACING_PX = 2
# A fit has converged once a step would move the centre by less than this (px). The axes may
# still creep then; the centre no longer follows them by more than noise.
STEP_TOLERANCE_PX = 5e-3


def _symmetry_fit(window: _Window, unmixing: np.ndarray, coarse: Contact, reach: float):
    """(centre x, centre y, axes) that make every unmixed channel mirror-symmetric, or None."""
    disk = _Disk.around(coarse, reach, SAMPLE_SPACING_PX)
    start = np.array([coarse.x_px, coarse.y_px])
    axes0 = _dipole_axes(window, unmixing, start, disk)
    x, converged = _levenberg_marquardt(
        _SymmetryResiduals(window, unmixing, disk),
        np.concatenate([start, axes0]),
        np.concatenate([[1.0, 1.0], np.full(len(axes0), 0.05)]),  # a pixel; 0.05 rad of axis
        tolerance=STEP_TOLERANCE_PX,
    )
    cx, cy = x[:2]
    _, _, w = _mirror_pairs(window, disk, (cx, cy), x[2:])
    usable = float(w.mean())
    moved = math.hypot(cx - coarse.x_px, cy - coarse.y_px)
    if not converged or usable < 0.1 or moved > 0.5 * coarse.radius_px:
        return None
    return float(cx), float(cy), x[2:]


def _fit_unmixing(windows, fits, contacts, reach: float) -> np.ndarray:
    """Rows w_k (w_kk = 1) that make channel mix w_k · ΔI mirror-symmetric about LED k's axes."""
    rows = []
    for k in range(3):
        differences = []
        for window, (cx, cy, axes), contact in zip(windows, fits, contacts, strict=True):
            disk = _Disk.around(contact, reach, SAMPLE_SPACING_PX)
            a, b, w = _mirror_pairs(window, disk, (cx, cy), axes[k : k + 1])
            differences.append(_without_ramps((a - b[0])[None], w, axes[k : k + 1], disk)[0].T)
        d = np.concatenate(differences)  # (pairs, C)
        others = [c for c in range(3) if c != k]
        solution, *_ = np.linalg.lstsq(d[:, others], -d[:, k], rcond=None)
        row = np.zeros(3)
        row[k], row[others] = 1.0, solution
        rows.append(row)
    return np.asarray(rows)


@dataclass(frozen=True)
class SymmetryRefinement:
    contacts: list[Contact | None]  # the refined contact of each input (None: no usable fit)
    unmixing: np.ndarray  # (3, 3): row k mixes the colour channels into LED k's image


def refine_by_symmetry(
    frames,
    blank: np.ndarray,
    coarse: list[Contact | None],
    rounds: int = 2,
    reach: float = 1.4,
    smooth_px: float = 1.0,
    calibration_contacts: int = 40,
    progress: bool = False,
) -> SymmetryRefinement:
    """Contact centres from the mirror symmetry of each LED's image (see the module docstring).

    `frames[i]` is an (H, W, 3) frame with contact `coarse[i]` (from `locate_contact`; None is
    passed through). The unmixing starts as the identity and is refitted `rounds` times on up to
    `calibration_contacts` contacts spread over the list; the radius stays the rim's.
    """
    if np.ndim(blank) != 3 or np.shape(blank)[2] != 3:
        raise RegistrationError(
            f"symmetry refinement needs RGB frames (H, W, 3), got shape {np.shape(blank)}"
        )
    present = [i for i, c in enumerate(coarse) if c is not None]
    unmixing = np.eye(3)
    calibration = (
        [present[j] for j in np.linspace(0, len(present) - 1, calibration_contacts).astype(int)]
        if len(present) > calibration_contacts
        else present
    )

    def window(i: int) -> _Window:
        return _Window.around(np.asarray(frames[i]), blank, smooth_px, coarse[i], reach)

    windows = {i: window(i) for i in calibration}
    for _ in range(rounds):
        fits, used = [], []
        for i in calibration:
            fit = _symmetry_fit(windows[i], unmixing, coarse[i], reach)
            if fit is not None:
                fits.append(fit)
                used.append(i)
        if len(used) < 3:
            break
        unmixing = _fit_unmixing([windows[i] for i in used], fits, [coarse[i] for i in used], reach)
    contacts: list[Contact | None] = [None] * len(coarse)
    for i in tqdm(present, desc="symmetric centres", unit="contact", disable=not progress):
        fit = _symmetry_fit(windows.get(i) or window(i), unmixing, coarse[i], reach)
        if fit is not None:
            c = coarse[i]
            contacts[i] = Contact(
                x_px=fit[0], y_px=fit[1], radius_px=c.radius_px, strength=c.strength
            )
    return SymmetryRefinement(contacts=contacts, unmixing=unmixing)


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
# `register` falls back to the affine alone below it (a small trial plan), with a warning.
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
    (docs/registration.md, The lens)."""
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


class DomedContacts:
    """Where a ball's contact lies on a domed gel, relative to the ball's axis (what the affine maps).

    Off the apex the dome falls away from the ball, which meets the gel first on its apex side: the
    contact, and the centre a locator finds in it, lies toward the apex (by up to ~3.5 px on a
    DIGIT 0.4 mm deep). The affine would take that radial shift for a scale. The rigid overlap
    w = d − gap − (sag − sag under the axis) predicts it (docs/registration.md, Domed gels):

    - `area`: the centroid of w > 0, where the rim of a gel that follows the ball is centred;
    - `pressure`: the centroid of the pressure with which the ball presses w into an elastic layer
      of the gel's `material` (threedcal.sim.elastic), where the symmetric centre of an elastic
      contact lies. Solved on a coarse lattice of axes over the image once per depth (a few dozen
      solves), then interpolated: the shift varies smoothly, almost linearly, across the frame.

    Each located centre is moved to the axis whose predicted centre it is (a fixed point, three
    steps). Coordinates: pixels of an image of `image_shape` at `px_per_mm`; the dome (profile
    gel.dome) in mm about the image centre; `depth_mm` per frame, the press's depth below the gel
    as the plan meant it.
    """

    _GRID = 81  # samples across the ball's diameter (0.05 mm for R = 2 mm)
    _FIELD = (7, 9)  # axes (rows, columns) at which the pressure centroid is solved per depth
    _LATTICE_MM = 0.1  # the elastic solver's nodes: the simulator's 2 px at ~20 px/mm

    def __init__(
        self,
        dome,
        radius_mm: float,
        depth_mm,
        px_per_mm: float,
        image_shape,
        material: GelMaterial | None = None,
    ):
        self.kx, self.ky = float(dome["kx_per_mm"]), float(dome["ky_per_mm"])
        self.apex = (float(dome.get("apex_x_mm", 0.0)), float(dome.get("apex_y_mm", 0.0)))
        self.radius_mm = float(radius_mm)
        self.depth_mm = np.asarray(depth_mm, dtype=np.float64)
        self.px_per_mm = float(px_per_mm)
        height, width = image_shape[:2]
        self.shape = (height, width)
        self.centre_px = ((width - 1) / 2, (height - 1) / 2)
        half = self._GRID // 2  # a grid exactly symmetric about the axis: no centroid of its own
        g = self.radius_mm * (np.arange(-half, half + 1) / half)
        self._dx, self._dy = np.meshgrid(g, g)
        self.material = material
        self._gel = None
        self._fields: dict[float, object] = {}

    @property
    def elastic(self) -> bool:
        """True when the gel's elastic constants are known: its contacts are modelled as elastic."""
        return self.material is not None

    def _local_dome(self, ax: float, ay: float) -> LocalDome:
        """The dome about an axis at (ax, ay) mm from the image centre, as the labels see it."""
        return LocalDome(self.kx, self.ky, ax - self.apex[0], ay - self.apex[1])

    def _overlap(self, ax: float, ay: float, dx, dy, depth_mm: float):
        """w at (ax + dx, ay + dy) mm for a press with its axis at (ax, ay); -inf off the ball."""
        r2 = dx * dx + dy * dy
        root = np.sqrt(np.maximum(self.radius_mm**2 - r2, 0.0))
        w = depth_mm - (self.radius_mm - root) - self._local_dome(ax, ay).sag_mm(dx, dy)
        return np.where(r2 < self.radius_mm**2, w, -np.inf)

    def _axis_mm(self, axis_px) -> tuple[float, float]:
        return (
            (axis_px[0] - self.centre_px[0]) / self.px_per_mm,
            (axis_px[1] - self.centre_px[1]) / self.px_per_mm,
        )

    def _area_shift(self, ax: float, ay: float, depth_mm: float) -> np.ndarray:
        inside = self._overlap(ax, ay, self._dx, self._dy, depth_mm) > 0
        if not inside.any():
            return np.zeros(2)
        return np.array([self._dx[inside].mean(), self._dy[inside].mean()])

    def _pressure_shift(self, ax: float, ay: float, depth_mm: float) -> np.ndarray:
        from threedcal.sim.elastic import ElasticGel

        if self._gel is None:
            self._gel = ElasticGel(self.material, self._LATTICE_MM)
        reach = self.radius_mm
        press = self._gel.press(
            lambda X, Y: self._overlap(ax, ay, X - ax, Y - ay, depth_mm),
            (ax - reach, ax + reach, ay - reach, ay + reach),
            (ax, ay),
        )
        if press is None:
            return np.zeros(2)
        X, Y = press.node_coords(press.node_box())
        p = press.pressure
        return np.array([(p * (X - ax)).sum(), (p * (Y - ay)).sum()]) / p.sum()

    def _pressure_field(self, depth_mm: float):
        from scipy.interpolate import RegularGridInterpolator

        key = round(float(depth_mm), 4)
        if key not in self._fields:
            rows, cols = self._FIELD
            ys = (np.linspace(0, self.shape[0] - 1, rows) - self.centre_px[1]) / self.px_per_mm
            xs = (np.linspace(0, self.shape[1] - 1, cols) - self.centre_px[0]) / self.px_per_mm
            shifts = np.array([[self._pressure_shift(x, y, key) for x in xs] for y in ys])
            self._fields[key] = RegularGridInterpolator(
                (ys, xs), shifts, bounds_error=False, fill_value=None
            )
        return self._fields[key]

    def contact_centre(self, axis_px, depth_mm: float, model: str = "area") -> np.ndarray:
        """Where the contact of a press with its axis at `axis_px`, `depth_mm` deep, is centred
        under `model` ("area" or "pressure")."""
        ax, ay = self._axis_mm(axis_px)
        if model == "pressure":
            shift = self._pressure_field(depth_mm)([[ay, ax]])[0]
        else:
            shift = self._area_shift(ax, ay, depth_mm)
        return np.asarray(axis_px, dtype=np.float64) + shift * self.px_per_mm

    def to_axis(self, contacts: list[Contact | None], model: str = "area") -> list[Contact | None]:
        """Each located centre moved to the axis of the press whose contact is centred there."""
        out = []
        for contact, depth in zip(contacts, self.depth_mm, strict=True):
            if contact is not None:
                seen = np.array([contact.x_px, contact.y_px])
                axis = seen.copy()
                for _ in range(3):
                    axis = axis + (seen - self.contact_centre(axis, depth, model))
                contact = Contact(
                    float(axis[0]), float(axis[1]), contact.radius_px, contact.strength
                )
            out.append(contact)
        return out

    def contacts_at(self, axes_px, model: str) -> np.ndarray:
        """The contact centres (N, 2) of presses whose axes lie at `axes_px`."""
        return np.array(
            [self.contact_centre(a, d, model) for a, d in zip(axes_px, self.depth_mm, strict=True)]
        )


@dataclass(frozen=True)
class Registration:
    """The affine of the chosen contact locator, and what the choice rested on."""

    fit: AffineFit
    contacts: list[Contact | None]  # per input frame, from the chosen locator
    locator: str  # "rim" or "symmetry"
    residual_px: dict[str, float]  # affine RMS residual of each locator that produced a fit
    unmixing: np.ndarray | None  # the symmetry locator's channel unmixing (None: not run)
    # where the kept symmetric fits started: "rim" (its centres) or "fit" (where the first pass's
    # affine places each press); None: the symmetry locator did not run
    symmetry_start: str | None = None


def register(
    xy_mm: np.ndarray,
    frames,
    blank: np.ndarray,
    accept=lambda contact: True,
    flat_gel: bool = True,
    progress: bool = False,
    lens: bool = False,
    dome: DomedContacts | None = None,
) -> Registration:
    """Locate the contact in every frame by rim and, on a flat gel, by symmetry; fit the affine
    (and with `lens`, the camera lens's radial distortion with it: `fit_lensed`).

    The rim locator's bias drifts across the frame and the affine absorbs it as a scale. The
    symmetry locator has no such drift on a flat gel. On a domed gel every contact leans toward the
    apex; with `dome` (DomedContacts) each centre is moved from its contact to its press's axis —
    the rim's by the rigid overlap's centroid, the symmetric one (run only where the gel is
    elastic, `dome.elastic`) by the elastic pressure's. Where the gel follows the ball
    (`flat_gel=False` without an elastic `dome`), the shading of the domed blank's slope shifts
    symmetric centres radially by up to a pixel, an error an affine absorbs unseen: only the rim
    is used. Where both run, the locator whose centres an affine maps with the smaller RMS
    residual is kept (a failing
    unmixing or a clipped sensor shows there). `accept(contact)` drops contacts (e.g. too near
    the image edge) before fitting.

    A lens bends each contact, so its located centre is not where the lens images the press's
    axis (on the DIGIT's lens a contact 70 px across is off by up to 0.4 px near the frame's edge).
    With `lens`, a first fit (principal point and κ₁) rectifies the frames; the contacts are
    located again there, where they are round, mapped back through it, and the lens refitted to
    them (docs/registration.md, The lens).
    """
    shape = np.shape(blank)[:2] if lens else None
    located = _locate_and_fit(xy_mm, frames, blank, accept, flat_gel, progress, shape, dome=dome)
    if not lens:
        return located
    first = located.fit.lens
    if first is None:  # too few contacts for the lens
        return located
    again = _locate_and_fit(
        xy_mm,
        [first.rectify(np.asarray(f)) for f in frames],
        first.rectify(np.asarray(blank, dtype=np.float32)),
        accept,
        flat_gel,
        progress,
        shape,
        back=first,
        dome=dome,
    )
    return again


def _locate_and_fit(xy_mm, frames, blank, accept, flat_gel, progress, shape, back=None, dome=None):
    """One pass of `register`. `back`: the frames were rectified through this lens; the contacts
    are mapped back through it to camera pixels before the fit."""

    def unbent(contacts):
        if back is None:
            return contacts
        out = []
        for c in contacts:
            if c is not None:
                x, y = back.distort(np.array([c.x_px, c.y_px]))
                c = Contact(float(x), float(y), c.radius_px, c.strength)
            out.append(c)
        return out

    rim = [
        locate_contact(np.asarray(f), blank)
        for f in tqdm(frames, desc="rim centres", unit="frame", disable=not progress)
    ]
    rim = [c if c is not None and accept(c) else None for c in rim]

    def on_axis(contacts, model):  # on a dome: each centre moved from its contact to its axis
        return contacts if dome is None else dome.to_axis(contacts, model)

    unmixing = None
    contacts = unbent(on_axis(rim, "area"))
    candidates = {"rim": (contacts, _fit_contacts(xy_mm, contacts, shape))}
    symmetry_start = None
    # the symmetric centre of a contact on a dome: where an elastic layer's pressure is centred
    by_symmetry = flat_gel if dome is None else dome.elastic
    if by_symmetry and np.ndim(blank) == 3 and sum(c is not None for c in rim) >= 3:
        refined = refine_by_symmetry(frames, blank, rim, progress=progress)
        unmixing = refined.unmixing
        symmetric = [c if c is not None and accept(c) else None for c in refined.contacts]
        if sum(c is not None for c in symmetric) >= 3:
            contacts = unbent(on_axis(symmetric, "pressure"))
            candidates["symmetry"] = (contacts, _fit_contacts(xy_mm, contacts, shape))
            symmetry_start = "rim"
            again = _symmetry_from_fit(
                xy_mm, frames, blank, rim, candidates["symmetry"][1], accept, back, progress, dome
            )
            if sum(c is not None for c in again.contacts) >= 3:
                contacts = unbent(on_axis(again.contacts, "pressure"))
                fit = _fit_contacts(xy_mm, contacts, shape)
                if fit.residual_px < candidates["symmetry"][1].residual_px:
                    candidates["symmetry"] = (contacts, fit)
                    unmixing, symmetry_start = again.unmixing, "fit"
    locator = min(candidates, key=lambda name: candidates[name][1].residual_px)
    contacts, fit = candidates[locator]
    return Registration(
        fit=fit,
        contacts=contacts,
        locator=locator,
        residual_px={name: fit.residual_px for name, (_, fit) in candidates.items()},
        unmixing=unmixing,
        symmetry_start=symmetry_start,
    )


def _symmetry_from_fit(
    xy_mm, frames, blank, rim, fit: AffineFit, accept, back, progress, dome=None
) -> SymmetryRefinement:
    """The symmetry locator again, each fit started where `fit` places its press.

    The symmetric fit's cost can have a second minimum a few pixels from the true centre. On an
    elastic gel, whose shading halo reaches well past the rim, the rim locator's centre lies 2-3 px
    off near the frame's edges and the fit started there can settle in that minimum (a lower cost
    than the true one's for about half the contacts within 30-45 px of the Mini's edge). A lattice
    of presses knows better where each contact is: the affine (and lens) of the first pass, fitted
    over every contact, places each within a fraction of a pixel, and the fit started there stays
    in the true minimum (docs/registration.md, Symmetric centres on an elastic gel)."""
    guess = fit.apply(np.asarray(xy_mm, dtype=np.float64))
    if back is not None:  # the frames are rectified: start where the ideal frame holds each press
        guess = back.undistort(guess)
    if dome is not None:  # ... at its contact's centre, off the axis toward the dome's apex
        guess = dome.contacts_at(guess, "pressure")
    starts = [
        None if c is None else Contact(float(g[0]), float(g[1]), c.radius_px, c.strength)
        for c, g in zip(rim, guess, strict=True)
    ]
    refined = refine_by_symmetry(frames, blank, starts, progress=progress)
    return SymmetryRefinement(
        contacts=[c if c is not None and accept(c) else None for c in refined.contacts],
        unmixing=refined.unmixing,
    )


def _fit_contacts(xy_mm: np.ndarray, contacts: list[Contact | None], lens_shape=None) -> AffineFit:
    """fit_affine (or, given the frames' `lens_shape`, fit_lensed) over all frames; a frame without
    a contact is a non-finite point, never an inlier."""
    xy_px = np.array([(c.x_px, c.y_px) if c is not None else (np.nan, np.nan) for c in contacts])
    found = sum(c is not None for c in contacts)
    if lens_shape is not None:
        try:
            if found >= MIN_LENS_CONTACTS:
                return fit_lensed(xy_mm, xy_px.reshape(-1, 2), lens_shape)
        except RegistrationError:  # outliers left too few: as too few found
            pass
        logging.getLogger(__name__).warning(
            "registration: %d contacts, fewer than the %d inliers a lens fit needs: the affine "
            "alone (the lens's distortion stays in the frames; probe a denser plan to remove it)",
            found,
            MIN_LENS_CONTACTS,
        )
    return fit_affine(xy_mm, xy_px.reshape(-1, 2))


@dataclass(frozen=True)
class TouchEstimate:
    """First-touch offset δ (true depth = commanded + δ) and the rim's edge offset e (None: not fitted)."""

    offset_mm: float
    edge_mm: float | None


# Commanded depths must span this much before a constant edge offset can be told from δ.
MIN_DEPTH_SPREAD_MM = 0.2


def estimate_touch(
    commanded_depth_mm: np.ndarray, contact_radius_mm: np.ndarray, sphere_radius_mm: float
) -> TouchEstimate:
    """δ with true depth = commanded + δ, from contact radii a: d_true = R − sqrt(R² − a²).

    A positive δ means the gel surface sits higher than the plan assumed (the probe touches earlier).
    At one depth the median over all contacts is used (robust to the few whose radius a halo or a
    clipped edge biased). The located rim, though, sits a near-constant distance e outside the true
    edge (blur, the gel's skirt), which that median takes for extra depth: by e / (da/dd), growing
    with depth as the contact's edge steepens. Probed at depths that span `MIN_DEPTH_SPREAD_MM` or
    more, a = sqrt(2R(d + δ) − (d + δ)²) + e is fitted for δ and e together (robust loss).
    """
    depth = np.asarray(commanded_depth_mm, dtype=float)
    a = np.asarray(contact_radius_mm, dtype=float)
    R = float(sphere_radius_mm)
    ok = np.isfinite(depth) & np.isfinite(a) & (a > 0) & (a < R)
    if not ok.any():
        raise RegistrationError("no contact with a usable radius to estimate the touch height")
    depth, a = depth[ok], a[ok]
    median = float(np.median(R - np.sqrt(R**2 - a**2) - depth))
    if np.ptp(depth) < MIN_DEPTH_SPREAD_MM:
        return TouchEstimate(median, None)

    def residual(params: np.ndarray) -> np.ndarray:
        d = np.clip(depth + params[0], 0.0, R)
        return np.sqrt(2 * R * d - d**2) + params[1] - a

    low = -float(depth.min()) + 1e-6  # every contact stays a contact
    start = np.array([max(median, low + 1e-6), 0.0])
    fit = optimize.least_squares(
        residual, start, bounds=([low, -R / 2], [R, R / 2]), loss="soft_l1", f_scale=0.02
    )
    return TouchEstimate(float(fit.x[0]), float(fit.x[1]))


# Pixels at or beyond these levels in a blank or a frame carry no shading change: left out.
DARK_DN = 3


@dataclass(frozen=True)
class ChangeDetector:
    """Where a frame differs from the blank beyond its noise, measured on the blank frames themselves.

    A frame's change is frame − g · blank per channel (g: the frame's exposure gain, a median ratio,
    so an LED or exposure flicker is not taken for contact), smoothed over `smooth_px`, saturated or
    black pixels left out. Its noise `sigma` (per channel) is measured by the same recipe on each
    blank frame against the mean of the others. A pixel is significant where the sum over channels
    of (change / sigma)² exceeds `threshold`: the larger of the χ²(3) level of `false_alarm` per
    pixel and twice the largest value any blank frame reached, so correlated noise or a flickering
    hot spot raises the bar instead of reading as contact.
    """

    blank: np.ndarray  # (H, W, 3) float32, the mean of the blank frames
    usable: np.ndarray  # (H, W, 3) bool: neither saturated nor black in any blank frame
    sigma: np.ndarray  # (3,) noise of one frame's smoothed change
    threshold: float
    smooth_px: float

    @classmethod
    def from_blanks(
        cls, blank_frames: np.ndarray, smooth_px: float = 1.5, false_alarm: float = 1e-6
    ) -> ChangeDetector:
        from scipy import stats

        frames = np.asarray(blank_frames, dtype=np.float32)
        if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) < 3:
            raise RegistrationError(
                f"the touch search needs >= 3 RGB blank frames (N, H, W, 3) to measure the "
                f"noise, got {frames.shape} (the sensor profile's probing.n_blank)"
            )
        usable = ~((frames >= SATURATED_DN) | (frames <= DARK_DN)).any(axis=0)
        total = frames.sum(axis=0)
        changes = [
            _smoothed_change(f, (total - f) / (len(frames) - 1), usable, smooth_px) for f in frames
        ]
        sigma = np.median(
            [
                [1.4826 * float(np.median(np.abs(c[..., k][usable[..., k]]))) for k in range(3)]
                for c in changes
            ],
            axis=0,
        )
        sigma = np.maximum(sigma, 1e-3)
        # One blank frame against the mean of the others has (1 + 1/(n − 1)) / (1 + 1/n) the
        # variance of a frame against the mean of all: the levels below are conservative.
        blank_peak = max(float((((c / sigma) ** 2).sum(axis=-1)).max()) for c in changes)
        threshold = max(float(stats.chi2.isf(false_alarm, 3)), 2.0 * blank_peak)
        return cls(frames.mean(axis=0), usable, sigma, threshold, float(smooth_px))

    def significance(self, frame: np.ndarray, window=None) -> np.ndarray:
        """Sum over channels of (smoothed change / noise)²: ~χ²(3) where nothing changed.

        (H, W), or the (y0, y1, x0, x1) `window` of it (the exposure gain is still the frame's)."""
        frame = np.asarray(frame, dtype=np.float32)
        if frame.shape != self.blank.shape:
            raise RegistrationError(
                f"frame shape {frame.shape} differs from blank shape {self.blank.shape}"
            )
        usable = self.usable & (frame < SATURATED_DN) & (frame > DARK_DN)
        change = _smoothed_change(frame, self.blank, usable, self.smooth_px, window)
        return ((change / self.sigma) ** 2).sum(axis=-1)


def _smoothed_change(frame, reference, usable, smooth_px: float, window=None) -> np.ndarray:
    """frame − (g · reference + o) per channel over usable pixels, normalised-Gaussian smoothed:
    (H, W, 3), or (h, w, 3) over `window` (y0, y1, x0, x1). Gain g and offset o (an exposure or
    LED flicker is no contact) are medians over the whole frame, every other pixel each way."""
    height, width, channels = frame.shape
    y0, y1, x0, x1 = window or (0, height, 0, width)
    pad = int(np.ceil(4 * smooth_px))
    py0, py1, px0, px1 = (
        max(y0 - pad, 0),
        min(y1 + pad, height),
        max(x0 - pad, 0),
        min(x1 + pad, width),
    )
    out = np.zeros((y1 - y0, x1 - x0, channels), dtype=np.float32)
    for k in range(channels):
        ok = usable[..., k]
        sample = ok[::2, ::2]
        if not sample.any():
            continue
        f, ref = frame[::2, ::2, k][sample], reference[::2, ::2, k][sample]
        gain = float(np.median(f)) / max(float(np.median(ref)), 1e-6)
        offset = float(np.median(f - gain * ref))
        ok = ok[py0:py1, px0:px1]
        change = frame[py0:py1, px0:px1, k] - gain * reference[py0:py1, px0:px1, k] - offset
        change = np.where(ok, change, 0.0).astype(np.float32)
        weight = ndimage.gaussian_filter(ok.astype(np.float32), smooth_px)
        smooth = ndimage.gaussian_filter(change, smooth_px)
        smooth = np.where(weight > 0.5, smooth / np.maximum(weight, 1e-6), 0.0)
        out[..., k] = smooth[y0 - py0 : y1 - py0, x0 - px0 : x1 - px0]
    return out


@dataclass(frozen=True)
class TouchSearch:
    """The first-contact search's answer: δ with true depth = commanded + δ, and how it was found."""

    offset_mm: float  # the median over places
    place_offsets_mm: np.ndarray  # δ of each place
    onset_depth_mm: np.ndarray  # per place: the commanded depth of the first step with contact
    steps_fitted: np.ndarray  # per place: steps in the fit
    signal: np.ndarray  # per step: the contact signal the fit saw (0 without contact)
    exponent: float  # p of signal ∝ (c + δ)^p, measured from the steps (or as given)


# The smoothing (px) of the changes the contact signal is taken from.
TOUCH_SMOOTHING_PX = 1.0
# The window the signal is summed over: this many probe radii about the place, clipped to the frame.
TOUCH_WINDOW_RADII = 3.0
# A step has contact where its signal exceeds this many times the blanks' own (and twice their largest).
TOUCH_SIGNAL_SIGMAS = 6.0
# The depth past the onset the signal is fitted over: 8 steps of 0.02 mm. Chosen on the bench's
# elastic DIGIT (sharp and 6 px blurred cameras) and geometric DIGIT, seeds 11-14 (docs/registration.md).
TOUCH_FIT_SPAN_MM = 0.16
# The exponents p of signal ∝ (c + δ)^p the search chooses from.
TOUCH_EXPONENTS = np.round(np.arange(1.0, 3.0001, 0.05), 2)


def measure_touch_search(
    frames,
    blank_frames: np.ndarray,
    depth_mm: np.ndarray,
    place: np.ndarray,
    centres_px: np.ndarray,
    px_per_mm: float,
    reach_mm: float,
    span_mm: float,
    progress: bool = False,
) -> TouchSearch:
    """δ from the frames of a first-contact search: one frame per step (`frames[i]` at commanded
    depth `depth_mm[i]`, below the nominal touch and corrected for the gel's sag there, at place
    `place[i]`, its contact expected at `centres_px[i]` from the registration).

    Each step's change (frame − blank, `ChangeDetector`'s recipe, over `TOUCH_WINDOW_RADII` probe
    radii `reach_mm` about the place) is projected onto its place's template, the mean change of
    its three deepest steps: the contact signal L. A projection is linear in the image, so the
    camera's blur and the smoothing scale it but add nothing to it — unlike a contact's size, which
    a blur widens by a constant that a line through the sizes takes for depth (behind a 6 px
    blur, 0.36 mm). The same projection of each blank frame against the others' mean gives L's noise; a
    step has contact where L exceeds `TOUCH_SIGNAL_SIGMAS` times it and twice the largest blank's.
    `fit_touch_onset` then finds where L grows from.
    """
    detector = ChangeDetector.from_blanks(blank_frames, smooth_px=TOUCH_SMOOTHING_PX)
    blanks = np.asarray(blank_frames, dtype=np.float32)
    total = blanks.sum(axis=0)
    height, width = detector.blank.shape[:2]
    reach_px = TOUCH_WINDOW_RADII * reach_mm * px_per_mm
    depth = np.asarray(depth_mm, dtype=float)
    place = np.asarray(place)
    signal = np.zeros(len(depth))
    touching = np.zeros(len(depth), bool)
    bar = tqdm(total=len(depth), desc="touch search", unit="frame", disable=not progress)
    for p in np.unique(place):
        rows = np.flatnonzero(place == p)
        rows = rows[np.argsort(depth[rows], kind="stable")]
        cx, cy = np.median(np.asarray(centres_px, dtype=float)[rows], axis=0)
        window = (
            max(int(cy - reach_px), 0),
            min(int(cy + reach_px) + 1, height),
            max(int(cx - reach_px), 0),
            min(int(cx + reach_px) + 1, width),
        )
        if window[1] - window[0] < 3 or window[3] - window[2] < 3:
            raise RegistrationError(f"touch search place {p}: its contact lies off the frame")

        def change(frame, reference, usable, window=window):
            return _smoothed_change(frame, reference, usable, TOUCH_SMOOTHING_PX, window) / (
                detector.sigma
            )

        changes = []
        for i in rows:
            frame = np.asarray(frames[i], dtype=np.float32)
            usable = detector.usable & (frame < SATURATED_DN) & (frame > DARK_DN)
            changes.append(change(frame, detector.blank, usable))
            bar.update()
        template = np.mean(changes[-3:], axis=0)
        norm = float((template * template).sum())
        if not norm > 0:
            raise RegistrationError(f"touch search place {p}: no change at its deepest steps")
        quiet = [
            float((change(f, (total - f) / (len(blanks) - 1), detector.usable) * template).sum())
            / norm
            for f in blanks
        ]
        level = max(TOUCH_SIGNAL_SIGMAS * float(np.std(quiet, ddof=1)), 2 * max(map(abs, quiet)))
        signal[rows] = [float((c * template).sum()) / norm for c in changes]
        touching[rows] = signal[rows] > level
    bar.close()
    return fit_touch_onset(depth, place, np.where(touching, signal, 0.0), touching, span_mm)


def _onset_steps(c: np.ndarray, on: np.ndarray, span_mm: float, p) -> np.ndarray:
    """Indices of a place's steps (sorted by depth) the line is fitted to, or an error naming why not.
    Contact counts from the step after the last one without it: a lone false alarm above that is
    passed over."""
    if on.all():
        raise RegistrationError(
            f"touch search place {p}: contact already at the first step ({c[0]:+.3f} mm): "
            "the gel sits higher than the search starts — raise the sensor profile's "
            "probing.touch_uncertainty_mm — or the image drifted from the blank frames"
        )
    if not on[-1]:
        raise RegistrationError(
            f"touch search place {p}: no contact even at the last step ({c[-1]:+.3f} mm): "
            "the gel sits lower than the search reaches — raise probing.touch_uncertainty_mm "
            "or plan.touch_search.beyond_mm"
        )
    onset = int(np.flatnonzero(~on)[-1]) + 1  # contact from here on
    fit = np.flatnonzero((np.arange(len(c)) >= onset) & (c <= c[onset] + span_mm + 1e-9))
    if len(fit) < 3:
        raise RegistrationError(
            f"touch search place {p}: {len(fit)} steps with contact within {span_mm:g} mm "
            "of its onset; at least 3 are needed (a smaller step_mm or a larger beyond_mm)"
        )
    return fit


def fit_touch_onset(
    depth_mm: np.ndarray,
    place: np.ndarray,
    signal: np.ndarray,
    touching: np.ndarray,
    span_mm: float,
    exponent: float | None = None,
) -> TouchSearch:
    """δ from a contact signal L against commanded depth c at each place of a first-contact search.

    Contact begins where c + δ = 0, and near it L grows as a power of the true depth:
    L = α (c + δ)^p, α free per place (the LEDs, the place). p depends on the gel's mechanics (about
    2 for a rigid cap, whose volume grows as d²; about 1.5 for an elastic gel, whose surface also
    sinks around the contact, as a·d/r), so unless `exponent` gives it, p is the one of
    `TOUCH_EXPONENTS` whose lines through L^(1/p) fit L best, all places together. From the first
    step after which every step shows contact (`touching`), the steps within `span_mm` are fitted
    by least squares and δ is the line's zero; the median over places is returned. Contact at every
    step of a place, none at its last, or fewer than 3 steps to fit are errors that say which
    setting to change.
    """
    depth = np.asarray(depth_mm, dtype=float)
    signal = np.asarray(signal, dtype=float)
    touching = np.asarray(touching, dtype=bool)
    place = np.asarray(place)
    groups = []
    for p in np.unique(place):
        rows = np.flatnonzero(place == p)
        rows = rows[np.argsort(depth[rows], kind="stable")]
        fit = _onset_steps(depth[rows], touching[rows], span_mm, p)
        groups.append((p, rows[fit]))

    def lines(p_exp: float):
        out, sse = [], 0.0
        for _, rows in groups:
            c, y = depth[rows], np.clip(signal[rows], 0.0, None)
            slope, intercept = np.polyfit(c, y ** (1.0 / p_exp), 1)
            sse += float(np.sum((np.clip(slope * c + intercept, 0.0, None) ** p_exp - y) ** 2))
            out.append((slope, intercept))
        return out, sse

    if exponent is None:
        exponent = float(min(TOUCH_EXPONENTS, key=lambda e: lines(float(e))[1]))
    offsets, onsets, used = [], [], []
    for (p, rows), (slope, intercept) in zip(groups, lines(exponent)[0], strict=True):
        if not slope > 0:
            raise RegistrationError(
                f"touch search place {p}: the contact does not grow with depth (slope {slope:.3g})"
            )
        offsets.append(intercept / slope)
        onsets.append(depth[rows[0]])
        used.append(len(rows))
    offsets = np.asarray(offsets)
    return TouchSearch(
        offset_mm=float(np.median(offsets)),
        place_offsets_mm=offsets,
        onset_depth_mm=np.asarray(onsets),
        steps_fitted=np.asarray(used),
        signal=signal,
        exponent=float(exponent),
    )
